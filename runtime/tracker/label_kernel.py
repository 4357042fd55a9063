"""The label term's rows as one compiled loop (numba): the CPU path of
:func:`runtime.tracker.label_term.label_rows`.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
``label_rows`` imports it lazily and keeps its torch code for GPUs, autograd and installs
without numba.

Why: some thirty small torch ops per Gauss-Newton iteration (the sampling, gathers of each
pixel's capsule, four 3 x 3 products, norms, the signed distance) for at most 300 pixels.
Here one call does them in float32 in torch's order (plain sequential sums for its 3 x 3
products, fused multiply-adds for its norms, as :mod:`~runtime.tracker.depth_kernel`): the
same rows, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from .extra_kernel import _norm32
from .sampling_kernel import sampled

__all__ = ["label_rows_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _label_rows(
    use, labels, obs_points, rot, origin, basis, span, scale, max_pixels, consts, sigma
):  # pragma: no cover - compiled
    """The rows of ``label_rows``; ``consts``: (gate, 1e-9, 1e-12, 1) in float32."""
    idx, ratio = sampled(use, max_pixels)
    n = idx.shape[0]
    dt = obs_points.dtype
    surface = np.empty((n, 3), dt)
    direction = np.empty((n, 3), dt)
    signed_out = np.empty(n, dt)
    weight = np.empty(n, dt)
    segment = np.empty(n, np.int64)
    scale_w = (np.sqrt(ratio) / sigma).astype(dt)
    zero = consts[3] - consts[3]
    d = np.empty(3, dt)
    local = np.empty(3, dt)
    c = np.empty(3, dt)
    off = np.empty(3, dt)
    t = np.empty(3, dt)
    for i in range(n):
        b, v, u = idx[i, 0], idx[i, 1], idx[i, 2]
        s = labels[b, v, u]
        segment[i] = s
        # runtime.tracker.label_term.capsule_offsets: the point in its capsule's coordinates.
        for k in range(3):
            d[k] = obs_points[b, v, u, k] - origin[b, s, k]
        for j in range(3):
            local[j] = (d[0] * rot[b, s, 0, j] + d[1] * rot[b, s, 1, j]) + d[2] * rot[b, s, 2, j]
        for r in range(3):
            c[r] = (basis[s, r, 0] * local[0] + basis[s, r, 1] * local[1]) + basis[s, r, 2] * local[
                2
            ]
        # runtime.raycast.capsule_signed_distance.
        off[0] = c[0]
        off[1] = c[1]
        off[2] = c[2] - min(max(c[2], span[b, s, 0]), span[b, s, 1])
        length = _norm32(off[0], off[1], off[2])
        rho = _norm32(off[0] / scale[b, s, 0], off[1] / scale[b, s, 1], off[2] / scale[b, s, 2])
        signed = length * (consts[3] - consts[3] / max(rho, consts[1]))
        unit_len = max(length, consts[2])
        for k in range(3):
            off[k] = off[k] / unit_len
        for k in range(3):
            t[k] = (basis[s, 0, k] * off[0] + basis[s, 1, k] * off[1]) + basis[s, 2, k] * off[2]
        for r in range(3):
            direction[i, r] = (rot[b, s, r, 0] * t[0] + rot[b, s, r, 1] * t[1]) + rot[
                b, s, r, 2
            ] * t[2]
        for r in range(3):
            surface[i, r] = obs_points[b, v, u, r] - signed * direction[i, r]
        signed_out[i] = signed
        weight[i] = scale_w[i] if abs(signed) < consts[0] else zero
    return idx[:, 0].copy(), surface, segment, direction, signed_out, weight


def label_rows_cpu(kin, geom, obs, use, max_pixels: int, gate: float, sigma: float):
    """The same rows as ``label_rows`` for CPU float32 tensors without autograd, ``use`` the
    labelled limb pixels: batch, surface points, segment, direction, signed distance,
    weight."""
    B = kin.origins.shape[0]
    rot, origin = geom.frames(kin)
    points = obs.points.contiguous().numpy()
    out = _label_rows(
        use.numpy(), obs.labels.numpy(), points, rot.contiguous().numpy(),
        origin.contiguous().numpy(), geom.basis.contiguous().numpy(),
        geom.span.expand(B, -1, -1).contiguous().numpy(),
        geom.scale.expand(B, -1, -1).contiguous().numpy(), int(max_pixels),
        np.array([gate, 1e-9, 1e-12, 1.0], points.dtype), float(sigma),
    )  # fmt: skip
    return tuple(torch.from_numpy(x) for x in out)
