"""The collision term's rows as one compiled loop (numba): the CPU path of
:func:`runtime.tracker.collision_term.collision_rows`.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
``collision_rows`` imports it lazily and keeps its torch code for GPUs, autograd and
installs without numba.

Why: some thirty small torch ops per Gauss-Newton iteration (gathers of 48 point and capsule
pairs per pose, four 3 x 3 products, norms, the deepest capsule, the column masks) for a term
that mostly finds no contact. Here one call in float32 in torch's order (plain sequential sums
for its 3 x 3 products, fused multiply-adds for its norms, as
:mod:`~runtime.tracker.label_kernel`): the same rows and columns, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from .extra_kernel import _norm32

__all__ = ["collision_rows_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _signed_offset(x, rot, origin, basis, span, scale, b, p, consts):  # pragma: no cover
    """runtime.tracker.label_term.capsule_offsets for one point and capsule p of pose b:
    signed distance and the camera-frame unit direction (3,)."""
    d = np.empty(3, x.dtype)
    local = np.empty(3, x.dtype)
    c = np.empty(3, x.dtype)
    t = np.empty(3, x.dtype)
    out = np.empty(3, x.dtype)
    for k in range(3):
        d[k] = x[k] - origin[b, p, k]
    for j in range(3):
        local[j] = (d[0] * rot[b, p, 0, j] + d[1] * rot[b, p, 1, j]) + d[2] * rot[b, p, 2, j]
    for r in range(3):
        c[r] = (basis[p, r, 0] * local[0] + basis[p, r, 1] * local[1]) + basis[p, r, 2] * local[2]
    c[2] = c[2] - min(max(c[2], span[b, p, 0]), span[b, p, 1])
    length = _norm32(c[0], c[1], c[2])
    rho = _norm32(c[0] / scale[b, p, 0], c[1] / scale[b, p, 1], c[2] / scale[b, p, 2])
    signed = length * (consts[3] - consts[3] / max(rho, consts[4]))
    unit_len = max(length, consts[5])
    for k in range(3):
        c[k] = c[k] / unit_len
    for k in range(3):
        t[k] = (basis[p, 0, k] * c[0] + basis[p, 1, k] * c[1]) + basis[p, 2, k] * c[2]
    for r in range(3):
        out[r] = (rot[b, p, r, 0] * t[0] + rot[b, p, r, 1] * t[1]) + rot[b, p, r, 2] * t[2]
    return signed, out


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _collision(
    points, seg, torso, hand, rot, origin, basis, span, scale, affects, consts
):  # pragma: no cover - compiled
    """The rows and columns of ``collision_rows``; ``consts``: (tolerance, hand tolerance,
    sigma, 1, 1e-9, 1e-12) in float32."""
    B, M = points.shape[0], points.shape[1]
    dt = points.dtype
    n = B * M
    batch = np.empty(n, np.int64)
    pts = np.empty((n, 3), dt)
    segment = np.empty(n, np.int64)
    direction = np.empty((n, 3), dt)
    excess = np.empty(n, dt)
    weight = np.empty(n, dt)
    columns = np.empty((n, affects.shape[1]), dt)
    zero = consts[3] - consts[3]
    for b in range(B):
        for m in range(M):
            i = b * M + m
            best, best_dir, best_t = np.inf, np.zeros(3, dt), 0
            for t in range(torso.shape[0]):
                s, dirn = _signed_offset(
                    points[b, m], rot, origin, basis, span, scale, b, torso[t], consts
                )
                if s < best:  # argmin: the first of equal values
                    best, best_dir, best_t = s, dirn, t
            tolerance = consts[1] if hand[m] else consts[0]
            e = max(-tolerance - best, zero)
            batch[i] = b
            for k in range(3):
                pts[i, k] = points[b, m, k]
                direction[i, k] = best_dir[k]
            segment[i] = seg[m]
            excess[i] = e
            weight[i] = (consts[3] if e > zero else zero) / consts[2]
            for j in range(affects.shape[1]):
                columns[i, j] = consts[3] - affects[torso[best_t], j]
    return batch, pts, segment, direction, excess, weight, columns


def collision_rows_cpu(points, seg, torso, hand, rot, origin, geom, consts):
    """The rows and columns of ``collision_rows`` for CPU float32 tensors without autograd:
    ``points`` (B, M, 3) the arm samples, ``seg`` (M,), ``torso`` (T,), ``hand`` (M,) bool,
    ``rot``, ``origin`` the primitives' frames, ``consts`` (tolerance, hand tolerance,
    sigma)."""
    from depthmocap.shared import skeleton as sk

    B = points.shape[0]
    dt = points.numpy().dtype
    out = _collision(
        points.contiguous().numpy(), seg.numpy(), torso.numpy(), hand.numpy(),
        rot.contiguous().numpy(), origin.contiguous().numpy(),
        geom.basis.contiguous().numpy(), geom.span.expand(B, -1, -1).contiguous().numpy(),
        geom.scale.expand(B, -1, -1).contiguous().numpy(),
        np.asarray(sk.DOF_AFFECTS_SEGMENT, dt), np.array([*consts, 1.0, 1e-9, 1e-12], dt),
    )  # fmt: skip
    return tuple(torch.from_numpy(x) for x in out)
