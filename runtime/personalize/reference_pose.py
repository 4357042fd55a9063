"""Where the shape fit starts: the reference calibration pose the user holds for both views,
and an average adult phenotype."""

from __future__ import annotations

import math

import numpy as np
import torch
from depthmocap.shared import skeleton as sk

__all__ = ["CALIBRATION_POSE_DEG", "INITIAL_PHENOTYPE", "calibration_pose", "initial_pose"]

# The reference pose the user is asked to hold for both views: arms lowered sideways (about
# 40 degrees from the body, so that they stay apart from the trunk in depth) and feet slightly
# apart; every other angle zero.
CALIBRATION_POSE_DEG: dict[str, float] = {
    "l_humerus_abd": 40.0,
    "r_humerus_abd": 40.0,
    "l_femur_abd": 6.0,
    "r_femur_abd": 6.0,
}
# Start of the shape search: an average adult (anny age 0.8 is about 40 years, height 0.4
# about 1.70 m), halfway between the male (0) and female (1) targets.
INITIAL_PHENOTYPE = (0.5, 0.8, 0.5, 0.5, 0.4, 0.5)
# Root rotation vectors: facing the camera upright, and turned by 180 degrees about the vertical.
_FACING = {"front": (math.pi, 0.0, 0.0), "back": (0.0, 0.0, math.pi)}


def calibration_pose(view: str = "front", root_position=(0.0, 0.0, 2.5)) -> np.ndarray:
    """The reference calibration pose (:data:`CALIBRATION_POSE_DEG`) for a view: (34,)."""
    if view not in _FACING:
        raise ValueError(f"view must be 'front' or 'back', got {view!r}")
    q = np.zeros(sk.NUM_DOFS)
    q[0:3] = root_position
    q[3:6] = _FACING[view]
    for name, deg in CALIBRATION_POSE_DEG.items():
        q[sk.DOF_NAMES.index(name)] = math.radians(deg)
    return q


def initial_pose(points: torch.Tensor, view: str) -> torch.Tensor:
    """Calibration pose with the hip centre behind the centroid of the view's points: (34,).

    The visible surface lies about 10 cm in front of the body's axis; the hip centre sits
    at about 52% of the cloud's height from its bottom (y down in the camera frame).
    """
    centre = points.mean(0)
    lo, hi = points[:, 1].min(), points[:, 1].max()
    root = torch.stack([centre[0], hi - 0.52 * (hi - lo), centre[2] + 0.1])
    return torch.as_tensor(calibration_pose(view, root.tolist()), dtype=torch.float64)
