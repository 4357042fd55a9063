"""The silhouette term's rows as one compiled loop (numba): the CPU path of
:func:`runtime.tracker.silhouette_term.silhouette_rows`.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
``silhouette_rows`` imports it lazily and keeps its torch code for GPUs, autograd and
installs without numba.

Why: some twenty small torch ops per Gauss-Newton iteration (the rendered boundary, the
sampling, two gathers, the projection's derivatives) for a few hundred pixels. Here one call,
with the compiled sampler and rendered points of :mod:`~runtime.tracker.sampling_kernel`, the
same float32 operations in the same order: the same rows, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from .sampling_kernel import points_at, sampled

__all__ = ["silhouette_rows_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _outside(rendered, distance):  # pragma: no cover - compiled
    """Rendered boundary pixels (a background 4-neighbour; image borders count as
    background) whose observed distance is above 0."""
    nb, h, w = rendered.shape
    out = np.zeros(rendered.shape, np.bool_)
    for b in range(nb):
        for v in range(h):
            for u in range(w):
                if not rendered[b, v, u] or not distance[b, v, u] > 0:
                    continue
                inner = (
                    0 < v < h - 1 and 0 < u < w - 1
                    and rendered[b, v - 1, u] and rendered[b, v + 1, u]
                    and rendered[b, v, u - 1] and rendered[b, v, u + 1]
                )  # fmt: skip
                out[b, v, u] = not inner
    return out


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _silhouette(
    rendered, distance, grad, depth, segment, centre, focal, max_count, consts, sigma
):  # pragma: no cover - compiled
    """The rows of ``silhouette_rows``; ``consts``: (fx, fy, 1e-6, deadzone) in the depth's
    dtype, as torch holds them."""
    idx, _, ratio = sampled(_outside(rendered, distance), max_count)
    points, seg = points_at(depth, segment, idx, centre, focal)
    n = idx.shape[0]
    dt = depth.dtype
    direction = np.empty((n, 3), dt)
    residual = np.empty(n, dt)
    weight = (np.sqrt(ratio) / sigma).astype(dt)
    zero = consts[2] - consts[2]
    for i in range(n):
        b, v, u = idx[i, 0], idx[i, 1], idx[i, 2]
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        inv_z = np.float32(1.0) / max(z, consts[2])
        gu = grad[b, v, u, 0] * consts[0] * inv_z
        gv = grad[b, v, u, 1] * consts[1] * inv_z
        direction[i, 0] = gu
        direction[i, 1] = gv
        direction[i, 2] = -(gu * x + gv * y) * inv_z
        residual[i] = -max(distance[b, v, u] - consts[3], zero)
    return idx[:, 0].copy(), points, seg.astype(np.int64), direction, residual, weight


def silhouette_rows_cpu(render, obs, max_count: int, deadzone: float, sigma: float):
    """The same rows as ``silhouette_rows`` for CPU float32 tensors (only: the reciprocal is
    float32's) without autograd: batch, points, segment, direction, residual, weight."""
    depth = render.depth.numpy()
    dt = depth.dtype
    intr = obs.intr
    out = _silhouette(
        render.mask.numpy(), obs.distance.numpy(), obs.distance_grad.numpy(),
        depth, render.segment.numpy(), np.array([intr.cx, intr.cy], dt),
        np.array([intr.fx, intr.fy], dt), int(max_count),
        np.array([intr.fx, intr.fy, 1e-6, deadzone], dt), float(sigma),
    )  # fmt: skip
    return tuple(torch.from_numpy(a) for a in out)
