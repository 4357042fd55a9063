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

from .label_kernel import capsule_offset

__all__ = ["collision_rows_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _collision(
    points, seg, targets, allowed, rot, origin, basis, span, scale, affects, consts
):  # pragma: no cover - compiled
    """The rows and columns of ``collision_rows``: ``targets`` (M, T) the capsules each
    sample is kept out of, ``allowed`` (M,) its tolerance; ``consts``: (sigma, -, -, 1, 1e-9,
    1e-12) in float32."""
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
            best, best_t = np.inf, 0
            d0 = d1 = d2 = zero
            for t in range(targets.shape[1]):
                s, e0, e1, e2 = capsule_offset(
                    points[b, m], rot, origin, basis, span, scale, b, targets[m, t], consts
                )
                if s < best:  # argmin: the first of equal values
                    best, best_t, d0, d1, d2 = s, t, e0, e1, e2
            e = max(-allowed[m] - best, zero)
            batch[i] = b
            for k in range(3):
                pts[i, k] = points[b, m, k]
            direction[i, 0], direction[i, 1], direction[i, 2] = d0, d1, d2
            segment[i] = seg[m]
            excess[i] = e
            weight[i] = (consts[3] if e > zero else zero) / consts[0]
            for j in range(affects.shape[1]):
                columns[i, j] = consts[3] - affects[targets[m, best_t], j]
    return batch, pts, segment, direction, excess, weight, columns


def collision_rows_cpu(points, seg, targets, allowed, rot, origin, geom, sigma):
    """The rows and columns of ``collision_rows`` for CPU float32 tensors without autograd:
    ``points`` (B, M, 3) the samples, ``seg`` (M,), ``targets`` (M, T) the capsules each is
    kept out of, ``allowed`` (M,) their tolerances, ``rot``, ``origin`` the primitives'
    frames, ``sigma`` the rows' noise scale."""
    from depthmocap.shared import skeleton as sk

    B = points.shape[0]
    dt = points.numpy().dtype
    out = _collision(
        points.contiguous().numpy(), seg.numpy(), targets.contiguous().numpy(), allowed.numpy(),
        rot.contiguous().numpy(), origin.contiguous().numpy(),
        geom.basis.contiguous().numpy(), geom.span.expand(B, -1, -1).contiguous().numpy(),
        geom.scale.expand(B, -1, -1).contiguous().numpy(),
        np.asarray(sk.DOF_AFFECTS_SEGMENT, dt), np.array([sigma, 0.0, 0.0, 1.0, 1e-9, 1e-12], dt),
    )  # fmt: skip
    return tuple(torch.from_numpy(x) for x in out)
