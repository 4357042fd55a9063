"""Tracker speed on a sequence rendered from the cylinder model itself (for ``make bench``).

The motion is one of :mod:`shared.procedural_motion`'s, seen by a Kinect v1 camera at 320x240
about 2.5 m in front of the person (camera 1 m above the floor, looking horizontally). The
frames are ray-cast before timing; what is timed is :meth:`Tracker.step` frame after frame
started from the ground truth of frame 0, and, separately, one ray-cast at the working
resolution (the inner loop's biggest single cost).
"""

from __future__ import annotations

import statistics
import time

import numpy as np
import torch

from runtime.raycast import render_body
from shared.body import BodyShape
from shared.camera import Intrinsics
from shared.kinematics import forward_kinematics, named_joint_positions, transform_pose
from shared.procedural_motion import ground_poses, motion_poses

from .config import TrackerConfig
from .tracker import Tracker, track_sequence

__all__ = ["camera_motion", "benchmark_tracker", "benchmark_recording"]


def camera_motion(
    name: str,
    frames: int,
    fps: float = 30.0,
    seed: int = 0,
    distance_m: float = 2.5,
    camera_height_m: float = 1.0,
    body: BodyShape | None = None,
) -> torch.Tensor:
    """Camera-frame poses (F, 34) of procedural motion ``name`` facing the camera, float64.

    The person starts ``distance_m`` in front of the camera, upright and facing it, feet on a
    floor ``camera_height_m`` below the camera.
    """
    body = BodyShape.default(torch.float64) if body is None else body.to(torch.float64)
    rng = np.random.default_rng(seed)
    world = torch.as_tensor(ground_poses(motion_poses(name, frames, fps, rng), body))
    # World (y up, person facing +z) -> camera (y down, z away from the camera).
    rot = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    shift = torch.tensor([0.0, camera_height_m, distance_m + float(world[0, 2])])
    return transform_pose(world, rot, shift.to(torch.float64))


def benchmark_tracker(
    device: str = "cpu",
    frames: int = 60,
    motion: str = "walk",
    cfg: TrackerConfig | None = None,
    distance_m: float = 2.5,
) -> dict[str, float]:
    """Frames per second of :meth:`Tracker.step` and the ray-cast time on ``device``.

    Args:
        distance_m: the person's distance from the camera: the farther, the fewer pixels, and
            the automatic working resolution (``cfg.downsample`` 0) pools less.
    Returns:
        ``frames_per_s`` (tracking), ``ms_per_frame``, ``raycast_ms`` (median of one
        working-resolution ray-cast), ``iterations_mean``, ``joint_error_mm`` (mean named-joint
        error against the ground truth, a sanity check), ``threads`` (torch CPU threads),
        ``working_pixels`` (the person's pixels at the working resolution, frame 0),
        ``working_width`` (the working image's width if it were uncropped).
    """
    dev = torch.device(device)
    cfg = TrackerConfig() if cfg is None else cfg
    body = BodyShape.default(torch.float32, dev)
    intr = Intrinsics.kinect_v1(320)
    truth = camera_motion(motion, frames, distance_m=distance_m).to(device=dev, dtype=torch.float32)
    depth = render_body(truth, body, intr).depth
    mask = depth > 0
    tracker = Tracker(body, intr, cfg, device=dev)

    def sync() -> None:
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)

    tracker.step(depth[0], mask[0], truth[0], None)  # warm-up
    sync()
    poses, iters = [], []
    prev, prev2 = truth[0], None
    t0 = time.perf_counter()
    for f in range(frames):
        res = tracker.step(depth[f], mask[f], prev, prev2)
        prev, prev2 = res.q, prev
        poses.append(res.q)
        iters.append(res.iterations)
    sync()
    elapsed = time.perf_counter() - t0

    obs = tracker.observe(depth[0], mask[0])
    work = obs.intr
    times = []
    for f in range(min(frames, 30)):
        sync()
        t = time.perf_counter()
        render_body(truth[f : f + 1], body, work)
        sync()
        times.append((time.perf_counter() - t) * 1e3)
    est = torch.stack(poses)
    err = named_joint_positions(forward_kinematics(est, body)) - named_joint_positions(
        forward_kinematics(truth, body)
    )
    return {
        "frames_per_s": frames / elapsed,
        "ms_per_frame": elapsed / frames * 1e3,
        "raycast_ms": statistics.median(times),
        "iterations_mean": float(np.mean(iters)),
        "joint_error_mm": float(err.norm(dim=-1).mean()) * 1e3,
        "threads": float(torch.get_num_threads()),
        "working_pixels": float(obs.valid.sum()),
        "working_width": float(intr.width * obs.intr.fx / intr.fx),
    }


def benchmark_recording(
    path, frames: int = 40, device: str = "cpu", cfg: TrackerConfig | None = None
) -> dict[str, float]:
    """Frame time of :meth:`Tracker.step` on a recording with ground truth (noisy sensor data,
    the recording's own body file), started from the ground truth of frame 0.

    Decoding and segmentation happen before timing. Returns ``ms_per_frame``,
    ``iterations_mean``, ``working_pixels`` (frame 0) and ``frames`` (timed).
    Raises ``shared.recording.RecordingError`` for a recording without ground truth.
    """
    from pathlib import Path

    from runtime.segmentation import segment_person
    from shared.recording import Recording, RecordingError

    rec = Recording(path)
    if not rec.has_groundtruth or not (Path(path) / "body.json").is_file():
        raise RecordingError(f"{path}: needs groundtruth.npz and body.json")
    dev = torch.device(device)
    body = BodyShape.load(Path(path) / "body.json").to(device=dev)
    tracker = Tracker(body, rec.intrinsics, cfg, device=dev)
    n = min(frames, len(rec))
    if n < 1:
        raise RecordingError(f"{path}: no frames to time")
    depths = torch.stack([torch.as_tensor(rec.read_depth(i)) for i in range(n)])
    masks = torch.stack([segment_person(d, rec.intrinsics) for d in depths])
    q = torch.as_tensor(rec.groundtruth()["q"][0], dtype=torch.float32, device=dev)
    tracker.step(depths[0], masks[0], q, None)  # warm-up
    t0 = time.perf_counter()
    _, results = track_sequence(depths, masks, q, tracker)
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)
    elapsed = time.perf_counter() - t0
    return {
        "ms_per_frame": elapsed / n * 1e3,
        "iterations_mean": float(np.mean([r.iterations for r in results])),
        "working_pixels": float(tracker.observe(depths[0], masks[0]).valid.sum()),
        "frames": float(n),
    }
