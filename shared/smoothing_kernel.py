"""Depth-gated posterior smoothing (:func:`shared.posterior_smoothing.smooth_posteriors`) as a
compiled loop (numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:func:`~shared.posterior_smoothing.smooth_posteriors` imports it lazily and keeps its torch
code for GPUs and where numba is missing.

Why: the torch code builds (N, K) index, gap and weight tables and an (N, K, C) gather of the
neighbours' posteriors (some 7,000 pixels x 25 neighbours x 20 classes on a person at 2 m),
about 2 ms a frame on the CPU, every frame. Here each pixel adds up its neighbours in place.

The same neighbours, in the same (row-major) order, with the same depth gate in the depth's
dtype; the sum of the kept neighbours' posteriors over their count. Only the summation may
round differently from torch's (whose einsum may fuse multiply-adds): the posteriors agree to
float32 rounding and the arg-max labels are the same but for exact ties (tested).
"""

from __future__ import annotations

import numba
import numpy as np
import torch

__all__ = ["smooth_posteriors_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _smooth(pix, probs, depth, radius, stride, gate, index, out):  # pragma: no cover
    nb, h, w = depth.shape
    n, c = probs.shape
    for i in range(n):
        f, r, q = pix[i, 0], pix[i, 1], pix[i, 2]
        index[f, r, q] = i
    acc = np.zeros(c, np.float64)
    for i in range(n):
        f, r, q = pix[i, 0], pix[i, 1], pix[i, 2]
        d0 = depth[f, r, q]
        acc[:] = 0.0
        count = 0
        for dv in range(-radius, radius + 1):
            v = r + dv * stride
            if v < 0 or v >= h:
                continue
            for du in range(-radius, radius + 1):
                u = q + du * stride
                if u < 0 or u >= w:
                    continue
                j = index[f, v, u]
                # "not <=": a NaN gap is left out, as torch's ``gap <= gate`` leaves it.
                if j < 0 or not abs(depth[f, v, u] - d0) <= gate:
                    continue
                count += 1
                for k in range(c):
                    acc[k] += probs[j, k]
        denom = max(count, 1)
        for k in range(c):
            out[i, k] = acc[k] / denom


def smooth_posteriors_cpu(
    pix: torch.Tensor, probs: torch.Tensor, depth_m: torch.Tensor, window: int,
    depth_gate_m: float, stride: int,
) -> torch.Tensor:  # fmt: skip
    """:func:`shared.posterior_smoothing.smooth_posteriors` for CPU tensors (its checks done
    by the caller): (N, C) posteriors in ``probs``' dtype."""
    d = np.ascontiguousarray(depth_m.detach().numpy())
    p = np.ascontiguousarray(probs.detach().numpy())
    index = np.full(d.shape, -1, np.int64)
    out = np.empty_like(p)
    gate = np.array(depth_gate_m, d.dtype)[()]  # compared in the depth's dtype, as torch does
    _smooth(np.ascontiguousarray(pix.numpy()), p, d, window // 2, stride, gate, index, out)
    return torch.from_numpy(out)
