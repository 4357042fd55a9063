"""Batched forward kinematics, point Jacobians and the pose update of the tracking skeleton.

The tracker's core (Wei section 3, appendix A) needs, for a point ``p = f(q; k, p0)`` fixed
on segment k, the Jacobian dp/dq. Every angular DoF d is a revolute joint with world axis
``a_d`` through the joint centre ``o_d``, so its column is ``a_d x (p - o_d)`` whenever d lies
on the chain from the root to k, and zero otherwise; root translations give the identity.

Root orientation is perturbed on SO(3) from the left: its three Jacobian columns are the
derivatives with respect to ``w`` in ``R <- exp(w) R``, and :func:`pose_update` applies an
increment the same way, so Gauss-Newton never meets gimbal lock at the root.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from . import skeleton as sk
from .body import BodyShape
from .so3 import axis_angle_to_matrix, compose_rotvec, rotvec_to_matrix

__all__ = [
    "Kinematics",
    "forward_kinematics",
    "segment_points_to_world",
    "named_joint_positions",
    "point_jacobian",
    "pose_update",
    "clamp_to_limits",
    "rest_pose",
]


@dataclass
class Kinematics:
    """Result of forward kinematics for B poses.

    Attributes:
        rotations: (B, 15, 3, 3) segment frames (segment -> camera).
        origins: (B, 15, 3) segment origins (joint centres) in camera frame.
        dof_axes: (B, 34, 3) world axis of each DoF (root translations: camera axes).
        dof_origins: (B, 34, 3) point each rotational DoF turns about.
        lengths: (B, 15) segment lengths of the body used.
    """

    rotations: torch.Tensor
    origins: torch.Tensor
    dof_axes: torch.Tensor
    dof_origins: torch.Tensor
    lengths: torch.Tensor


def _const(array, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(array, dtype=like.dtype, device=like.device)


def _index(array, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(array, dtype=torch.long, device=like.device)


def forward_kinematics(q: torch.Tensor, body: BodyShape) -> Kinematics:
    """Segment frames and DoF axes for poses ``q``.

    Args:
        q: (B, 34) poses (layout in :mod:`shared.skeleton`).
        body: body parameters, unbatched or with batch B.
    Returns:
        :class:`Kinematics` with batch B, same dtype/device as ``q``.
    """
    if q.dim() != 2 or q.shape[-1] != sk.NUM_DOFS:
        raise ValueError(f"q must have shape (B, {sk.NUM_DOFS}), got {tuple(q.shape)}")
    B, K = q.shape[0], sk.NUM_SEGMENTS
    lengths = body.lengths.to(q).expand(B, K)
    hip = body.hip_half_width.to(q).expand(B)

    # Local joint rotations: every angular DoF at once, then the (up to 3) per joint composed.
    dof_rot = axis_angle_to_matrix(_const(sk.DOF_AXIS[6:], q), q[:, 6:])  # (B, 28, 3, 3)
    eye = torch.eye(3, dtype=q.dtype, device=q.device).expand(B, 1, 3, 3)
    padded = torch.cat([dof_rot, eye], 1)  # index 28 = identity for unused slots
    slots = _index(sk.SEGMENT_DOF_SLOTS, q)
    slots = torch.where(slots >= 6, slots - 6, torch.full_like(slots, 28))
    r1, r2, r3 = (padded[:, slots[:, i]] for i in range(3))  # (B, 15, 3, 3) each
    prefix1 = r1
    prefix2 = r1 @ r2
    local = prefix2 @ r3
    root_rot = rotvec_to_matrix(q[:, 3:6])
    local = torch.cat([root_rot[:, None], local[:, 1:]], 1)

    # Joint offsets in the parent frame.
    parent = _index(sk.SEGMENT_PARENT.clip(min=0), q)
    axis = _const(sk.SEGMENT_AXIS, q)
    offsets = (_const(sk.SEGMENT_ATTACH_END, q) * lengths[:, parent])[..., None] * axis[parent]
    lateral = _const(sk.SEGMENT_LATERAL, q)[None, :] * hip[:, None]
    offsets = offsets + lateral[..., None] * _const([1.0, 0.0, 0.0], q)

    rotations = torch.empty(B, K, 3, 3, dtype=q.dtype, device=q.device)
    origins = torch.empty(B, K, 3, dtype=q.dtype, device=q.device)
    rotations[:, 0] = local[:, 0]
    origins[:, 0] = q[:, 0:3]
    for level in sk.SEGMENT_LEVELS[1:]:
        idx = _index(level, q)
        par = parent[idx]
        r_par = rotations[:, par]
        rotations[:, idx] = r_par @ local[:, idx]
        origins[:, idx] = origins[:, par] + (r_par @ offsets[:, idx, :, None])[..., 0]

    # World axes of the angular DoFs: parent frame, then the rotations earlier in the joint.
    dof_seg = _index(sk.DOF_SEGMENT[6:], q)
    dof_slot = _index(sk.DOF_SLOT[6:], q)
    prefixes = torch.stack([eye.expand(B, K, 3, 3), prefix1, prefix2], 2)  # (B, 15, 3, 3, 3)
    pre = prefixes[:, dof_seg, dof_slot]  # (B, 28, 3, 3)
    r_par = rotations[:, parent[dof_seg]]
    ang_axes = (r_par @ pre @ _const(sk.DOF_AXIS[6:], q)[..., None])[..., 0]
    root_axes = _const(sk.DOF_AXIS[:6], q).expand(B, 6, 3)
    dof_axes = torch.cat([root_axes, ang_axes], 1)
    dof_origins = origins[:, _index(sk.DOF_SEGMENT, q)]
    return Kinematics(rotations, origins, dof_axes, dof_origins, lengths)


def segment_points_to_world(
    kin: Kinematics, local_points: torch.Tensor, segment: torch.Tensor
) -> torch.Tensor:
    """Camera-frame positions of points given in their segment's frame.

    Args:
        kin: kinematics with batch B.
        local_points: (B, N, 3) coordinates in the frame of ``segment``.
        segment: (B, N) or (N,) segment index of each point.
    Returns:
        (B, N, 3).
    """
    B = kin.rotations.shape[0]
    seg = segment.expand(B, -1) if segment.dim() == 1 else segment
    b = torch.arange(B, device=seg.device)[:, None]
    rot = kin.rotations[b, seg]  # (B, N, 3, 3)
    return (rot @ local_points[..., None])[..., 0] + kin.origins[b, seg]


def named_joint_positions(kin: Kinematics) -> torch.Tensor:
    """Named output joints (``skeleton.JOINT_NAMES``) in camera frame: (B, J, 3)."""
    like = kin.origins
    seg = _index(sk.JOINT_SEGMENT, like)
    frac = _const(sk.JOINT_FRACTION, like)
    local = (frac * kin.lengths[:, seg])[..., None] * _const(sk.SEGMENT_AXIS, like)[seg]
    return segment_points_to_world(kin, local, seg)


def point_jacobian(kin: Kinematics, points: torch.Tensor, segment: torch.Tensor) -> torch.Tensor:
    """Jacobian dp/dq of camera-frame points rigidly attached to segments.

    Args:
        kin: kinematics with batch B.
        points: (B, N, 3) current camera-frame positions.
        segment: (B, N) or (N,) segment each point is fixed on.
    Returns:
        (B, N, 3, 34); root-orientation columns are w.r.t. the left SO(3) increment.
    """
    B, N = points.shape[:2]
    seg = segment.expand(B, -1) if segment.dim() == 1 else segment
    affects = torch.as_tensor(sk.DOF_AFFECTS_SEGMENT, device=points.device)[seg]  # (B, N, 34)
    arm = points[:, :, None, :] - kin.dof_origins[:, None, 3:, :]  # (B, N, 31, 3)
    axes = kin.dof_axes[:, None, 3:, :].expand_as(arm)
    rot_cols = torch.linalg.cross(axes, arm, dim=-1)
    trans_cols = torch.eye(3, dtype=points.dtype, device=points.device).expand(B, N, 3, 3)
    cols = torch.cat([trans_cols, rot_cols], 2) * affects[..., None].to(points.dtype)
    return cols.transpose(-1, -2)


def pose_update(q: torch.Tensor, dq: torch.Tensor) -> torch.Tensor:
    """Gauss-Newton step ``q (+) dq``: additive except the root, ``R <- exp(dw) R``.

    Args:
        q, dq: (B, 34).
    Returns:
        (B, 34).
    """
    root = compose_rotvec(dq[:, 3:6], q[:, 3:6])
    return torch.cat([q[:, :3] + dq[:, :3], root, q[:, 6:] + dq[:, 6:]], 1)


def clamp_to_limits(q: torch.Tensor) -> torch.Tensor:
    """Joint angles clamped into their limits; root untouched. (B, 34) -> (B, 34)."""
    lim = _const(sk.DOF_LIMITS, q)
    return torch.maximum(torch.minimum(q, lim[:, 1]), lim[:, 0])


def rest_pose(
    batch: int = 1,
    root_position=(0.0, 0.0, 2.5),
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """Upright rest pose facing the camera at ``root_position`` (metres): (B, 34)."""
    q = torch.zeros(batch, sk.NUM_DOFS, dtype=dtype, device=device)
    q[:, 0:3] = torch.as_tensor(root_position, dtype=dtype, device=device)
    q[:, 3:6] = torch.as_tensor(sk.FACING_CAMERA_ROTVEC, dtype=dtype, device=device)
    return q
