"""The RANSAC bone fits (:func:`runtime.detector.bone_ransac.fit_bones`) as compiled loops
(numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:mod:`~runtime.detector.bone_ransac` imports it lazily and keeps its torch code for GPUs and
where numba is missing.

Why: torch scores every pair of every bone against every point of the bone's subset through
(K, S, P, 3) temporaries (15 bones x 128 pairs x 400 points: 2.3 M numbers, ~10 ms of a
detector run's 69). Here each (bone, pair) counts its inliers in one pass. The rest of the
fit (the subsets' table, the pairs and their length test, the winners, the final inliers)
was some forty small torch ops on a few thousand points, ~4 ms of a detection's 28
(thirty-fourth session); :func:`fit_bones_cpu` runs it in two calls around the torch sort and
top-k (whose order among equal keys is torch's own). Every value is computed with the same
float32 operations in the same order as the torch code, so the same fit to the bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from ..tracker.extra_kernel import norm3_float32

__all__ = ["fit_bones_cpu", "inlier_counts_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False, inline="always")
def _on_bone(x0, x1, x2, a0, a1, a2, u0, u1, u2, low, reach, limit):  # pragma: no cover
    """``bone_ransac._inliers`` of one point: within the line's diameter, inside the reach."""
    r0 = x0 - a0
    r1 = x1 - a1
    r2 = x2 - a2
    t = r0 * u0 + r1 * u1 + r2 * u2
    perp2 = (r0 * r0 + r1 * r1 + r2 * r2) - t * t
    return perp2 <= limit and t >= low and t <= reach


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _counts(sub, sub_ok, a, u, d, reach, max_perp, out):  # pragma: no cover - compiled
    K, S = a.shape[0], a.shape[1]
    P = sub.shape[1]
    for k in range(K):
        limit = max_perp[k] * max_perp[k]
        for s in range(S):
            a0, a1, a2 = a[k, s, 0], a[k, s, 1], a[k, s, 2]
            u0, u1, u2 = u[k, s, 0], u[k, s, 1], u[k, s, 2]
            low = d[k, s] - reach[k]
            n = 0
            for p in range(P):
                if sub_ok[k, p] and _on_bone(
                    sub[k, p, 0], sub[k, p, 1], sub[k, p, 2], a0, a1, a2, u0, u1, u2, low,
                    reach[k], limit,
                ):  # fmt: skip
                    n += 1
            out[k, s] = n


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _pairs(points, seg, order, pair_draws, reach, min_reach, max_points):  # pragma: no cover
    """The subsets and the drawn pairs of ``fit_bones``: each bone's first ``max_points``
    points in ``order`` (``sub`` (K, P, 3), ``sub_ok`` (K, P) where they exist), the pairs'
    points ``a``, ``b`` (K, S, 3), distances ``d`` (K, S) and length test ``ok`` (K, S)."""
    K, S = pair_draws.shape[0], pair_draws.shape[1]
    N = seg.shape[0]
    counts = np.zeros(K, np.int64)
    for i in range(N):
        counts[seg[i]] += 1
    P = max(1, min(max_points, counts.max()))
    table = np.full((K, P), -1, np.int64)
    filled = np.zeros(K, np.int64)
    for i in range(N):  # the rank of a point within its bone, in the random order
        j = order[i]
        k = seg[j]
        if filled[k] < P:
            table[k, filled[k]] = j
        filled[k] += 1
    dt = points.dtype
    sub = np.empty((K, P, 3), dt)
    for k in range(K):
        for p in range(P):
            for c in range(3):
                sub[k, p, c] = points[max(table[k, p], 0), c]
    a = np.empty((K, S, 3), dt)
    b = np.empty((K, S, 3), dt)
    d = np.empty((K, S), dt)
    ok = np.empty((K, S), np.bool_)
    for k in range(K):
        n_sub = min(counts[k], P)
        top_index = max(n_sub - 1, 0)
        scale = np.float32(n_sub)
        for s in range(S):
            i = min(np.int64(pair_draws[k, s, 0] * scale), top_index)
            j = min(np.int64(pair_draws[k, s, 1] * scale), top_index)
            for c in range(3):
                a[k, s, c] = sub[k, i, c]
                b[k, s, c] = sub[k, j, c]
            d[k, s] = norm3_float32(b[k, s, 0] - a[k, s, 0], b[k, s, 1] - a[k, s, 1],
                                    b[k, s, 2] - a[k, s, 2])  # fmt: skip
            ok[k, s] = d[k, s] <= reach[k] and d[k, s] >= min_reach[k] and n_sub >= 2
    return sub, table >= 0, a, b, d, ok


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _winners(points, seg, sub, sub_ok, a, b, d, ok, pick, reach, max_perp):  # pragma: no cover
    """Scores the ``pick``-ed pairs (K, S') on ``_pairs``' subsets, takes each bone's first
    best, and tests every point against its bone's winner: inlier (N,), found (K,), line
    point and direction (K, 3), score (K,)."""
    K, Sp = pick.shape[0], pick.shape[1]
    dt = points.dtype
    pa = np.empty((K, Sp, 3), dt)
    pu = np.empty((K, Sp, 3), dt)
    pd = np.empty((K, Sp), dt)
    pok = np.empty((K, Sp), np.bool_)
    for k in range(K):
        for s in range(Sp):
            j = pick[k, s]
            dist = max(d[k, j], np.float32(1e-9))
            for c in range(3):
                pa[k, s, c] = a[k, j, c]
                pu[k, s, c] = (b[k, j, c] - a[k, j, c]) / dist
            pd[k, s] = d[k, j]
            pok[k, s] = ok[k, j]
    counts = np.empty((K, Sp), np.int64)
    _counts(sub, sub_ok, pa, pu, pd, reach, max_perp, counts)
    found = np.empty(K, np.bool_)
    line_point = np.empty((K, 3), dt)
    line_dir = np.empty((K, 3), dt)
    line_d = np.empty(K, dt)
    score = np.zeros(K, np.int64)
    for k in range(K):
        best, best_score = 0, np.int64(-2)
        for s in range(Sp):
            sc = counts[k, s] if pok[k, s] else np.int64(-1)
            if sc > best_score:  # the first of equal scores, as torch's argmax
                best, best_score = s, sc
        found[k] = pok[k, best]
        score[k] = max(best_score, 0)
        line_d[k] = pd[k, best]
        for c in range(3):
            line_point[k, c] = pa[k, best, c]
            line_dir[k, c] = pu[k, best, c]
    N = seg.shape[0]
    inlier = np.empty(N, np.bool_)
    for i in range(N):
        k = seg[i]
        inlier[i] = (not found[k]) or _on_bone(
            points[i, 0], points[i, 1], points[i, 2], line_point[k, 0], line_point[k, 1],
            line_point[k, 2], line_dir[k, 0], line_dir[k, 1], line_dir[k, 2],
            line_d[k] - reach[k], reach[k], max_perp[k] * max_perp[k],
        )  # fmt: skip
    return inlier, found, line_point, line_dir, score


