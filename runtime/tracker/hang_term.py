"""A hidden arm hangs: pull an arm that neither the model nor the camera shows towards gravity.

Not in Wei. When the model's rendering shows (almost) none of an arm, no data term constrains
its angles; the constant-acceleration prior then carries it on at whatever velocity it had,
and in profile (grabHigh, the far arm behind the torso) it ends bent behind the back or across
the chest, 20-40 cm from the truth. Measured on the 39 dev takes (docs/experiments.md): the
dev actor's fully hidden arms hang within 5-16 degrees of vertical in grabHigh, and replacing
the track's hidden arms by a straight hanging one put 37 of 87 bad arm-frames within 20 cm
while breaking 6.

For each bone b of a hidden arm (upper arm, forearm) the residual is ``r_b = d - u_b``: the
unit bone direction ``u_b`` against gravity's direction ``d``, both in camera frame (about
the angle between them, in radians). Only the arm's own angles move it (humerus abduction,
flexion and twist for both bones, elbow flexion for the forearm); a revolute DoF with world
axis ``a`` turns ``u_b`` by ``a x u_b``, which is its Jacobian column. The torso's angles are
left out on purpose: the pull must hang the arm, not bend the spine to do it.
"""

from __future__ import annotations

import torch

from shared import skeleton as sk
from shared.body import BodyShape
from shared.camera import Intrinsics

from .signals import LIMB_SEGMENTS, limb_visibility

__all__ = ["ARM_DOFS", "hidden_arms", "hang_residuals", "hang_system"]

# (side, DoF indices moving the upper arm, DoF index of the elbow) for the left and right arm.
ARM_DOFS: tuple[tuple[tuple[int, ...], int], ...] = tuple(
    (
        tuple(sk.DOF_NAMES.index(f"{side}_humerus_{n}") for n in ("abd", "flex", "twist")),
        sk.DOF_NAMES.index(f"{side}_radius_flex"),
    )
    for side in "lr"
)


def hidden_arms(render, intr: Intrinsics, body: BodyShape, visibility: float) -> torch.Tensor:
    """Which arms the rendering hides: (B, 2) bool, left then right.

    An arm is hidden when its visible fraction (:func:`limb_visibility`) is below
    ``visibility``.
    """
    return limb_visibility(render, intr, body)[:, :2] < visibility


def _bone_directions(kin) -> torch.Tensor:
    """Unit directions of each arm's upper arm and forearm: (B, 2, 2, 3) (arm, bone, xyz)."""
    axis = torch.as_tensor(sk.SEGMENT_AXIS, dtype=kin.rotations.dtype, device=kin.rotations.device)
    segs = torch.as_tensor(LIMB_SEGMENTS[:2], device=kin.rotations.device)  # (2, 2)
    u = (kin.rotations[:, segs] @ axis[segs][..., None])[..., 0]
    return u / u.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def hang_residuals(kin, down: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Residuals ``d - u_b`` and their Jacobians in the arm's own DoFs.

    Args:
        kin: forward kinematics of B poses.
        down: (3,) gravity's direction in camera frame (normalized here).
    Returns:
        residual (B, 2, 2, 3) (arm, bone, xyz) and jacobian (B, 2, 2, 3, 4): columns for the
        humerus abduction, flexion, twist and the elbow flexion, in ``ARM_DOFS`` order.
    """
    d = down.to(kin.rotations) / down.to(kin.rotations).norm().clamp_min(1e-12)
    u = _bone_directions(kin)
    cols = torch.as_tensor(
        [list(h) + [e] for h, e in ARM_DOFS], device=kin.rotations.device
    )  # (2, 4)
    axes = kin.dof_axes[:, cols]  # (B, 2, 4, 3)
    jac = torch.linalg.cross(axes[:, :, None], u[:, :, :, None], dim=-1)  # (B, 2, 2, 4, 3)
    # The elbow does not move the upper arm.
    moves = torch.ones(2, 4, dtype=u.dtype, device=u.device)
    moves[0, 3] = 0.0
    jac = jac * moves[None, None, :, :, None]
    return d - u, jac.transpose(-1, -2)


def hang_system(
    kin, down: torch.Tensor, active: torch.Tensor, sigma: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The pull's contribution to the normal equations and its energy.

    Args:
        kin: forward kinematics of B poses.
        down: (3,) gravity's direction in camera frame.
        active: (B, 2) bool, the arms to pull (left, right); the others add nothing.
        sigma: noise scale of a bone's direction (about radians).
    Returns:
        hessian (B, 34, 34) w^2 J^T J, right-hand side (B, 34) w^2 J^T r, energy (B,)
        sum (w r)^2, all float64.
    """
    res, jac = hang_residuals(kin, down)
    w = active.to(res.dtype)[:, :, None, None] / sigma  # (B, 2, 1, 1)
    res = (res * w).double().reshape(res.shape[0], 2, 6)
    jac = (jac * w[..., None]).double().reshape(res.shape[0], 2, 6, 4)
    B = res.shape[0]
    hess = res.new_zeros(B, sk.NUM_DOFS, sk.NUM_DOFS)
    grad = res.new_zeros(B, sk.NUM_DOFS)
    for arm, (humerus, elbow) in enumerate(ARM_DOFS):
        idx = torch.as_tensor(list(humerus) + [elbow], device=res.device)
        jt = jac[:, arm].transpose(-1, -2)  # (B, 4, 6)
        hess[:, idx[:, None], idx[None, :]] += jt @ jac[:, arm]
        grad[:, idx] += (jt @ res[:, arm, :, None])[..., 0]
    return hess, grad, (res * res).sum((-1, -2))
