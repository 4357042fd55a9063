"""Constant-acceleration prior (Wei eq. 7, 12, 18): ``q ~ 2 q_prev - q_prev2``.

Its Jacobian is the identity (root rotation: the left SO(3) increment), so it enters the
normal equations as a diagonal; angles and the root position get separate noise scales
because q mixes radians and metres.
"""

from __future__ import annotations

import torch
from depthmocap.shared.kinematics import clamp_to_limits
from depthmocap.shared.so3 import (
    quaternion_conjugate,
    quaternion_multiply,
    quaternion_to_rotvec,
    rotvec_to_quaternion,
)

__all__ = [
    "MAX_VELOCITY_SCALE",
    "predict_pose",
    "prior_residual",
    "prior_system",
    "prior_weights",
    "velocity_scale",
]


def predict_pose(
    q_prev: torch.Tensor, q_prev2: torch.Tensor | None, velocity_gain: float = 1.0
) -> torch.Tensor:
    """Prediction ``q_prev + g (q_prev - q_prev2)`` (root rotation on SO(3)): (B, 34).

    ``g = 1`` is Wei's constant velocity (the prior then penalizes acceleration); ``g < 1``
    lets velocity decay, so degrees of freedom the data hardly constrain (a cylinder's twist)
    do not keep drifting at the velocity they once had. Without ``q_prev2`` the prediction is
    ``q_prev`` (zero velocity).
    """
    if q_prev2 is None or velocity_gain == 0.0:
        return q_prev.clone()
    pred = q_prev + velocity_gain * (q_prev - q_prev2)
    r1, r2 = rotvec_to_quaternion(q_prev[:, 3:6]), rotvec_to_quaternion(q_prev2[:, 3:6])
    step = quaternion_to_rotvec(quaternion_multiply(r1, quaternion_conjugate(r2)))
    step = rotvec_to_quaternion(step * velocity_gain)
    pred[:, 3:6] = quaternion_to_rotvec(quaternion_multiply(step, r1))
    return clamp_to_limits(pred)


def prior_residual(q: torch.Tensor, q_pred: torch.Tensor) -> torch.Tensor:
    """``q_pred (-) q`` in the update's coordinates (root: the left increment taking q there).

    The root part is ``sin(angle) * axis`` of ``R_pred R^T`` (the vee of its antisymmetric
    part): the rotation vector to first order, exact in direction, and a fraction of the cost
    of the logarithm; prior residuals are per-frame accelerations, i.e. small angles.
    """
    res = q_pred - q
    # R_pred R^T as the quaternion (cos(a/2), sin(a/2) axis): sin(a) axis = 2 w v, whatever
    # the quaternion's sign.
    rel = quaternion_multiply(
        rotvec_to_quaternion(q_pred[:, 3:6]), quaternion_conjugate(rotvec_to_quaternion(q[:, 3:6]))
    )
    res[:, 3:6] = 2.0 * rel[:, :1] * rel[:, 1:]
    return res


def prior_weights(like: torch.Tensor, sigma_rad: float, sigma_m: float) -> torch.Tensor:
    """Per-DoF prior weights ``1 / sigma`` (B, 34) in ``like``'s dtype: ``sigma_m`` for the
    root position, ``sigma_rad`` for the rest."""
    w = torch.full_like(like, 1.0 / sigma_rad)
    w[:, 0:3] = 1.0 / sigma_m
    return w


def prior_system(
    q: torch.Tensor, q_pred: torch.Tensor, sigma_rad: float, sigma_m: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Prior contribution to the normal equations and its energy.

    Returns:
        diagonal (B, 34) of w^2, right-hand side (B, 34) w^2 r, energy (B,) sum (w r)^2.
    """
    w = prior_weights(q, sigma_rad, sigma_m)
    res = prior_residual(q, q_pred)
    w2 = w * w
    return w2, w2 * res, (w2 * res * res).sum(-1)


# The prior extrapolates at most this many inter-pose intervals ahead: after a long stall the
# last velocity says little about where the person is now.
MAX_VELOCITY_SCALE = 4.0


def velocity_scale(index: int, index_prev: int | None, index_prev2: int | None) -> float:
    """How far ahead the constant-velocity prior should predict, in units of the last two
    poses' interval: ``(index - index_prev) / (index_prev - index_prev2)``, at most
    :data:`MAX_VELOCITY_SCALE`; 1 when either index is unknown or the interval is not
    positive. A file keeps every frame (1 always: Wei's prior, bit for bit); a live stream
    keeps the newest, so after two frames skipped the motion since the last pose is three
    frames' worth, not one."""
    if index_prev is None or index_prev2 is None or index_prev <= index_prev2:
        return 1.0
    return min(max(index - index_prev, 0) / (index_prev - index_prev2), MAX_VELOCITY_SCALE)
