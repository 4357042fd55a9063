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

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch
from depthmocap.shared.compiled import compiled_module

from . import skeleton as sk
from .body import BodyShape
from .so3 import compose_rotvec, matrix_to_rotvec, rotvec_to_matrix, skew

__all__ = [
    "Kinematics",
    "forward_kinematics",
    "segment_points_to_world",
    "segment_axis_points",
    "named_joint_positions",
    "point_jacobian",
    "pose_update",
    "clamp_to_limits",
    "rest_pose",
    "transform_pose",
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


# The skeleton's constant arrays as tensors, built once per content, dtype and device: made
# afresh on every call they were a host-to-device copy and a wait for the GPU each (about
# 150 a frame on CUDA, the most of any source: docs/results.md). Callers only read them.
_CONSTANTS: dict[tuple, torch.Tensor] = {}
_MAX_CONSTANTS = 512


def _cached(array, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    a = np.asarray(array)
    key = (a.tobytes(), a.shape, a.dtype.str, dtype, device)
    t = _CONSTANTS.get(key)
    if t is None:
        if len(_CONSTANTS) >= _MAX_CONSTANTS:  # only ever a few dozen; never grow unbounded
            _CONSTANTS.clear()
        # Never an inference tensor, even when first asked for inside torch.inference_mode
        # (runtime-track's estimates): autograd could not save it for backward later on.
        with torch.inference_mode(False):
            t = _CONSTANTS[key] = torch.as_tensor(a, dtype=dtype, device=device)
    return t


def _const(array, like: torch.Tensor) -> torch.Tensor:
    return _cached(array, like.dtype, like.device)


def _index(array, like: torch.Tensor) -> torch.Tensor:
    return _cached(array, torch.long, like.device)


# Internally, 3x3 matrices are stored batch-last as (3, 3, n, B): a product is then 15
# contiguous vector multiply-adds and a gather over n copies whole rows. On the CPU that is
# several times faster than bmm on millions of tiny matrices; it runs unchanged on CUDA.
# A few poses (the tracker's B = 1) are the opposite case: there the 20 small ops cost more
# than one matmul over permuted views (9 us against 50 us for 15 matrices).
_SMALL = 4096


def _mm(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(3, 3, *) @ (3, 3, *) -> (3, 3, *)."""
    if math.prod(a.shape[2:]) <= _SMALL:
        n = a.dim()
        last = (*range(2, n), 0, 1)
        back = (n - 2, n - 1, *range(n - 2))
        return (a.permute(last) @ b.permute(last)).permute(back)
    return torch.stack([a[i, 0] * b[0] + a[i, 1] * b[1] + a[i, 2] * b[2] for i in range(3)])


def _mv(a: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """(3, 3, *) @ (3, *) -> (3, *)."""
    if math.prod(a.shape[2:]) <= _SMALL:
        n = v.dim()
        last = (*range(2, n + 1), 0, 1)
        out = a.permute(last) @ v.permute(*range(1, n), 0)[..., None]
        return out[..., 0].permute(n - 1, *range(n - 1))
    return a[:, 0] * v[0] + a[:, 1] * v[1] + a[:, 2] * v[2]


def _dof_rotations(q: torch.Tensor) -> torch.Tensor:
    """Rotations of the 28 angular DoFs plus an identity at index 28: (3, 3, 29, B)."""
    k = skew(_const(sk.DOF_AXIS[6:], q))  # (28, 3, 3)
    k2 = (k @ k).permute(1, 2, 0)[..., None]
    k = k.permute(1, 2, 0)[..., None]
    angle = q[:, 6:].T
    eye = torch.eye(3, dtype=q.dtype, device=q.device)[:, :, None, None]
    rot = eye + torch.sin(angle) * k + (1.0 - torch.cos(angle)) * k2
    return torch.cat([rot, eye.expand(3, 3, 1, q.shape[0])], 2)


_CHEST = sk.SEGMENT_NAMES.index("chest")
# Position of each level's parents within the level before, and where each segment lands when
# the levels are concatenated (its inverse permutation).
_LEVEL_PARENT_SLOT = [
    [list(prev).index(int(sk.SEGMENT_PARENT[k])) for k in level]
    for prev, level in zip(sk.SEGMENT_LEVELS, sk.SEGMENT_LEVELS[1:])
]
_LEVEL_ORDER = np.argsort(np.concatenate(sk.SEGMENT_LEVELS))


def _tilt_about_x(angle: torch.Tensor) -> torch.Tensor:
    """Rotations about x by ``angle`` (B,), batch-last: (3, 3, B)."""
    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(angle), torch.zeros_like(angle)
    rows = ((one, zero, zero), (zero, c, -s), (zero, s, c))
    return torch.stack([torch.stack(row) for row in rows])


def _clavicle_rest_angles(body: BodyShape, q: torch.Tensor) -> torch.Tensor:
    """(B, 34) the body's clavicle rest angles at the clavicle DoFs, zero elsewhere: FK turns
    each clavicle by its DoFs plus its rest, so joint limits and priors act around the rest."""
    rest = body.clavicle_rest.to(q).expand(q.shape[0], 2).repeat(1, 2)  # (B, 4)
    return torch.zeros_like(q).index_copy(1, _index(sk.CLAVICLE_DOFS, q), rest)


_UPPER_ARMS = [sk.SEGMENT_NAMES.index(n) for n in ("l_upper_arm", "r_upper_arm")]
assert _UPPER_ARMS[1] == _UPPER_ARMS[0] + 1  # adjacent: one block of pre-rotations


def _upper_arm_pre_rotations(body: BodyShape, q: torch.Tensor) -> torch.Tensor:
    """(3, 3, 15, B) the inverse clavicle rest rotation before each upper arm's DoFs, the
    identity elsewhere: the arm hangs from the clavicle's rest direction turned back, so the
    humerus angles (and their limits) mean the same whatever the rest (q = 0: arms straight
    down, an arm raised overhead at 180 degrees)."""
    B = q.shape[0]
    rest = body.clavicle_rest.to(q).expand(B, 2)
    (ce, cp), (se, sp) = torch.cos(rest).T, torch.sin(rest).T
    zero, one = torch.zeros_like(ce), torch.ones_like(ce)
    # Left: R_z(elev) R_-y(prot), written out and transposed; the right side's axes are the
    # mirror images (x, -y, -z), which flips the signs of the mixed x-y and x-z entries.
    left = torch.stack([ce * cp, se * cp, sp, -se, ce, zero, -ce * sp, -se * sp, cp])
    mirror = _const([1.0, -1.0, -1.0, -1.0, 1.0, 1.0, -1.0, 1.0, 1.0], q)[:, None]
    undo = torch.stack([left, left * mirror], 1).reshape(3, 3, 2, B)
    eye = torch.stack([one, zero, zero, zero, one, zero, zero, zero, one]).reshape(3, 3, 1, B)
    first, last = _UPPER_ARMS
    return torch.cat(
        [eye.expand(3, 3, first, B), undo, eye.expand(3, 3, sk.NUM_SEGMENTS - last - 1, B)], 2
    )


def _compiled_kernel():
    """:mod:`shared.kinematics_kernel` (numba's compiled walk), or None without numba."""
    return compiled_module("depthmocap.shared.kinematics_kernel")


def _needs_grad(q: torch.Tensor, body: BodyShape) -> bool:
    """Whether autograd must see the kinematics (the compiled walk is not differentiable)."""
    if not torch.is_grad_enabled():
        return False
    params = (body.lengths, body.hip_half_width, body.chest_tilt, body.clavicle_rest)
    return q.requires_grad or any(p.requires_grad for p in params)


def forward_kinematics(q: torch.Tensor, body: BodyShape) -> Kinematics:
    """Segment frames and DoF axes for poses ``q``.

    Args:
        q: (B, 34) poses (layout in :mod:`shared.skeleton`).
        body: body parameters, unbatched or with batch B.
    Returns:
        :class:`Kinematics` with batch B, same dtype/device as ``q``.

    On the CPU, where nothing needs gradients and numba is installed, a compiled loop computes
    the same frames (:mod:`shared.kinematics_kernel`), 20 times faster for one pose.
    """
    if q.dim() != 2 or q.shape[-1] != sk.NUM_DOFS:
        raise ValueError(f"q must have shape (B, {sk.NUM_DOFS}), got {tuple(q.shape)}")
    kernel = _compiled_kernel() if q.device.type == "cpu" else None
    if kernel is not None and not _needs_grad(q, body):
        return Kinematics(*kernel.forward_kinematics_cpu(q, body))
    B, K = q.shape[0], sk.NUM_SEGMENTS
    lengths = body.lengths.to(q).expand(B, K)
    hip = body.hip_half_width.to(q).expand(B)
    parent = sk.SEGMENT_PARENT

    # Joint offsets in the parent frame, batch-last: (3, 15, B).
    par_idx = _index(parent.clip(min=0), q)
    axis = _const(sk.SEGMENT_AXIS, q)
    offsets = (_const(sk.SEGMENT_ATTACH_END, q) * lengths[:, par_idx])[..., None] * axis[par_idx]
    offsets = offsets + (_const(sk.SEGMENT_LATERAL, q) * hip[:, None])[..., None] * _const(
        [1.0, 0.0, 0.0], q
    )
    offsets = offsets.permute(2, 1, 0)

    # Local joint rotations P R_1 R_2 R_3 (unused slots are the identity; P is the identity but
    # for the upper arms), keeping prefixes.
    dof_rot = _dof_rotations(q + _clavicle_rest_angles(body, q))
    slots = _index(sk.SEGMENT_DOF_SLOTS, q)
    slots = torch.where(slots >= 6, slots - 6, torch.full_like(slots, 28))
    arm_pre = _upper_arm_pre_rotations(body, q)  # (3, 3, 15, B), P in local = P R_1 R_2 R_3
    prefix1 = _mm(arm_pre, dof_rot[:, :, slots[:, 0]])
    prefix2 = _mm(prefix1, dof_rot[:, :, slots[:, 1]])
    local = _mm(prefix2, dof_rot[:, :, slots[:, 2]])
    # The chest has no DoFs: its local rotation is the body's fixed forward lean.
    tilt = _tilt_about_x(body.chest_tilt.to(q).expand(B))[:, :, None]
    local = torch.cat([local[:, :, :_CHEST], tilt, local[:, :, _CHEST + 1 :]], 2)

    # Walk the tree one depth level at a time (every segment of a level in one batched op);
    # each level's parents all sit in the level before (``_LEVEL_PARENT_SLOT``).
    r = rotvec_to_matrix(q[:, 3:6]).permute(1, 2, 0)[:, :, None]  # (3, 3, 1, B)
    t = q[:, 0:3].T[:, None]  # (3, 1, B)
    rots, orgs = [r], [t]
    for level, slot in zip(sk.SEGMENT_LEVELS[1:], _LEVEL_PARENT_SLOT):
        idx, parents = _index(level, q), _index(slot, q)
        r_par, t_par = r[:, :, parents], t[:, parents]
        r = _mm(r_par, local[:, :, idx])
        t = t_par + _mv(r_par, offsets[:, idx])
        rots.append(r)
        orgs.append(t)
    order = _index(_LEVEL_ORDER, q)  # level-major -> segment order
    rotations = torch.cat(rots, 2)[:, :, order]  # (3, 3, 15, B)
    origins = torch.cat(orgs, 1)[:, order]  # (3, 15, B)

    # World axis of the s-th DoF of a joint: R_parent @ P @ (R_1 ... R_(s-1)) @ axis.
    dof_seg = sk.DOF_SEGMENT[6:]
    prefixes = torch.stack([arm_pre, prefix1, prefix2], 2)  # (3, 3, 3, 15, B)
    pre = prefixes[:, :, _index(sk.DOF_SLOT[6:], q), _index(dof_seg, q)]  # (3, 3, 28, B)
    r_par = rotations[:, :, _index(parent[dof_seg], q)]
    local_axes = _const(sk.DOF_AXIS[6:], q).T[:, :, None]  # (3, 28, 1)
    ang_axes = _mv(r_par, _mv(pre, local_axes)).permute(2, 1, 0)  # (B, 28, 3)

    rotations = rotations.permute(3, 2, 0, 1)
    origins = origins.permute(2, 1, 0)
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


def segment_axis_points(
    kin: Kinematics, segment: torch.Tensor, fraction: torch.Tensor
) -> torch.Tensor:
    """Camera-frame points on segments' axes, ``fraction`` (N,) of each ``segment``'s (N,)
    length from its joint: (B, N, 3)."""
    local = (fraction * kin.lengths[:, segment])[..., None]
    local = local * _const(sk.SEGMENT_AXIS, kin.origins)[segment]
    return segment_points_to_world(kin, local, segment)


def named_joint_positions(kin: Kinematics) -> torch.Tensor:
    """Named output joints (``skeleton.JOINT_NAMES``) in camera frame: (B, J, 3)."""
    like = kin.origins
    return segment_axis_points(kin, _index(sk.JOINT_SEGMENT, like), _const(sk.JOINT_FRACTION, like))


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


@functools.cache
def _limits(dtype: torch.dtype, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    lim = torch.as_tensor(sk.DOF_LIMITS, dtype=dtype, device=device)
    return lim[:, 0].contiguous(), lim[:, 1].contiguous()


def clamp_to_limits(q: torch.Tensor) -> torch.Tensor:
    """Joint angles clamped into their limits; root untouched. (B, 34) -> (B, 34)."""
    lower, upper = _limits(q.dtype, q.device)
    return torch.maximum(torch.minimum(q, upper), lower)


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


def transform_pose(
    q: torch.Tensor, rotation: torch.Tensor, translation: torch.Tensor
) -> torch.Tensor:
    """Pose seen from another frame: ``x' = rotation @ x + translation`` applied to the root.

    Args:
        q: (B, 34) poses in the source frame.
        rotation: (3, 3) or (B, 3, 3); translation: (3,) or (B, 3).
    Returns:
        (B, 34) the same body configuration expressed in the target frame.
    """
    rotation = rotation.to(q).expand(q.shape[0], 3, 3)
    translation = translation.to(q).expand(q.shape[0], 3)
    root_pos = (rotation @ q[:, 0:3, None])[..., 0] + translation
    root_rot = matrix_to_rotvec(rotation @ rotvec_to_matrix(q[:, 3:6]))
    return torch.cat([root_pos, root_rot, q[:, 6:]], 1)
