"""Turning the whole body about its own spine: the starts of the hybrid's turn search.

Near profile, a torso turned a little towards the camera and one turned a little away show
nearly the same silhouette, and the tracker, started from the last pose, follows whichever
way the data tips it first. On a turning runner (jog, 4 m away) it turned the model away while
the person turned towards the camera; the far shoulder ended 30 cm off while every failure
test still passed. When a fit is suspect the hybrid refines the frame from the pose turned
about the spine by a few angles each way (:func:`turn_candidates`) and keeps the best fit.
"""

from __future__ import annotations

import math

import torch

from shared import skeleton as sk
from shared.body import BodyShape
from shared.kinematics import forward_kinematics, named_joint_positions, transform_pose
from shared.so3 import axis_angle_to_matrix

__all__ = ["TURN_DEG", "turn_candidates"]

# Turns tried, degrees about the spine (pelvis to neck); 0 is the tracker's own result.
TURN_DEG: tuple[float, ...] = (-40.0, -20.0, 20.0, 40.0)


def turn_candidates(
    q: torch.Tensor, body: BodyShape, angles_deg: tuple[float, ...] = TURN_DEG
) -> torch.Tensor:
    """``q`` (34,) turned rigidly about its spine axis through the root: (K, 34).

    The axis runs from the pelvis joint to the neck joint of ``q`` (the body's own up, not
    the camera's, so a tilted camera or a leaning person turns correctly); the root position
    stays and every joint angle keeps its value.
    """
    q1 = q.detach().reshape(1, sk.NUM_DOFS)
    joints = named_joint_positions(forward_kinematics(q1, body.to(dtype=q1.dtype)))[0]
    up = joints[sk.JOINT_NAMES.index("neck")] - joints[sk.JOINT_NAMES.index("pelvis")]
    up = up / up.norm().clamp_min(1e-9)
    angles = q1.new_tensor([math.radians(a) for a in angles_deg])
    rot = axis_angle_to_matrix(up.expand(len(angles_deg), 3), angles)  # (K, 3, 3)
    root = q1[0, 0:3]
    shift = root - (rot @ root)  # keeps the root where it is
    return transform_pose(q1.expand(len(angles_deg), -1), rot, shift)
