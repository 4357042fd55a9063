"""The built-in demo: a synthetic depth sequence that needs no camera, data or renderer.

A default-sized body (the tracker's own cylinder model, :mod:`runtime.raycast`) performs the
procedural motions of :mod:`shared.procedural_motion` (wave, squat, kick, arm crossing, walk)
2.6 m in front of a level camera 1.0 m above a floor. Depth goes through the same Kinect v1
sensor model as the synthetic recordings (:mod:`shared.sensor_noise`): disparity-quantized,
noise growing with z squared, projector shadows, grazing-angle dropout, holes and ragged
silhouettes, the floor in view.
The stream carries its ground truth (:attr:`DemoStream.groundtruth`), so the tracker alone can be
started from it and the result evaluated.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, transform_pose
from depthmocap.shared.procedural_motion import ground_poses, motion_poses
from depthmocap.shared.sensor_noise import (
    BackgroundConfig,
    BackgroundScene,
    KinectNoiseConfig,
    add_floor_and_background,
    apply_kinect_noise,
)

from .base import ALL_FRAMES, DepthFrame, DepthStream, FrameRange

__all__ = ["DEMO_MOTIONS", "DemoStream", "open_demo_stream", "demo_poses"]

DEMO_MOTIONS = ("wave", "squat", "arm_cross", "kick", "walk")
_SECONDS_PER_MOTION = 2.0
_CAMERA_HEIGHT = 1.0  # metres above the floor
_DISTANCE = 2.6  # person's root from the camera, metres
# The scene: the floor only (no wall, no boxes), cut off 8 m from the camera.
_SCENE = BackgroundScene(wall_distance=None)
_SCENE_CONFIG = BackgroundConfig(max_distance_m=8.0)


def demo_poses(fps: float, seed: int = 0) -> np.ndarray:
    """World poses (F, 34) of the demo (y up, floor y = 0, facing +z): 12 s at ``fps``."""
    rng = np.random.default_rng(seed)
    frames = int(round(_SECONDS_PER_MOTION * fps))
    body = BodyShape.default(torch.float64)
    parts = [motion_poses(m, frames, fps, rng) for m in DEMO_MOTIONS]
    # Half a second of linear blend between motions: a person does not teleport between poses.
    blend = int(round(0.5 * fps))
    w = (np.arange(1, blend + 1) / (blend + 1))[:, None]
    seq = [parts[0]]
    for nxt in parts[1:]:
        seq += [(1 - w) * seq[-1][-1] + w * nxt[0], nxt]
    q = np.concatenate(seq)
    q[:, 0] = 0.0  # stay in place (walking on the spot keeps the person in view)
    q[:, 2] = 0.0
    return ground_poses(q, body)


def _camera_from_world() -> tuple[torch.Tensor, torch.Tensor]:
    """Level camera at world (0, h, d) looking along -z at the person, who faces it:
    ``p_cam = R p_world + t`` with R = diag(1, -1, -1) (rotation vector (pi, 0, 0))."""
    rot = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    trans = torch.tensor([0.0, _CAMERA_HEIGHT, _DISTANCE], dtype=torch.float64)
    return rot, trans


class DemoStream(DepthStream):
    """The demo sequence as a depth stream (frames rendered on the fly, in batches).

    Attributes:
        groundtruth: ``joints`` (F, J, 3) camera metres, ``joint_names``, ``q`` (F, 34).
        body: the body the sequence is rendered with.
    """

    source = "demo"

    def __init__(
        self,
        intrinsics: Intrinsics | None = None,
        frame_range: FrameRange = ALL_FRAMES,
        fps: float | None = None,
        seed: int = 0,
    ) -> None:
        self._intrinsics = intrinsics or Intrinsics.kinect_v1(320)
        self._fps = float(fps or 30.0)
        self.body = BodyShape.default(torch.float64)
        rot, trans = _camera_from_world()
        q_world = torch.as_tensor(demo_poses(self._fps, seed))
        self._q = transform_pose(q_world, rot, trans)
        joints = named_joint_positions(forward_kinematics(self._q, self.body))
        self.groundtruth = {
            "joints": joints.numpy().astype(np.float32),
            "joint_names": np.array(sk.JOINT_NAMES),
            "q": self._q.numpy().astype(np.float32),
        }
        self._range = frame_range.clip(len(self._q))
        self._seed = seed

    @property
    def frame_count(self) -> int:
        return len(self._range)

    def __iter__(self) -> Iterator[DepthFrame]:
        from depthmocap.runtime.raycast import render_body_depth

        rng = np.random.default_rng(self._seed)
        sensor = KinectNoiseConfig()
        intr = self._intrinsics
        body = self.body.to(torch.float32)
        idx = list(self._range)
        for start in range(0, len(idx), 16):
            chunk = idx[start : start + 16]
            q = self._q[chunk].to(torch.float32)
            depth = render_body_depth(q, body, intr).numpy()
            for i, d in zip(chunk, depth):
                # Level camera (pitch 0): the floor lies _CAMERA_HEIGHT below it.
                scene, _ = add_floor_and_background(
                    d, None, intr, _CAMERA_HEIGHT, 0.0, cfg=_SCENE_CONFIG, scene=_SCENE
                )
                depth_mm, _ = apply_kinect_noise(scene, None, intr, sensor, rng)
                yield DepthFrame(i, i / self._fps, depth_mm, intr)


def open_demo_stream(
    intrinsics: Intrinsics | None = None, frame_range: FrameRange = ALL_FRAMES, fps=None
) -> DemoStream:
    """The demo as a stream (see :class:`DemoStream`)."""
    return DemoStream(intrinsics, frame_range, fps)
