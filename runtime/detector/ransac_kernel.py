"""The RANSAC bone fits' scoring (:func:`runtime.detector.bone_ransac.fit_bones`) as a compiled
loop (numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:mod:`~runtime.detector.bone_ransac` imports it lazily and keeps its torch code for GPUs and
where numba is missing.

Why: torch scores every pair of every bone against every point of the bone's subset through
(K, S, P, 3) temporaries (15 bones x 128 pairs x 400 points: 2.3 M numbers, ~10 ms of a
detector run's 69). Here each (bone, pair) counts its inliers in one pass, with the same
float32 operations in the same order as the torch test, so the same counts.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

__all__ = ["inlier_counts_cpu"]


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
                if not sub_ok[k, p]:
                    continue
                r0 = sub[k, p, 0] - a0
                r1 = sub[k, p, 1] - a1
                r2 = sub[k, p, 2] - a2
                t = r0 * u0 + r1 * u1 + r2 * u2
                perp2 = (r0 * r0 + r1 * r1 + r2 * r2) - t * t
                if perp2 <= limit and t >= low and t <= reach[k]:
                    n += 1
            out[k, s] = n


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

    def arr(x: torch.Tensor) -> np.ndarray:
        return np.ascontiguousarray(x.detach().numpy())

    _counts(arr(sub), arr(sub_ok), arr(a), arr(u), arr(d), arr(reach), arr(max_perp), out)
    return torch.from_numpy(out)
