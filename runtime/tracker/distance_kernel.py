"""The observed silhouette's truncated distance transform as one compiled loop (numba): the
CPU path of :func:`runtime.tracker.observation.distance_to_mask`.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
``distance_to_mask`` imports it lazily and keeps its torch code for GPUs and installs without
numba.

Why: the torch transform shifts the whole image once per offset, (2T + 1) times in each of two
passes, some 150 small ops a frame (~1.4 ms at the working resolution, every frame). Here the
same two passes run per pixel over the same offsets with the same float32 values. Squared
distances are whole numbers, exact in float32; their square roots are read from a table made
by torch's own float32 square root, which is not always correctly rounded (sqrt(37) one unit
in the last place low on this build), so the distances are torch's to the bit on any build.
"""

from __future__ import annotations

import functools

import numba
import numpy as np
import torch

__all__ = ["distance_to_mask_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _distance(mask, reach, max_px, roots):  # pragma: no cover - compiled
    """Distances (B, H, W) float32 of each pixel to the nearest True pixel of ``mask``,
    searched ``reach`` pixels along each axis, capped at ``max_px``; ``roots[k]``: the square
    root of k, for k up to 2 reach^2."""
    nb, h, w = mask.shape
    far = np.float32(reach)
    cap = np.float32(max_px)
    out = np.empty((nb, h, w), np.float32)
    row = np.empty((h, w), np.float32)
    gap = np.empty(w, np.int64)
    for b in range(nb):
        # Row pass: the nearest True pixel of the same row within the reach (else the reach),
        # as two sweeps (the nearest on the left, then on the right).
        for v in range(h):
            last = -1
            for u in range(w):
                if mask[b, v, u]:
                    last = u
                gap[u] = u - last if last >= 0 else reach
            last = -1
            for u in range(w - 1, -1, -1):
                if mask[b, v, u]:
                    last = u
                d = min(gap[u], last - u if last >= 0 else reach, reach)
                row[v, u] = np.float32(d)
        # Column pass: the smallest row distance squared plus the row offset squared; rows
        # beyond the image count as the reach away. Offsets are tried nearest first, and
        # stop once the offset alone is no better (inside the silhouette: at once).
        for v in range(h):
            for u in range(w):
                best = row[v, u] * row[v, u]
                for s in range(1, reach + 1):
                    s2 = np.float32(s * s)
                    if s2 >= best:
                        break
                    for vv in (v - s, v + s):
                        r2 = row[vv, u] * row[vv, u] if 0 <= vv < h else far * far
                        d2 = r2 + s2
                        if d2 < best:
                            best = d2
                out[b, v, u] = min(roots[int(best)], cap)
    return out


@functools.lru_cache(maxsize=8)
def _roots(reach: int) -> np.ndarray:
    """torch's float32 square roots of 0, 1, ..., 2 reach^2 (every squared distance)."""
    return torch.arange(2 * reach * reach + 1, dtype=torch.float32).sqrt().numpy()


def distance_to_mask_cpu(mask: torch.Tensor, max_px: float) -> torch.Tensor:
    """:func:`runtime.tracker.observation.distance_to_mask` of a CPU (B, H, W) bool mask:
    (B, H, W) float32."""
    reach = int(max_px) + 1
    flags = np.ascontiguousarray(mask.numpy())
    return torch.from_numpy(_distance(flags, reach, float(max_px), _roots(reach)))
