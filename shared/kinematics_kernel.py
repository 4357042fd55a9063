"""Forward kinematics as one compiled loop (numba): the CPU path of the tracker's inner loop.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:func:`shared.kinematics.forward_kinematics` imports it lazily and keeps its torch code for
autograd, GPUs, and where numba is missing.

Why: the torch version walks the tree level by level in ~380 small tensor ops, about 1 ms per
call for one pose on the CPU whatever the batch, and the tracker calls it at every Gauss-Newton
iteration (a tenth of a tracked frame). Here one call computes every pose's frames in
registers. The arithmetic is the same (Rodrigues rotations, the same products in the same
order), in float64, so the two agree to the float32 rounding of the result.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch

from . import skeleton as sk

__all__ = ["forward_kinematics_cpu"]

_SMALL = 1e-4  # shared.so3's switch to Taylor series for the root's rotation vector
_PARENT = sk.SEGMENT_PARENT.astype(np.int64)
_ORDER = np.concatenate(sk.SEGMENT_LEVELS).astype(np.int64)  # parents before children
_AXIS = sk.SEGMENT_AXIS.astype(np.float64)
_ATTACH = sk.SEGMENT_ATTACH_END.astype(np.float64)
_LATERAL = sk.SEGMENT_LATERAL.astype(np.float64)
_SLOTS = sk.SEGMENT_DOF_SLOTS.astype(np.int64)
_DOF_AXIS = sk.DOF_AXIS.astype(np.float64)
_DOF_SEGMENT = sk.DOF_SEGMENT.astype(np.int64)
_DOF_SLOT = sk.DOF_SLOT.astype(np.int64)
_CLAVICLE = np.asarray(sk.CLAVICLE_DOFS, dtype=np.int64)
_CHEST = sk.SEGMENT_NAMES.index("chest")
_ARMS = np.array([sk.SEGMENT_NAMES.index(n) for n in ("l_upper_arm", "r_upper_arm")])
# The right arm's undo rotation is the left's with these entries' signs flipped (row-major).
_MIRROR = np.array([1.0, -1.0, -1.0, -1.0, 1.0, 1.0, -1.0, 1.0, 1.0])


@numba.njit(inline="always")
def _matmul(a, b, out):  # pragma: no cover - compiled
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@numba.njit(inline="always")
def _rotation(x, y, z, a, b, out):  # pragma: no cover - compiled
    """I + a K + b K^2 for K the cross-product matrix of (x, y, z): Rodrigues' formula with
    a = sin, b = 1 - cos for a unit axis, or the exponential map's coefficients for a rotation
    vector."""
    out[0, 0] = 1.0 + b * (-y * y - z * z)
    out[0, 1] = -a * z + b * x * y
    out[0, 2] = a * y + b * x * z
    out[1, 0] = a * z + b * x * y
    out[1, 1] = 1.0 + b * (-x * x - z * z)
    out[1, 2] = -a * x + b * y * z
    out[2, 0] = -a * y + b * x * z
    out[2, 1] = a * x + b * y * z
    out[2, 2] = 1.0 + b * (-x * x - y * y)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _fk(q, lengths, hip, clavicle, tilt, parent, order, seg_axis, attach, lateral, slots,
        dof_axis, dof_segment, dof_slot, clav_dofs, chest, arms, mirror,
        rotations, origins, dof_axes, dof_origins):  # fmt: skip  # pragma: no cover
    B = q.shape[0]
    K = parent.shape[0]
    D = q.shape[1]
    angles = np.empty(D)
    prefix = np.empty((K, 3, 3, 3))  # per segment: P, P R1, P R1 R2
    local = np.empty((3, 3))
    step = np.empty((3, 3))
    tmp = np.empty((3, 3))
    rot = np.empty((3, 3))
    for b in range(B):
        for d in range(D):
            angles[d] = q[b, d]
        for i in range(clav_dofs.shape[0]):
            angles[clav_dofs[i]] += clavicle[b, i % 2]
        # Local rotations P R_1 R_2 R_3, keeping the prefixes for the DoF axes.
        ce, cp = math.cos(clavicle[b, 0]), math.cos(clavicle[b, 1])
        se, sp = math.sin(clavicle[b, 0]), math.sin(clavicle[b, 1])
        undo = (ce * cp, se * cp, sp, -se, ce, 0.0, -ce * sp, -se * sp, cp)
        for k in range(K):
            for i in range(3):
                for j in range(3):
                    prefix[k, 0, i, j] = 1.0 if i == j else 0.0
            for a in range(arms.shape[0]):
                if arms[a] == k:
                    for e in range(9):
                        sign = mirror[e] if a == 1 else 1.0
                        prefix[k, 0, e // 3, e % 3] = undo[e] * sign
        # The root: exp of its rotation vector, with shared.so3's small-angle series.
        wx, wy, wz = q[b, 3], q[b, 4], q[b, 5]
        th2 = wx * wx + wy * wy + wz * wz
        if th2 < _SMALL * _SMALL:
            ca, cb = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
        else:
            th = math.sqrt(th2)
            ca, cb = math.sin(th) / th, (1.0 - math.cos(th)) / th2
        _rotation(wx, wy, wz, ca, cb, rot)
        for n in range(K):
            k = order[n]
            p = parent[k]
            if p < 0:
                for i in range(3):
                    origins[b, k, i] = q[b, i]
                    for j in range(3):
                        rotations[b, k, i, j] = rot[i, j]
                continue
            if k == chest:
                c, s = math.cos(tilt[b]), math.sin(tilt[b])
                local[0, 0], local[0, 1], local[0, 2] = 1.0, 0.0, 0.0
                local[1, 0], local[1, 1], local[1, 2] = 0.0, c, -s
                local[2, 0], local[2, 1], local[2, 2] = 0.0, s, c
            else:
                for i in range(3):
                    for j in range(3):
                        local[i, j] = prefix[k, 0, i, j]
                for s in range(3):
                    d = slots[k, s]
                    if d < 0:
                        if s < 2:
                            for i in range(3):
                                for j in range(3):
                                    prefix[k, s + 1, i, j] = local[i, j]
                        continue
                    ax = dof_axis[d]
                    angle = angles[d]
                    _rotation(ax[0], ax[1], ax[2], math.sin(angle), 1.0 - math.cos(angle), step)
                    _matmul(local, step, tmp)
                    for i in range(3):
                        for j in range(3):
                            local[i, j] = tmp[i, j]
                            if s < 2:
                                prefix[k, s + 1, i, j] = tmp[i, j]
            _matmul(rotations[b, p], local, tmp)
            off0 = attach[k] * lengths[b, p] * seg_axis[p, 0] + lateral[k] * hip[b]
            off1 = attach[k] * lengths[b, p] * seg_axis[p, 1]
            off2 = attach[k] * lengths[b, p] * seg_axis[p, 2]
            for i in range(3):
                origins[b, k, i] = origins[b, p, i] + (
                    rotations[b, p, i, 0] * off0
                    + rotations[b, p, i, 1] * off1
                    + rotations[b, p, i, 2] * off2
                )
                for j in range(3):
                    rotations[b, k, i, j] = tmp[i, j]
        # World DoF axes: R_parent P R_1 ... R_(s-1) axis; root DoFs: the camera axes.
        for d in range(D):
            k = dof_segment[d]
            for i in range(3):
                dof_origins[b, d, i] = origins[b, k, i]
            if d < 6:
                for i in range(3):
                    dof_axes[b, d, i] = dof_axis[d, i]
                continue
            pre = prefix[k, dof_slot[d]]
            for i in range(3):
                tmp[0, i] = pre[i, 0] * dof_axis[d, 0] + pre[i, 1] * dof_axis[d, 1]
                tmp[0, i] += pre[i, 2] * dof_axis[d, 2]
            a0, a1, a2 = tmp[0, 0], tmp[0, 1], tmp[0, 2]
            r = rotations[b, parent[k]]
            for i in range(3):
                dof_axes[b, d, i] = r[i, 0] * a0 + r[i, 1] * a1 + r[i, 2] * a2


def _per_pose(value: torch.Tensor, B: int, *shape: int) -> np.ndarray:
    """A body parameter, unbatched or batched, as a float64 (B, *shape) array."""
    return np.ascontiguousarray(
        value.detach().to(torch.float64).expand(B, *shape).numpy(), dtype=np.float64
    )


def forward_kinematics_cpu(q: torch.Tensor, body) -> tuple[torch.Tensor, ...]:
    """Rotations (B, 15, 3, 3), origins (B, 15, 3), DoF axes (B, 34, 3), DoF origins (B, 34, 3)
    and lengths (B, 15) of CPU poses ``q`` (B, 34), in q's dtype: the fields of
    :class:`shared.kinematics.Kinematics`, without autograd."""
    B, K, D = q.shape[0], sk.NUM_SEGMENTS, sk.NUM_DOFS
    q64 = np.ascontiguousarray(q.detach().numpy(), dtype=np.float64)
    lengths = _per_pose(body.lengths, B, K)
    out = (np.empty((B, K, 3, 3)), np.empty((B, K, 3)), np.empty((B, D, 3)), np.empty((B, D, 3)))
    _fk(
        q64, lengths, _per_pose(body.hip_half_width, B), _per_pose(body.clavicle_rest, B, 2),
        _per_pose(body.chest_tilt, B), _PARENT, _ORDER, _AXIS, _ATTACH, _LATERAL, _SLOTS,
        _DOF_AXIS, _DOF_SEGMENT, _DOF_SLOT, _CLAVICLE, _CHEST, _ARMS, _MIRROR, *out,
    )  # fmt: skip
    return tuple(torch.from_numpy(a).to(q.dtype) for a in (*out, lengths))
