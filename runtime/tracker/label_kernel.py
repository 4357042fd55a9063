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

from .extra_kernel import norm3_float32
from .sampling_kernel import sampled

__all__ = ["capsule_offset", "label_rows_at", "label_rows_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def capsule_offset(x, rot, origin, basis, span, scale, b, p, consts):  # pragma: no cover
    """runtime.tracker.label_term.capsule_offsets for one point ``x`` (3,) and capsule ``p``
    of pose ``b``: the signed distance and the camera-frame unit direction's three
    components; ``consts`` (..., 1, 1e-9, 1e-12) at indices 3-5 in the points' dtype."""
    R, A = rot[b, p], basis[p]
    d0, d1, d2 = x[0] - origin[b, p, 0], x[1] - origin[b, p, 1], x[2] - origin[b, p, 2]
    # local = (x - o) R, then c = basis local: torch's 3 x 3 products, summed in order.
    l0 = (d0 * R[0, 0] + d1 * R[1, 0]) + d2 * R[2, 0]
    l1 = (d0 * R[0, 1] + d1 * R[1, 1]) + d2 * R[2, 1]
    l2 = (d0 * R[0, 2] + d1 * R[1, 2]) + d2 * R[2, 2]
    c0 = (A[0, 0] * l0 + A[0, 1] * l1) + A[0, 2] * l2
    c1 = (A[1, 0] * l0 + A[1, 1] * l1) + A[1, 2] * l2
    c2 = (A[2, 0] * l0 + A[2, 1] * l1) + A[2, 2] * l2
    c2 = c2 - min(max(c2, span[b, p, 0]), span[b, p, 1])
    length = norm3_float32(c0, c1, c2)
    rho = norm3_float32(c0 / scale[b, p, 0], c1 / scale[b, p, 1], c2 / scale[b, p, 2])
    signed = length * (consts[3] - consts[3] / max(rho, consts[4]))
    unit = max(length, consts[5])
    u0, u1, u2 = c0 / unit, c1 / unit, c2 / unit
    t0 = (A[0, 0] * u0 + A[1, 0] * u1) + A[2, 0] * u2
    t1 = (A[0, 1] * u0 + A[1, 1] * u1) + A[2, 1] * u2
    t2 = (A[0, 2] * u0 + A[1, 2] * u1) + A[2, 2] * u2
    return (
        signed,
        (R[0, 0] * t0 + R[0, 1] * t1) + R[0, 2] * t2,
        (R[1, 0] * t0 + R[1, 1] * t1) + R[1, 2] * t2,
        (R[2, 0] * t0 + R[2, 1] * t1) + R[2, 2] * t2,
    )


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _label_rows(
    use, labels, obs_points, rot, origin, basis, span, scale, max_pixels, consts, sigma
):  # pragma: no cover - compiled
    """The rows of ``label_rows``; ``consts``: (gate, -, -, 1, 1e-9, 1e-12) in float32."""
    idx, _, ratio = sampled(use, max_pixels)
    return label_rows_at(idx, ratio, labels, obs_points, rot, origin, basis, span, scale,
                         consts, sigma)  # fmt: skip


@numba.njit(cache=True, nogil=True, boundscheck=False)
def label_rows_at(
    idx, ratio, labels, obs_points, rot, origin, basis, span, scale, consts, sigma
):  # pragma: no cover - compiled
    """:func:`_label_rows` at the sampled pixels ``idx`` (N, 3) and their ratios (N,): the
    labelled pixels of a frame are the same at every iteration, so a fit samples them once."""
    n = idx.shape[0]
    dt = obs_points.dtype
    surface = np.empty((n, 3), dt)
    direction = np.empty((n, 3), dt)
    signed_out = np.empty(n, dt)
    weight = np.empty(n, dt)
    segment = np.empty(n, np.int64)
    scale_w = (np.sqrt(ratio) / sigma).astype(dt)
    zero = consts[3] - consts[3]
    for i in range(n):
        b, v, u = idx[i, 0], idx[i, 1], idx[i, 2]
        s = labels[b, v, u]
        segment[i] = s
        signed, direction[i, 0], direction[i, 1], direction[i, 2] = capsule_offset(
            obs_points[b, v, u], rot, origin, basis, span, scale, b, s, consts
        )
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
    points = obs.points.numpy()
    out = _label_rows(
        use.numpy(), obs.labels.numpy(), points, rot.contiguous().numpy(),
        origin.contiguous().numpy(), geom.basis.contiguous().numpy(),
        geom.span.expand(B, -1, -1).contiguous().numpy(),
        geom.scale.expand(B, -1, -1).contiguous().numpy(), int(max_pixels),
        np.array([gate, 0.0, 0.0, 1.0, 1e-9, 1e-12], points.dtype), float(sigma),
    )  # fmt: skip
    return tuple(torch.from_numpy(x) for x in out)
