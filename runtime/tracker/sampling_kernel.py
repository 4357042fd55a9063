"""The tracker's pixel sampling (:func:`runtime.tracker.regions.sample_pixels`) and the
rendered points at the samples (:func:`~runtime.tracker.regions.rendered_points`) as compiled
loops (numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:func:`~runtime.tracker.regions.sample_pixels` imports it lazily and keeps its torch code for
GPUs and where numba is missing.

Why: the samplers of every term call it some 6-7 times per Gauss-Newton iteration on masks of
a few thousand pixels; in torch each call is about ten small ops (nonzero, bincount, the hash,
its modulo, a gather, a filter), ~0.2 ms of dispatch for microseconds of work. Here one pass
counts each mask's pixels and a second writes the kept ones: the same rows, counts and
ratios, bit for bit. The rendered points (a gather and the pixel rays, some 4 calls per
iteration) are one loop in the depth's own dtype, the same operations in the same order as
the torch code's: the same points, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

__all__ = ["sample_pixels_cpu", "rendered_points_cpu", "sampled", "points_at"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _count(mask, total, box):  # pragma: no cover - compiled
    """Each mask's count of True pixels into ``total`` and the rows and columns (v0, v1, u0,
    u1), end-exclusive, that hold them into ``box`` (B, 4); returns the counts' sum."""
    nb, h, w = mask.shape
    n = 0
    for b in range(nb):
        c = 0
        v0, v1, u0, u1 = h, 0, w, 0
        for v in range(h):
            row = 0
            for u in range(w):
                row += mask[b, v, u]  # branch-free, so the row is summed in vector lanes
            if row == 0:
                continue
            c += row
            v0, v1 = min(v0, v), v + 1
            first = 0
            while not mask[b, v, first]:
                first += 1
            last = w - 1
            while not mask[b, v, last]:
                last -= 1
            u0, u1 = min(u0, first), max(u1, last + 1)
        total[b] = c
        box[b, 0], box[b, 1], box[b, 2], box[b, 3] = v0, v1, u0, u1
        n += c
    return n


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _sample(mask, max_count, thin, total, box, idx, kept):  # pragma: no cover - compiled
    """Rows (b, v, u) of the kept True pixels of ``mask`` (B, H, W) into ``idx``, row-major,
    and each mask's count of kept ones into ``kept``; ``thin``: whether the cap applies;
    ``box``: :func:`_count`'s, outside which the masks are False. Returns the number of rows
    written."""
    nb, h, w = mask.shape
    rows = 0
    for b in range(nb):
        # The same stride and hash as the torch code: ceil(count / cap), at least 1, and a
        # pixel kept where the hash of its (v, u) is 0 modulo the stride.
        stride = (total[b] + max_count - 1) // max_count if thin else 1
        if stride < 1:
            stride = 1
        k = 0
        for v in range(box[b, 0], box[b, 1]):
            for u in range(box[b, 2], box[b, 3]):
                if mask[b, v, u]:
                    key = (np.int64(u) * 73856093) ^ (np.int64(v) * 19349663)
                    if key % stride == 0:
                        idx[rows, 0] = b
                        idx[rows, 1] = v
                        idx[rows, 2] = u
                        rows += 1
                        k += 1
        kept[b] = k
    return rows


def sample_pixels_cpu(
    mask: torch.Tensor, max_count: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`runtime.tracker.regions.sample_pixels` for a CPU ``mask`` (B, H, W) bool: the
    same (N, 3) int64 rows, (B,) int64 counts and (N,) float64 ratios."""
    return tuple(torch.from_numpy(a) for a in sampled(mask.numpy(), int(max_count)))


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _rendered_points(depth, segment, idx, uv, centre, focal, points, seg):  # pragma: no cover
    """Points (N, 3) and segments (N,) at pixels ``idx`` (b, v, u); ``uv`` (N, 2) the pixels'
    (u, v) and ``centre``, ``focal`` (2,) the intrinsics, all in the depth's dtype."""
    for i in range(idx.shape[0]):
        b, v, u = idx[i, 0], idx[i, 1], idx[i, 2]
        d = depth[b, v, u]
        points[i, 0] = d * ((uv[i, 0] - centre[0]) / focal[0])
        points[i, 1] = d * ((uv[i, 1] - centre[1]) / focal[1])
        points[i, 2] = d
        seg[i] = segment[b, v, u]


def rendered_points_cpu(
    depth: torch.Tensor, segment: torch.Tensor, idx: torch.Tensor, intr
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`runtime.tracker.regions.rendered_points` for CPU tensors without autograd:
    ``depth`` (B, H, W) float, ``segment`` (B, H, W) int, ``idx`` (N, 3) int64."""
    d = depth.numpy()
    centre = np.array([intr.cx, intr.cy], d.dtype)
    focal = np.array([intr.fx, intr.fy], d.dtype)
    points, seg = points_at(d, segment.numpy(), np.ascontiguousarray(idx.numpy()), centre, focal)
    return torch.from_numpy(points), torch.from_numpy(seg)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def sampled(mask, max_count):  # pragma: no cover - compiled
    """The pixel sampling on numpy arrays (also inside compiled code): rows (N, 3) int64,
    each mask's count of True pixels (B,) and the float64 ratio each row stands for (N,)."""
    nb = mask.shape[0]
    total = np.zeros(nb, np.int64)
    kept = np.zeros(nb, np.int64)
    box = np.empty((nb, 4), np.int64)
    n = _count(mask, total, box)
    thin = max_count > 0 and n > max_count
    idx = np.empty((n, 3), np.int64)  # the True pixels bound the kept ones
    rows = _sample(mask, max_count, thin, total, box, idx, kept)
    idx = idx[:rows]
    ratio = np.ones(rows, np.float64)
    if thin:
        for i in range(rows):
            b = idx[i, 0]
            ratio[i] = np.float64(total[b]) / np.float64(max(kept[b], 1))
    return idx, total, ratio


@numba.njit(cache=True, nogil=True, boundscheck=False)
def points_at(depth, segment, idx, centre, focal):  # pragma: no cover - compiled
    """The rendered points on numpy arrays (also inside compiled code): points (N, 3) in the
    depth's dtype and segments (N,) at pixels ``idx`` (b, v, u)."""
    n = idx.shape[0]
    uv = np.empty((n, 2), depth.dtype)
    for i in range(n):
        uv[i, 0] = idx[i, 2]
        uv[i, 1] = idx[i, 1]
    points = np.empty((n, 3), depth.dtype)
    seg = np.empty(n, segment.dtype)
    _rendered_points(depth, segment, idx, uv, centre, focal, points, seg)
    return points, seg
