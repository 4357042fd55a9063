"""Built-in motion source: joint-limit-aware random poses and a few parametric motions.

With no mocap data (a fresh machine without ``../shared``) the synthesis pipeline still has
varied, plausible poses: walk, wave, squat, kick, arm crossing and turning in place, plus
random poses drawn inside the joint limits with a bias towards relaxed angles.

Poses are in the *world* frame: y up, floor at y = 0, the person facing +z at the origin;
root rotation zero means upright. :func:`ground_poses` puts the lower foot on the floor.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions

__all__ = ["MOTIONS", "motion_poses", "random_poses", "ground_poses", "procedural_sequences"]

D = {n: i for i, n in enumerate(sk.DOF_NAMES)}
_LIM = sk.DOF_LIMITS


def _blank(frames: int) -> np.ndarray:
    return np.zeros((frames, sk.NUM_DOFS))


def _walk(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    f = rng.uniform(0.8, 1.1)  # strides per second
    ph = 2 * math.pi * f * t
    amp = rng.uniform(0.35, 0.55)
    q = _blank(len(t))
    q[:, D["l_femur_flex"]] = amp * np.sin(ph)
    q[:, D["r_femur_flex"]] = -amp * np.sin(ph)
    q[:, D["l_tibia_flex"]] = 0.6 * np.clip(np.sin(ph - 1.2), 0, None) + 0.1
    q[:, D["r_tibia_flex"]] = 0.6 * np.clip(-np.sin(ph - 1.2), 0, None) + 0.1
    q[:, D["l_humerus_flex"]] = -0.6 * amp * np.sin(ph)
    q[:, D["r_humerus_flex"]] = 0.6 * amp * np.sin(ph)
    q[:, D["l_radius_flex"]] = q[:, D["r_radius_flex"]] = 0.3
    q[:, D["lower_back_y"]] = 0.08 * np.sin(ph)
    q[:, 2] = rng.uniform(0.5, 1.3) * t  # forward progress
    return q


def _wave(t, rng):
    q = _blank(len(t))
    side = rng.choice(["l", "r"])
    q[:, D[f"{side}_humerus_abd"]] = rng.uniform(2.0, 2.6)
    q[:, D[f"{side}_humerus_flex"]] = 0.3
    q[:, D[f"{side}_radius_flex"]] = 0.9 + 0.5 * np.sin(2 * math.pi * rng.uniform(1.5, 2.5) * t)
    q[:, D["head_z"]] = 0.1
    return q


def _squat(t, rng):
    q = _blank(len(t))
    depth = rng.uniform(0.6, 1.0) * 0.5 * (1 - np.cos(2 * math.pi * rng.uniform(0.3, 0.5) * t))
    for s in "lr":
        q[:, D[f"{s}_femur_flex"]] = 1.7 * depth
        q[:, D[f"{s}_tibia_flex"]] = 2.0 * depth
        q[:, D[f"{s}_humerus_flex"]] = 1.4 * depth
    q[:, D["lower_back_x"]] = 0.5 * depth
    return q


def _kick(t, rng):
    q = _blank(len(t))
    s = rng.choice(["l", "r"])
    o = "r" if s == "l" else "l"
    k = np.clip(np.sin(2 * math.pi * rng.uniform(0.5, 0.8) * t), 0, None) ** 2
    q[:, D[f"{s}_femur_flex"]] = rng.uniform(1.0, 1.6) * k
    q[:, D[f"{s}_tibia_flex"]] = 1.2 * (1 - k) * (k > 0.05)
    q[:, D[f"{o}_tibia_flex"]] = 0.15
    q[:, D["l_humerus_abd"]] = q[:, D["r_humerus_abd"]] = 0.4
    q[:, D["lower_back_x"]] = -0.2 * k
    return q


def _arm_cross(t, rng):
    q = _blank(len(t))
    c = 0.5 * (1 - np.cos(2 * math.pi * rng.uniform(0.25, 0.5) * t))
    for s in "lr":
        q[:, D[f"{s}_humerus_flex"]] = 1.3 * c
        q[:, D[f"{s}_humerus_abd"]] = -0.6 * c
        q[:, D[f"{s}_radius_flex"]] = 1.6 * c
        q[:, D[f"{s}_humerus_twist"]] = 0.3 * c
    return q


def _turn(t, rng):
    q = _walk(t, rng) * 0.3
    q[:, 0:3] = 0.0
    q[:, D["root_ry"]] = rng.choice([-1, 1]) * rng.uniform(0.8, 2.0) * t
    return q


def _t_pose(t, rng):
    """Wei's calibration reference pose held (arms out sideways, legs apart), slight sway."""
    q = _blank(len(t))
    sway = 0.03 * np.sin(2 * math.pi * 0.3 * t + rng.uniform(0, 2 * math.pi))
    for s in "lr":
        q[:, D[f"{s}_humerus_abd"]] = math.radians(90.0) + sway
        q[:, D[f"{s}_femur_abd"]] = math.radians(12.0)
    return q


