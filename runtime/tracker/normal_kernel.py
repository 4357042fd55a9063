"""The normal equations' assembly (:func:`runtime.tracker.gauss_newton.normal_equations`) as
compiled loops (numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:mod:`runtime.tracker.gauss_newton` imports it lazily and keeps its torch code for GPUs,
autograd and where numba is missing.

Why: torch forms every row's lever and its (6, 7) outer product as (N, 6, 7) float64
temporaries (8 MB for the ~20,000 rows of a batched refit) before summing them by (pose,
segment), then ``H = sum_k T_k^T M_k T_k`` with four batched products over all 34 DoFs and a
(B, 34, 15, 34) masked sum, and the collision term's rows as dense (N, 34) Jacobians grouped
by pose: ~50 small ops and ~2 ms a Gauss-Newton iteration for a batch of starts, most of it
dispatch. Here each row adds its products in place and each segment touches only the DoFs of
its own chain (at most 18 of 34). The levers are formed in float64 from the rows' float32
points (torch: in float32) and the sums run in another order than torch's, so the results
agree with torch's to float32 rounding, not to the bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch
from depthmocap.shared import skeleton as sk

__all__ = ["normal_equations_cpu", "column_rows_cpu"]


def _chain_table(affects: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, D) int64 the DoFs that move segment k first, padded with -1, and (K,) their
    counts, from the (K, D) 0/1 table ``affects``."""
    K, D = affects.shape
    chains = np.full((K, D), -1, np.int64)
    counts = np.zeros(K, np.int64)
    for k in range(K):
        idx = np.flatnonzero(affects[k])
        chains[k, : idx.size] = idx
        counts[k] = idx.size
    return chains, counts


_AFFECTS = np.asarray(sk.DOF_AFFECTS_SEGMENT, np.float64)  # (K, D)
_CHAINS, _COUNTS = _chain_table(_AFFECTS)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _moments(points, direction, residual, weight, batch, segment, K, stats):  # pragma: no cover
    """Each row's ``w^2 l l^T`` and ``w^2 r l`` (lever ``l = (p x g, g)``) summed into its
    (pose, segment)'s (6, 7) ``stats``."""
    lever = np.empty(7, np.float64)
    for i in range(points.shape[0]):
        w = np.float64(weight[i])
        if w == 0.0:
            continue
        px, py, pz = np.float64(points[i, 0]), np.float64(points[i, 1]), np.float64(points[i, 2])
        gx = np.float64(direction[i, 0])
        gy = np.float64(direction[i, 1])
        gz = np.float64(direction[i, 2])
        lever[0] = (py * gz - pz * gy) * w
        lever[1] = (pz * gx - px * gz) * w
        lever[2] = (px * gy - py * gx) * w
        lever[3] = gx * w
        lever[4] = gy * w
        lever[5] = gz * w
        lever[6] = np.float64(residual[i]) * w
        m = stats[batch[i] * K + segment[i]]
        for a in range(6):
            la = lever[a]
            for c in range(7):
                m[a, c] += la * lever[c]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _assemble(stats, table, chains, counts, hess, grad):  # pragma: no cover - compiled
    B, D = table.shape[0], table.shape[2]
    K = counts.shape[0]
    mt = np.empty((6, D), np.float64)
    for b in range(B):
        for k in range(K):
            m = stats[b * K + k]
            n = counts[k]
            for jj in range(n):  # M_k T on the chain's columns
                j = chains[k, jj]
                for a in range(6):
                    s = 0.0
                    for c in range(6):
                        s += m[a, c] * table[b, c, j]
                    mt[a, j] = s
            for ii in range(n):
                i = chains[k, ii]
                g = 0.0
                for a in range(6):
                    g += table[b, a, i] * m[a, 6]
                grad[b, i] += g
                for jj in range(n):
                    j = chains[k, jj]
                    s = 0.0
                    for a in range(6):
                        s += table[b, a, i] * mt[a, j]
                    hess[b, i, j] += s


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _column_rows(lever, residual, weight, batch, segment, columns, table, affects, hess,
                 grad):  # fmt: skip  # pragma: no cover - compiled
    D = table.shape[2]
    jac = np.empty(D, np.float64)
    for r in range(lever.shape[0]):
        w = weight[r]
        if w == 0.0:
            continue
        b, k = batch[r], segment[r]
        for i in range(D):
            if affects[k, i] != 0.0 and columns[r, i] != 0.0:
                s = 0.0
                for a in range(6):
                    s += lever[r, a] * table[b, a, i]
                jac[i] = s * w * columns[r, i]
            else:
                jac[i] = 0.0
        res = residual[r] * w
        for i in range(D):
            if jac[i] != 0.0:
                grad[b, i] += jac[i] * res
                for j in range(D):
                    hess[b, i, j] += jac[i] * jac[j]


def normal_equations_cpu(
    points: torch.Tensor,
    direction: torch.Tensor,
    residual: torch.Tensor,
    weight: torch.Tensor,
    batch: torch.Tensor,
    segment: torch.Tensor,
    table: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``H`` (B, 34, 34) and ``g`` (B, 34), float64, of the rows (``points``, ``direction``
    (N, 3), ``residual``, ``weight`` (N,), ``batch``, ``segment`` (N,) int64, CPU) under the
    lever tables ``table`` (B, 6, 34) float64; rows of zero weight add nothing."""
    B, D = table.shape[0], table.shape[2]
    K = sk.NUM_SEGMENTS
    stats = np.zeros((B * K, 6, 7), np.float64)
    _moments(
        np.ascontiguousarray(points.numpy()), np.ascontiguousarray(direction.numpy()),
        residual.numpy(), weight.numpy(), batch.numpy(), segment.numpy(), K, stats,
    )  # fmt: skip
    hess = np.zeros((B, D, D), np.float64)
    grad = np.zeros((B, D), np.float64)
    _assemble(stats, np.ascontiguousarray(table.numpy()), _CHAINS, _COUNTS, hess, grad)
    return torch.from_numpy(hess), torch.from_numpy(grad)


def column_rows_cpu(
    lever: torch.Tensor,
    residual: torch.Tensor,
    weight: torch.Tensor,
    batch: torch.Tensor,
    segment: torch.Tensor,
    columns: torch.Tensor,
    table: torch.Tensor,
    batch_size: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``H``, ``g`` (float64) of rows whose Jacobian ``lever @ T_b`` (masked to the segment's
    chain) keeps only ``columns``; rows of zero weight add nothing. CPU tensors: ``lever``
    (N, 6), ``residual``, ``weight`` (N,), ``batch``, ``segment`` (N,) int64, ``columns`` (N,
    34), ``table`` (B, 6, 34) float64."""
    D = table.shape[2]
    hess = np.zeros((batch_size, D, D), np.float64)
    grad = np.zeros((batch_size, D), np.float64)
    _column_rows(
        np.ascontiguousarray(lever.double().numpy()), residual.double().numpy(),
        weight.double().numpy(), batch.numpy(), segment.numpy(),
        np.ascontiguousarray(columns.double().numpy()), np.ascontiguousarray(table.numpy()),
        _AFFECTS, hess, grad,
    )  # fmt: skip
    return torch.from_numpy(hess), torch.from_numpy(grad)
