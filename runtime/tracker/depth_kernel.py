"""The depth term's rows as one compiled loop (numba): the CPU path of
:func:`runtime.tracker.depth_term.depth_rows`.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
``depth_rows`` imports it lazily and keeps its torch code for GPUs, autograd and installs
without numba.

Why: the term and the surface normals it needs are some forty small torch ops per
Gauss-Newton iteration (the sampling, gathers of each pixel's capsule frame, three 3 x 3
products, norms, the viewing angle's cosine) for about a thousand pixels. Here one call does
them in float32 in torch's order: its 3 x 3 products and three-element sums are plain
sequential sums on the CPU, its norms ``fma(z, z, fma(y, y, x * x))`` (the products exact in
float64, as :mod:`~runtime.tracker.extra_kernel` does): the same rows, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from .extra_kernel import norm3_float32
from .sampling_kernel import points_at, sampled

__all__ = ["depth_rows_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _depth_rows(
    good, depth, segment, primitive, rot, origin, basis, span, scale, depth_diff, centre,
    focal, max_pixels, consts, sigma,
):  # pragma: no cover - compiled  # fmt: skip
    """The rows of ``depth_rows``; ``consts``: (min cosine, 1e-9, 1e-12, 0) in float32."""
    idx, _, ratio = sampled(good, max_pixels)
    points, seg = points_at(depth, segment, idx, centre, focal)
    n = idx.shape[0]
    dt = depth.dtype
    direction = np.empty((n, 3), dt)
    residual = np.empty(n, dt)
    weight = np.empty(n, dt)
    scale_w = (np.sqrt(ratio) / sigma).astype(dt)
    a = np.empty((3, 3), dt)
    d = np.empty(3, dt)
    c = np.empty(3, dt)
    g = np.empty(3, dt)
    nrm = np.empty(3, dt)
    for i in range(n):
        b, v, u = idx[i, 0], idx[i, 1], idx[i, 2]
        p = max(primitive[b, v, u], 0)
        # Surface normal (runtime.raycast.surface_normals): camera -> section coordinates
        # A = basis R^T, c = A (x - o), the capsule's gradient there, back by A^T.
        for r in range(3):
            for k in range(3):
                a[r, k] = (
                    basis[p, r, 0] * rot[b, p, k, 0] + basis[p, r, 1] * rot[b, p, k, 1]
                ) + basis[p, r, 2] * rot[b, p, k, 2]
        for k in range(3):
            d[k] = points[i, k] - origin[b, p, k]
        for r in range(3):
            c[r] = (a[r, 0] * d[0] + a[r, 1] * d[1]) + a[r, 2] * d[2]
        axial = c[2] - min(max(c[2], span[b, p, 0]), span[b, p, 1])
        g[0] = c[0] / (scale[b, p, 0] * scale[b, p, 0])
        g[1] = c[1] / (scale[b, p, 1] * scale[b, p, 1])
        g[2] = axial / (scale[b, p, 2] * scale[b, p, 2])
        for r in range(3):
            nrm[r] = (a[0, r] * g[0] + a[1, r] * g[1]) + a[2, r] * g[2]
        length = max(norm3_float32(nrm[0], nrm[1], nrm[2]), consts[2])
        for r in range(3):
            nrm[r] = nrm[r] / length
        # The row (runtime.tracker.depth_term.depth_rows).
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        dist = norm3_float32(x, y, z)
        ray_len = dist / max(z, consts[1])
        cosine = ((nrm[0] * x + nrm[1] * y) + nrm[2] * z) / max(dist, consts[1])
        weight[i] = scale_w[i] if abs(cosine) >= consts[0] else consts[3]
        for r in range(3):
            direction[i, r] = -nrm[r] / ray_len
        residual[i] = depth_diff[b, v, u] * abs(cosine)
    return idx[:, 0].copy(), points, seg.astype(np.int64), direction, residual, weight


def depth_rows_cpu(render, obs, regions, max_pixels: int, min_cosine: float, sigma: float):
    """The same rows as ``depth_rows`` for CPU float32 tensors without autograd (the
    rendering cast without normals): batch, points, segment, direction, residual, weight."""
    depth = render.depth.numpy()
    dt = depth.dtype
    B = render.rot.shape[0]
    geom = render.geom
    intr = obs.intr
    out = _depth_rows(
        regions.good.numpy(), depth, render.segment.numpy(), render.primitive.numpy(),
        render.rot.contiguous().numpy(), render.origin.contiguous().numpy(),
        geom.basis.contiguous().numpy(), geom.span.expand(B, -1, -1).contiguous().numpy(),
        geom.scale.expand(B, -1, -1).contiguous().numpy(), regions.depth_diff.numpy(),
        np.array([intr.cx, intr.cy], dt), np.array([intr.fx, intr.fy], dt), int(max_pixels),
        np.array([min_cosine, 1e-9, 1e-12, 0.0], dt), float(sigma),
    )  # fmt: skip
    return tuple(torch.from_numpy(x) for x in out)