MOTIONS: dict[str, Callable[[np.ndarray, np.random.Generator], np.ndarray]] = {
    "walk": _walk,
    "wave": _wave,
    "squat": _squat,
    "kick": _kick,
    "arm_cross": _arm_cross,
    "turn": _turn,
    "t_pose": _t_pose,
}


def motion_poses(name: str, frames: int, fps: float, rng: np.random.Generator) -> np.ndarray:
    """World-frame poses of parametric motion ``name``: (F, 34), clamped to the limits."""
    if name not in MOTIONS:
        raise ValueError(f"unknown motion '{name}'; known: {', '.join(MOTIONS)}")
    q = MOTIONS[name](np.arange(frames) / fps, rng)
    q[:, 6:] = np.clip(q[:, 6:], _LIM[6:, 0], _LIM[6:, 1])
    return q


def random_poses(count: int, rng: np.random.Generator, spread: float = 0.6) -> np.ndarray:
    """Independent random poses inside the joint limits, biased towards relaxed angles.

    Each joint angle is ``limit * spread * beta`` on the side of zero it falls, with a Beta
    distribution peaked near zero, so extreme angles are rare but reachable. Root yaw is
    uniform; root pitch/roll small. Returns (count, 34) world-frame poses.
    """
    q = np.zeros((count, sk.NUM_DOFS))
    lo, hi = _LIM[6:, 0], _LIM[6:, 1]
    mag = rng.beta(1.2, 2.5, size=(count, 28)) * spread
    side = rng.random((count, 28)) < hi / np.maximum(hi - lo, 1e-9)
    q[:, 6:] = np.where(side, hi * mag, lo * mag)
    yaw = rng.uniform(-math.pi, math.pi, count)
    tilt = rng.normal(0.0, 0.08, size=(count, 2))
    q[:, 3:6] = np.stack([tilt[:, 0], yaw, tilt[:, 1]], 1)
    return q


def ground_poses(q: np.ndarray, body: BodyShape) -> np.ndarray:
    """Shift each pose vertically so the lower sole touches the floor (y = 0).

    The sole is approximated by the ankle minus the shank's foot extent.
    """
    qt = torch.as_tensor(q, dtype=torch.float64)
    b = body.to(torch.float64)
    joints = named_joint_positions(forward_kinematics(qt, b)).numpy()
    ankles = joints[:, [sk.JOINT_NAMES.index("l_ankle"), sk.JOINT_NAMES.index("r_ankle")], 1]
    sole = ankles.min(1) - float(b.extents[13, 1])
    out = q.copy()
    out[:, 1] -= sole
    return out


def procedural_sequences(
    rng: np.random.Generator, fps: float = 30.0, seconds: float = 4.0, body: BodyShape | None = None
) -> dict[str, np.ndarray]:
    """One grounded world-frame sequence per parametric motion: name -> (F, 34)."""
    body = BodyShape.default(torch.float64) if body is None else body
    frames = int(round(fps * seconds))
    return {n: ground_poses(motion_poses(n, frames, fps, rng), body) for n in MOTIONS}