def _array(x: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(x.detach().numpy())


def fit_bones_cpu(
    points: torch.Tensor,
    seg: torch.Tensor,
    reach: torch.Tensor,
    max_perp: torch.Tensor,
    max_points: int,
    samples: int,
    scored: int,
    min_pair_fraction: float,
    rand,
) -> tuple[torch.Tensor, ...]:
    """``fit_bones`` on float32 CPU tensors: (inlier (N,), found (K,), line point (K, 3),
    line direction (K, 3), score (K,)).

    Args:
        points: (N, 3) float32; seg: (N,) int64 bone of each point (0..K-1).
        reach, max_perp: (K,) float32 per bone.
        rand: ``rand(*shape)``, the caller's uniform draws (float32), called in the torch
            path's order.
    """
    K, N = reach.shape[0], points.shape[0]
    order = torch.argsort(seg.to(points.dtype) + rand(N) * 0.5)
    pair_draws = rand(K, samples, 2)
    min_reach = min_pair_fraction * reach
    pts, sg = _array(points), _array(seg)
    sub, sub_ok, a, b, d, ok = _pairs(
        pts, sg, _array(order), _array(pair_draws), _array(reach), _array(min_reach),
        int(max_points),
    )  # fmt: skip
    keys = torch.from_numpy(ok).to(points.dtype) + rand(K, samples) * 0.5
    pick = torch.topk(keys, min(scored, samples), dim=1).indices
    out = _winners(pts, sg, sub, sub_ok, a, b, d, ok, _array(pick), _array(reach), _array(max_perp))
    return tuple(torch.from_numpy(x) for x in out)


def inlier_counts_cpu(
    sub: torch.Tensor,
    sub_ok: torch.Tensor,
    a: torch.Tensor,
    u: torch.Tensor,
    d: torch.Tensor,
    reach: torch.Tensor,
    max_perp: torch.Tensor,
) -> torch.Tensor:
    """Inliers of each pair's bone hypothesis among the bone's valid subset points: (K, S)
    int64, as ``(_inliers(sub, a, u, d, reach, max_perp) & sub_ok).sum(-1)`` in
    :mod:`~runtime.detector.bone_ransac`.

    Args:
        sub: (K, P, 3) float32 subset points per bone; sub_ok: (K, P) bool, valid entries.
        a: (K, S, 3) first point of each pair; u: (K, S, 3) its unit direction; d: (K, S)
            pair distance; reach, max_perp: (K,) per bone.
    """
    out = np.zeros(a.shape[:2], np.int64)
    _counts(
        _array(sub), _array(sub_ok), _array(a), _array(u), _array(d), _array(reach),
        _array(max_perp), out,
    )  # fmt: skip
    return torch.from_numpy(out)
