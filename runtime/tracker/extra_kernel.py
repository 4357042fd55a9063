"""The extra depth term's correspondences as one compiled loop (numba): the CPU path of
:func:`runtime.tracker.extra_depth_term.extra_rows`.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
``extra_rows`` imports it lazily and keeps its torch code for GPUs, autograd and installs
without numba.

Why: the term's torch code is some sixty small ops per Gauss-Newton iteration (three mask
dilations, three pixel samplings, two point gathers, two closest-point searches, offsets,
weights, the rows' layout), ~1.3 ms in place for a few hundred pixels' worth of arithmetic.
Here one call does all of it with the compiled sampler, rendered points and closest-point walk
of :mod:`~runtime.tracker.sampling_kernel` and :mod:`~runtime.tracker.closest_kernel`, the
same operations in the same dtypes and order: the same rows, bit for bit (the distances'
float32 norm is computed as torch's, ``fma(z, z, fma(y, y, x * x))``, the products exact in
float64). float32 only, the tracker's dtype: in float64 that emulation is not exact.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from .closest_kernel import candidate_grid, closest_in, closest_of
from .sampling_kernel import points_at, sampled

__all__ = ["extra_correspondences_cpu", "norm3_float32"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _near(mask, r, b, v, u):  # pragma: no cover - compiled
    """Whether a True pixel of ``mask[b]`` lies within the (2 r + 1)^2 square around (v, u)."""
    h, w = mask.shape[1], mask.shape[2]
    for vv in range(max(v - r, 0), min(v + r + 1, h)):
        for uu in range(max(u - r, 0), min(u + r + 1, w)):
            if mask[b, vv, uu]:
                return True
    return False


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _query_masks(b1, front, behind, b3, good, silhouette, rendered, r):  # pragma: no cover
    """The two query masks of ``extra_rows``: rendered -> observed (B1 off the observed
    silhouette's margin, B2 in front off G's) and observed -> rendered (B3 off the rendered
    silhouette's margin, B2 behind off G's); ``r`` the margin (0: none)."""
    nb, h, w = b1.shape
    q = np.zeros(b1.shape, np.bool_)
    o = np.zeros(b1.shape, np.bool_)
    for b in range(nb):
        for v in range(h):
            for u in range(w):
                if b1[b, v, u] and not (r > 0 and _near(silhouette, r, b, v, u)):
                    q[b, v, u] = True
                elif front[b, v, u] and not (r > 0 and _near(good, r, b, v, u)):
                    q[b, v, u] = True
                if b3[b, v, u] and not (r > 0 and _near(rendered, r, b, v, u)):
                    o[b, v, u] = True
                elif behind[b, v, u] and not (r > 0 and _near(good, r, b, v, u)):
                    o[b, v, u] = True
    return q, o


@numba.njit(cache=True, nogil=True, boundscheck=False)
def norm3_float32(x, y, z):  # pragma: no cover - compiled
    """torch's float32 norm of 3 values: fma(z, z, fma(y, y, x * x)), then the root."""
    acc = np.float32(np.float64(x) * np.float64(x))
    acc = np.float32(np.float64(y) * np.float64(y) + np.float64(acc))
    acc = np.float32(np.float64(z) * np.float64(z) + np.float64(acc))
    return np.float32(np.sqrt(acc))


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _correspondences(
    b1, front, behind, b3, good, silhouette, rendered, margin, depth, segment, centre,
    focal, obs_points, cand_points, cand_batch, half, max_candidates, gate, max_d2,
    depth_gate, sigma_torso, sigma_limb, first_limb, batch_size,
):  # pragma: no cover - compiled  # fmt: skip
    """Everything :func:`extra_rows` computes, in its order (see there)."""
    return _correspondences_in(
        b1, front, behind, b3, good, silhouette, rendered, margin, depth, segment, centre,
        focal, obs_points, candidate_grid(cand_points, cand_batch, batch_size), half,
        max_candidates, gate, max_d2, depth_gate, sigma_torso, sigma_limb, first_limb,
        batch_size,
    )  # fmt: skip


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _correspondences_in(
    b1, front, behind, b3, good, silhouette, rendered, margin, depth, segment, centre,
    focal, obs_points, candidates, half, max_candidates, gate, max_d2, depth_gate,
    sigma_torso, sigma_limb, first_limb, batch_size,
):  # pragma: no cover - compiled  # fmt: skip
    """:func:`_correspondences` with the observed candidates' grid made beforehand
    (:func:`~runtime.tracker.closest_kernel.candidate_grid`): a fit makes it once."""
    cand_points = candidates[0]
    dt = depth.dtype
    # The constants in the depth's dtype, as torch's tensors of it hold them.
    consts = np.array([depth_gate, sigma_torso, sigma_limb, 0.0], dt)
    zero = consts[3]
    qmask, omask = _query_masks(b1, front, behind, b3, good, silhouette, rendered, margin)
    error = np.zeros(batch_size, dt)
    count = np.zeros(batch_size, dt)

    # Types 1 and 3: rendered point -> closest observed point.
    q_idx, _, q_ratio64 = sampled(qmask, half)
    q_pts, q_seg = points_at(depth, segment, q_idx, centre, focal)
    nq = q_idx.shape[0]
    j, found = closest_in(q_pts, q_idx[:, 0].copy(), candidates, gate, max_d2)
    q_ratio = q_ratio64.astype(dt)
    off_r = np.zeros((nq, 3), dt)
    for i in range(nq):
        dist = consts[0]
        if found[i]:
            for a in range(3):
                off_r[i, a] = cand_points[j[i], a] - q_pts[i, a]
            dist = norm3_float32(off_r[i, 0], off_r[i, 1], off_r[i, 2])
        error[q_idx[i, 0]] += dist * q_ratio[i]
        count[q_idx[i, 0]] += q_ratio[i]

    # Types 2 and 4: observed point -> closest rendered point (a model point to pull).
    o_idx, _, o_ratio64 = sampled(omask, half)
    o_ratio = o_ratio64.astype(dt)
    no = o_idx.shape[0]
    o_pts = np.empty((no, 3), dt)
    for i in range(no):
        for a in range(3):
            o_pts[i, a] = obs_points[o_idx[i, 0], o_idx[i, 1], o_idx[i, 2], a]
    c_idx, _, _ = sampled(rendered, max_candidates)
    c_pts, c_seg = points_at(depth, segment, c_idx, centre, focal)
    o_batch = o_idx[:, 0].copy()
    k, found_o = closest_of(o_pts, o_batch, c_pts, c_idx[:, 0].copy(), gate, max_d2)
    have = c_pts.shape[0] > 0
    n = nq + no
    q_weight = np.sqrt(q_ratio64).astype(dt)
    o_weight = np.sqrt(o_ratio64).astype(dt)
    points = np.empty((n, 3), dt)
    seg = np.zeros(n, np.int64)
    batch = np.empty(n, np.int64)
    offset = np.zeros((n, 3), dt)
    weight = np.empty(n, dt)
    for i in range(nq):
        points[i] = q_pts[i]
        seg[i] = q_seg[i]
        batch[i] = q_idx[i, 0]
        offset[i] = off_r[i]
        weight[i] = q_weight[i] if found[i] else zero
    for i in range(no):
        r = nq + i
        for a in range(3):
            points[r, a] = c_pts[k[i], a] if have else o_pts[i, a]
        seg[r] = c_seg[k[i]] if have else 0
        batch[r] = o_batch[i]
        dist = consts[0]
        if found_o[i]:
            for a in range(3):
                offset[r, a] = o_pts[i, a] - points[r, a]
            dist = norm3_float32(offset[r, 0], offset[r, 1], offset[r, 2])
        error[o_batch[i]] += dist * o_ratio[i]
        count[o_batch[i]] += o_ratio[i]
        weight[r] = o_weight[i] if found_o[i] else zero
    for i in range(n):
        weight[i] = weight[i] / (consts[2] if seg[i] >= first_limb else consts[1])
    return points, seg, batch, offset, weight, error, count


