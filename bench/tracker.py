"""Speed of the tracker (:func:`runtime.tracker.track_sequence`) frame after frame.

Two inputs: a sequence ray-cast from the cylinder model itself (:func:`bench.scenes.camera_motion`
at 320x240, nothing to download), and recordings with ground truth (noisy sensor data, the
recording's own body). Frames are rendered or decoded and segmented before timing; what is
timed is tracking the whole sequence from the ground truth of frame 0, after one untimed
step (warm-up), and, separately, one ray-cast at the working resolution (the inner loop's
biggest single cost).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import torch
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker import Tracker, TrackerConfig, track_sequence
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions

from .scenes import camera_motion
from .timing import median_ms, wall_ms

__all__ = ["benchmark_tracker", "benchmark_recording", "tracker_rows", "recording_rows"]


def _timed_track(depths, masks, q0, tracker) -> tuple[float, torch.Tensor, list]:
    """Warm up on frame 0, then track every frame: (ms per frame, poses (F, 34), results)."""
    tracker.step(depths[0], masks[0], q0, None)  # warm-up
    out = {}

    def run():
        out["q"], out["results"] = track_sequence(depths, masks, q0, tracker)

    ms = wall_ms(run, tracker.device)
    return ms / len(depths), out["q"], out["results"]


def benchmark_tracker(
    device: str = "cpu",
    frames: int = 60,
    motion: str = "walk",
    cfg: TrackerConfig | None = None,
    distance_m: float = 2.5,
) -> dict[str, float]:
    """Frames per second of the tracker and the ray-cast time on ``device``.

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
    ms, est, results = _timed_track(depth, mask, truth[0], tracker)

    obs = tracker.observe(depth[0], mask[0])
    some = min(frames, 30)
    poses = itertools.cycle(truth[:some].split(1))  # each of the first frames once
    raycast_ms = median_ms(
        lambda: render_body(next(poses), body, obs.intr), repeats=some, warmup=0, device=dev
    )
    err = named_joint_positions(forward_kinematics(est, body)) - named_joint_positions(
        forward_kinematics(truth, body)
    )
    return {
        "frames_per_s": 1e3 / ms,
        "ms_per_frame": ms,
        "raycast_ms": raycast_ms,
        "iterations_mean": float(np.mean([r.iterations for r in results])),
        "joint_error_mm": float(err.norm(dim=-1).mean()) * 1e3,
        "threads": float(torch.get_num_threads()),
        "working_pixels": float(obs.valid.sum()),
        "working_width": float(intr.width * obs.intr.fx / intr.fx),
    }


def benchmark_recording(
    path: str | Path, frames: int = 40, device: str = "cpu", cfg: TrackerConfig | None = None
) -> dict[str, float]:
    """Frame time of the tracker on a recording with ground truth (noisy sensor data, the
    recording's own body file), started from the ground truth of frame 0.

    Decoding and segmentation happen before timing. Returns ``ms_per_frame``,
    ``iterations_mean``, ``working_pixels`` (frame 0) and ``frames`` (timed).
    Raises ``shared.recording.RecordingError`` for a recording without ground truth.
    """
    from depthmocap.runtime.segmentation import segment_person
    from depthmocap.shared.recording import Recording, RecordingError

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
    ms, _, results = _timed_track(depths, masks, q, tracker)
    return {
        "ms_per_frame": ms,
        "iterations_mean": float(np.mean([r.iterations for r in results])),
        "working_pixels": float(tracker.observe(depths[0], masks[0]).valid.sum()),
        "frames": float(n),
    }


def tracker_rows(device: str) -> list[tuple[str, float, str]]:
    """Tracker frame time and ray-cast time at two distances; rows of (what, ms, note)."""
    rows = []
    for distance in (2.5, 3.5):
        r = benchmark_tracker(device=device, frames=60, distance_m=distance)
        at = (
            f"person at {distance} m: {r['working_pixels']:.0f} pixels at "
            f"{r['working_width']:.0f} px wide"
        )
        rows += [
            (
                f"tracker step (Gauss-Newton, all terms), {at}",
                r["ms_per_frame"],
                f"{r['frames_per_s']:.1f} frames/s, {r['iterations_mean']:.1f} iterations, "
                f"joint error {r['joint_error_mm']:.1f} mm; target >= 30 frames/s",
            ),
            (f"ray-cast of the body, {at}", r["raycast_ms"], "one render per iteration"),
        ]
    return rows


def recording_rows(folder: Path, device: str) -> list[tuple[str, float, str]]:
    """Tracker frame time on each recording with ground truth in ``folder`` (others skipped)."""
    rows = []
    for rec in sorted(d for d in folder.iterdir() if (d / "groundtruth.npz").is_file()):
        r = benchmark_recording(rec, device=device)
        rows.append(
            (
                f"tracker step, {rec.name}",
                r["ms_per_frame"],
                f"{1e3 / r['ms_per_frame']:.1f} frames/s, {r['iterations_mean']:.1f} "
                f"iterations, {r['working_pixels']:.0f} working pixels",
            )
        )
    return rows
