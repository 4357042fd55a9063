"""The forest walk as a compiled per-pixel loop (numba): the CPU path, several times faster
than the level-synchronous torch walk of :mod:`shared.forest_walk` and equal to it bit for bit.

Importing this module imports numba (an optional dependency, the ``runtime`` extra); callers
import it lazily and fall back to :mod:`shared.forest_walk` when that fails.

Why it is faster: the torch walk makes some fifteen passes over all (pixel, tree) pairs per
level, and on two CPU threads every pass is an OpenMP fork and join. Here each pair walks down
its tree in registers and stops at its leaf. Sixteen pixels of one tree step together: their
node fetches are independent, so the CPU overlaps their cache misses in the deep levels.

Same arithmetic as the torch walk, step by step, in float32 without fused multiply-adds (numba
does not contract ``a * b + c`` unless asked to with fastmath), so every pair reaches the same
leaf: a probe is ``floor(min(max(u * (s / D(x)) + (x + 1.5), 0), W + 1))`` in the depth image
padded by one background pixel, and the right child is taken when ``D(probe u) - D(probe v) >
threshold``. Posteriors are the sum of the trees' leaf distributions in tree order divided by
the number of trees in float32, which is the order in which torch's ``mean`` over the tree
axis adds them (tested for one to five trees of 20 classes).

One thread. numba's ``parallel=True`` is out: starting numba's OpenMP thread pool in a process
that also runs torch made torch's own operations 5-7x slower. Two Python threads over halves of
the pixels (the kernels release the GIL) were 1.25x slower than one on the busy 2-core host,
and 1.4x slower when they shared smaller parts (``docs/experiments.md``).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["pad_person", "walk_leaf_rows", "walk_posteriors"]

_GROUP = (
    16  # pixels of one tree that step together (8-64 measured alike, one at a time 1.2x slower)
)
_JIT = {"cache": True, "nogil": True, "boundscheck": False}


@numba.njit(**_JIT)
def _pad(depth, valid, background, out):  # pragma: no cover - compiled
    b, h, w = depth.shape
    for f in range(b):
        for y in range(h + 2):
            for x in range(w + 2):
                out[f, y, x] = background
        for y in range(h):
            for x in range(w):
                if valid[f, y, x]:
                    out[f, y + 1, x + 1] = depth[f, y, x]


@numba.njit(inline="always", **_JIT)
def _clamp(x, hi):  # pragma: no cover - compiled
    # max(x, 0) then min(x, hi) as in torch; NaN (0 * inf, never for depths in millimetres)
    # goes to 0 rather than to an index outside the image.
    x = x if x > np.float32(0.0) else np.float32(0.0)
    return x if x < hi else hi


@numba.njit(inline="always", **_JIT)
def _child(table, node, feature):  # pragma: no cover - compiled
    # Written as a function with two returns: inlined, this compiles to code that measured
    # 1.5x faster than the same test as an if/else or a conditional expression in the loop.
    if feature > table[node, 4]:
        return np.int64(table[node, 6])
    return np.int64(table[node, 5])


@numba.njit(**_JIT)
def _walk(table, roots, flat, origin, inv, base, wp, hi_x, hi_y, levels, out):  # pragma: no cover
    n, t = origin.shape[0], roots.shape[0]
    nodes = np.empty(_GROUP, np.int64)
    for k in range(t):
        for p0 in range(0, n, _GROUP):
            g = min(_GROUP, n - p0)
            for i in range(g):
                nodes[i] = roots[k]
            for _ in range(levels):
                moving = False
                for i in range(g):
                    node = nodes[i]
                    left = np.int64(table[node, 5])
                    if left == node:  # a leaf points to itself
                        continue
                    moving = True
                    p = p0 + i
                    ix, iy, bx, by = inv[p, 0], inv[p, 1], base[p, 0], base[p, 1]
                    ux = _clamp(table[node, 0] * ix + bx, hi_x)
                    uy = _clamp(table[node, 1] * iy + by, hi_y)
                    vx = _clamp(table[node, 2] * ix + bx, hi_x)
                    vy = _clamp(table[node, 3] * iy + by, hi_y)
                    du = flat[origin[p] + np.int64(uy) * wp + np.int64(ux)]
                    dv = flat[origin[p] + np.int64(vy) * wp + np.int64(vx)]
                    nodes[i] = _child(table, node, du - dv)
                if not moving:
                    break
            for i in range(g):
                out[p0 + i, k] = np.int64(table[nodes[i], 7])  # the leaf's row of leaf_dist


@numba.njit(**_JIT)
def _average(leaf_dist, rows, out):  # pragma: no cover - compiled
    n, t = rows.shape
    c = leaf_dist.shape[1]
    trees = np.float32(t)
    for p in range(n):
        for j in range(c):
            out[p, j] = leaf_dist[rows[p, 0], j]
        for k in range(1, t):
            for j in range(c):
                out[p, j] += leaf_dist[rows[p, k], j]
        for j in range(c):
            out[p, j] /= trees


def pad_person(depth: np.ndarray, valid: np.ndarray, background: float) -> np.ndarray:
    """Depth padded by one pixel, ``background`` outside ``valid`` and around the image.

    Args:
        depth: (B, H, W) float32 metres; valid: (B, H, W) bool.
    Returns:
        (B, H + 2, W + 2) float32.
    """
    b, h, w = depth.shape
    out = np.empty((b, h + 2, w + 2), np.float32)
    _pad(_f32(depth), np.ascontiguousarray(valid, dtype=np.bool_), np.float32(background), out)
    return out


def walk_leaf_rows(
    table: np.ndarray,
    roots: np.ndarray,
    levels: int,
    background: float,
    depth: np.ndarray,
    valid: np.ndarray,
    pix: np.ndarray,
    scale: tuple[float, float] = (1.0, 1.0),
) -> np.ndarray:
    """Leaf row (index into ``leaf_dist``) reached by pixels ``pix`` in every tree:
    :func:`shared.forest_walk.walk_leaf_rows` with numpy arrays, the same rows.

    Args:
        table: (Nn, 8) float32 node table (``traversal_table``); roots: (T,) root nodes.
        levels: most steps to take (the forest's max depth).
        background: depth read by probes outside ``valid`` or off the image, metres.
        depth: (B, H, W) float32 metres; valid: (B, H, W) bool pixels that are the person.
        pix: (N, 3) int64 (frame, row, col) with a depth > 0 (normally those of ``valid``).
        scale: offset scale (fx'/fx, fy'/fy) of the camera against the trained one.
    Returns:
        (N, T) int64 leaf rows.
    """
    depth = _f32(depth)
    pix = np.ascontiguousarray(pix, dtype=np.int64)
    b, h, w = depth.shape
    padded = pad_person(depth, valid, background)
    # Per pixel, as in the torch walk: (sx / D, sy / D) and (x + 1.5, y + 1.5) in float32 (the
    # padded coordinates plus 0.5 for rounding) and the offset of its frame in ``padded``.
    inv = np.asarray(scale, np.float32)[None, :] / depth[pix[:, 0], pix[:, 1], pix[:, 2], None]
    base = pix[:, :0:-1].astype(np.float32) + np.float32(1.5)
    origin = pix[:, 0] * ((h + 2) * (w + 2))
    out = np.empty((pix.shape[0], roots.shape[0]), np.int64)
    table, roots = _f32(table), np.ascontiguousarray(roots, dtype=np.int64)
    hi_x, hi_y = np.float32(w + 1), np.float32(h + 1)
    flat = padded.reshape(-1)
    _walk(table, roots, flat, origin, inv, base, w + 2, hi_x, hi_y, int(levels), out)
    return out


def walk_posteriors(
    table: np.ndarray,
    roots: np.ndarray,
    leaf_dist: np.ndarray,
    levels: int,
    background: float,
    depth: np.ndarray,
    valid: np.ndarray,
    pix: np.ndarray,
    scale: tuple[float, float] = (1.0, 1.0),
) -> np.ndarray:
    """Posteriors (N, C) float32 of pixels ``pix`` averaged over the trees:
    :func:`shared.forest_walk.walk_posteriors` with numpy arrays, bit for bit.

    Args:
        leaf_dist: (L, C) float32 leaf distributions; the others as in :func:`walk_leaf_rows`.
    """
    rows = walk_leaf_rows(table, roots, levels, background, depth, valid, pix, scale)
    out = np.empty((rows.shape[0], leaf_dist.shape[1]), np.float32)
    _average(_f32(leaf_dist), rows, out)
    return out


def _f32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)
