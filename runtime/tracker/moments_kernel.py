"""The normal equations' per-(pose, segment) moments (:func:`runtime.tracker.gauss_newton.
normal_equations`) as a compiled loop (numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:func:`~runtime.tracker.gauss_newton.normal_equations` imports it lazily and keeps its torch
code for GPUs and where numba is missing.

Why: torch forms every row's (6, 7) outer product as an (N, 6, 7) float64 temporary (1 M
numbers, 8 MB, for the ~20,000 rows of a batched refit) before ``index_add_`` sums them by
(pose, segment): 0.8 ms a Gauss-Newton iteration for one pose and 3 ms for nine. Here each row
adds its products in place, in row order, as ``index_add_`` does: the same sums, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

__all__ = ["moments_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _moments(lever, ext, group, out):  # pragma: no cover - compiled
    for i in range(lever.shape[0]):
        g = group[i]
        for a in range(lever.shape[1]):
            la = lever[i, a]
            for b in range(ext.shape[1]):
                out[g, a, b] += la * ext[i, b]


def moments_cpu(
    lever: torch.Tensor, ext: torch.Tensor, group: torch.Tensor, groups: int
) -> torch.Tensor:
    """``sum_i lever_i ext_i^T`` per group: (groups, 6, 7) float64 for CPU float64 ``lever``
    (N, 6), ``ext`` (N, 7) and int64 ``group`` (N,) in [0, groups)."""
    out = np.zeros((groups, lever.shape[1], ext.shape[1]), np.float64)
    _moments(
        np.ascontiguousarray(lever.numpy()),
        np.ascontiguousarray(ext.numpy()),
        np.ascontiguousarray(group.numpy()),
        out,
    )
    return torch.from_numpy(out)
