"""The shoulder's second Euler branch: leave a joint limit without moving the arm.

Each upper arm turns by ``R_a(abd) R_b(flex) R_c(twist)`` about three orthogonal axes, and such
a product equals ``R_a(abd + pi) R_b(pi - flex) R_c(twist + pi)``. The limits (abduction -45 to
180 degrees, flexion -70 to 180) admit both forms for an arm raised overhead. Passing the
gimbal lock (flexion 90: arm straight ahead) the tracker may pick the other form, and when the
arm then comes down along a path that form cannot follow inside its limits, Gauss-Newton stays
pinned at the limits (rotateArms: flexion 180 and abduction -45 for 20 frames while the true arm
sweeps down sideways).

Before each frame the tracker therefore moves a shoulder to its other form when that form is
farther from the limits and, once clamped into them, turns the upper arm by less than
``max_turn`` radians; and it writes the frame before in the same form as the previous one, so
the constant-velocity prediction compares like with like.
"""

from __future__ import annotations

import math

import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.kinematics import clamp_to_limits
from depthmocap.shared.so3 import rotvec_to_matrix

__all__ = [
    "SHOULDER_DOFS",
    "other_branch",
    "shoulder_rotations",
    "move_to_roomier_branch",
    "align_branch",
]

# (2 sides, 3 angles: abduction, flexion, twist)
SHOULDER_DOFS = torch.tensor(
    [[sk.DOF_NAMES.index(f"{s}_humerus_{a}") for a in ("abd", "flex", "twist")] for s in "lr"]
)
_SIGN = (1.0, -1.0, 1.0)  # (abd, flex, twist) -> (abd + pi, pi - flex, twist + pi)
_ROOM_CAP = 0.5  # radians of distance to a limit that still count as room


def _wrap(a: torch.Tensor) -> torch.Tensor:
    return torch.remainder(a + math.pi, 2 * math.pi) - math.pi


def other_branch(q: torch.Tensor) -> torch.Tensor:
    """The same poses (B, 34) with both shoulders in their other Euler form, in [-pi, pi)."""
    idx = SHOULDER_DOFS.to(q.device)
    out = q.clone()
    out[:, idx] = _wrap(q.new_tensor(_SIGN) * q[:, idx] + math.pi)
    return out


def shoulder_rotations(q: torch.Tensor) -> torch.Tensor:
    """Each upper arm's Euler rotation ``R_a R_b R_c`` (no clavicle): (B, 2, 3, 3)."""
    idx = SHOULDER_DOFS.to(q.device)
    axes = torch.as_tensor(sk.DOF_AXIS, dtype=q.dtype, device=q.device)[idx]  # (2, 3, 3)
    rot = rotvec_to_matrix(axes * q[:, idx, None])  # (B, 2, 3, 3, 3)
    return rot[:, :, 0] @ rot[:, :, 1] @ rot[:, :, 2]


def _room(q: torch.Tensor) -> torch.Tensor:
    """(B, 2) summed distance of each shoulder's angles to their limits, each capped."""
    idx = SHOULDER_DOFS.to(q.device)
    lim = torch.as_tensor(sk.DOF_LIMITS, dtype=q.dtype, device=q.device)[idx]  # (2, 3, 2)
    a = q[:, idx]
    return torch.minimum(a - lim[..., 0], lim[..., 1] - a).clamp(0.0, _ROOM_CAP).sum(-1)


def move_to_roomier_branch(
    q: torch.Tensor, max_turn: float = 0.7, min_gain: float = 0.2
) -> torch.Tensor:
    """Move each shoulder to its other form where that form, clamped into the limits, has at
    least ``min_gain`` radians more room and turns the upper arm by less than ``max_turn``.

    Args:
        q: (B, 34) poses inside the joint limits.
    Returns:
        (B, 34).
    """
    room = _room(q)
    # Most frames have both arms clear of every limit, and the other form's room cannot
    # exceed the capped most (three caps): nothing can move, so its rotations are skipped.
    if bool((room + min_gain >= 3 * _ROOM_CAP).all()):
        return q.clone()
    return _move_where_roomier(q, room, max_turn, min_gain)


def _move_where_roomier(
    q: torch.Tensor, room: torch.Tensor, max_turn: float, min_gain: float
) -> torch.Tensor:
    """:func:`move_to_roomier_branch` without its shortcut; ``room``: ``_room(q)`` (B, 2)."""
    other = clamp_to_limits(other_branch(q))
    rel = shoulder_rotations(other) @ shoulder_rotations(q).transpose(-1, -2)
    cos = ((rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0).clamp(-1.0, 1.0)
    move = (torch.acos(cos) < max_turn) & (_room(other) > room + min_gain)  # (B, 2)
    idx = SHOULDER_DOFS.to(q.device)
    out = q.clone()
    out[:, idx] = torch.where(move[..., None], other[:, idx], q[:, idx])
    return out


def align_branch(q: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """``q`` with each shoulder written in the form whose angles are nearer ``like``'s (the
    other form is unwrapped next to ``like``), so differences between them are motions."""
    idx = SHOULDER_DOFS.to(q.device)
    other = other_branch(q)[:, idx]
    ref = like[:, idx]
    other = ref + _wrap(other - ref)
    same = ref + _wrap(q[:, idx] - ref)
    use_other = (other - ref).norm(dim=-1) < (same - ref).norm(dim=-1)
    out = q.clone()
    out[:, idx] = torch.where(use_other[..., None], other, q[:, idx])
    return out
