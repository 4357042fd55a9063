"""Synthetic inputs for the benchmarks: no data files needed, the same scene every run.

A tracker scene is a procedural motion (:mod:`shared.procedural_motion`) placed in front of a
Kinect-v1-like camera; a forest scene is a person-sized silhouette drawn from ellipses. Both
are fixed by their seeds, so figures of different runs time the same work.
"""

from __future__ import annotations

import numpy as np
import torch
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import transform_pose
from depthmocap.shared.procedural_motion import ground_poses, motion_poses

__all__ = ["camera_motion", "person_frame"]


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
    floor ``camera_height_m`` below the camera (camera looking horizontally).
    """
    body = BodyShape.default(torch.float64) if body is None else body.to(torch.float64)
    rng = np.random.default_rng(seed)
    world = torch.as_tensor(ground_poses(motion_poses(name, frames, fps, rng), body))
    # World (y up, person facing +z) -> camera (y down, z away from the camera).
    rot = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    shift = torch.tensor([0.0, camera_height_m, distance_m + float(world[0, 2])])
    return transform_pose(world, rot, shift.to(torch.float64))


def person_frame(width: int = 320, height: int = 240) -> tuple[np.ndarray, np.ndarray]:
    """A synthetic standing person at about 2.5 m: depth (H, W) float32 metres, mask (H, W) bool.

    About 7,000 person pixels at 320x240 (the synthetic training set averages about 4,000 at
    1.5-4 m), enough for the forest's per-pixel cost to dominate.
    """
    import cv2

    s = width / 320.0
    mask = np.zeros((height, width), np.uint8)
    cx = width // 2

    def ell(x, y, ax, ay, angle=0.0):
        pts = (int(cx + x * s), int(y * s)), (int(ax * s), int(ay * s))
        cv2.ellipse(mask, pts[0], pts[1], angle, 0, 360, 1, -1)

    ell(0, 45, 9, 11)  # head
    ell(0, 95, 22, 38)  # torso
    ell(-30, 95, 6, 30, 15)  # arms
    ell(30, 95, 6, 30, -15)
    ell(-11, 170, 9, 45, 3)  # legs
    ell(11, 170, 9, 45, -3)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    depth = 2.5 + 0.1 * np.cos((xx - cx) / (30 * s)) + 0.002 * (yy - height / 2) / s
    return (depth * mask).astype(np.float32), mask.astype(bool)