def extra_correspondences_cpu(
    render, obs, regions, observed, batch_size: int, margin: int, half: int,
    max_candidates: int, gate: float, max_distance: float, depth_gate: float,
    sigma_torso: float, sigma_limb: float, first_limb: int,
) -> tuple[torch.Tensor, ...]:  # fmt: skip
    """The correspondences of ``extra_rows`` for CPU tensors without autograd: points (N,
    3), segment (N,) int64, batch (N,) int64, offset (N, 3), weight (N,) (1 / sigma, 0 where
    no match), and the error sum and query count per pose (B,)."""
    depth = render.depth.numpy()
    centre = np.array([obs.intr.cx, obs.intr.cy], depth.dtype)
    focal = np.array([obs.intr.fx, obs.intr.fy], depth.dtype)
    out = _correspondences(
        regions.b1.numpy(), regions.b2_front.numpy(), regions.b2_behind.numpy(),
        regions.b3.numpy(), regions.good.numpy(), obs.silhouette.numpy(),
        render.mask.numpy(), int(margin), depth, render.segment.numpy(), centre, focal,
        obs.points.numpy(), observed.points.numpy(),
        observed.batch.numpy().astype(np.int64, copy=False), int(half), int(max_candidates),
        float(gate), float(max_distance) ** 2, float(depth_gate), float(sigma_torso),
        float(sigma_limb), int(first_limb), int(batch_size),
    )  # fmt: skip
    return tuple(torch.from_numpy(a) for a in out)
