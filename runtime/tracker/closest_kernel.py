"""The extra depth term's closest-point search as a compiled loop (numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:func:`runtime.tracker.extra_depth_term.closest_points` imports it lazily and keeps its torch
search where numba is missing or the points are on a GPU.

Why: the torch search builds each pose's whole (queries x candidates) table of squared
distances, masks it by the depth gate and takes its minimum, five passes over some million
entries per Gauss-Newton iteration (a sixth of a tracked frame's time on the CPU). Here each
pose's candidates are bucketed on a square grid over their (x, y) box (a counting sort, a few
candidates a cell), and each query searches the cells in rings around its own until a
ring's nearest possible point is beyond the best match so far: a dozen candidates for a query
near the surface. Within a ring a cell is skipped when its box (its (x, y) square and the depth
range of its candidates) lies farther than the best match so far or beyond the depth gate
(thirty-fifth session: a query visited ~105 candidates of which half passed the gate; the
searches of a batched refit took 0.38 instead of 0.52 ms an iteration, the same matches).
(The walk it replaced sorted each pose's candidates by height and scanned a band across the
whole body; the sort alone was a third of its time: eleventh session, ``docs/experiments.md``.)
Which candidate wins does not depend on the order they are looked at: the smallest squared
distance, ties to the smallest index.

The distance is the plain sum of squared differences in float64; the torch table expands it
as ``|q|^2 + |c|^2 - 2 q.c`` in the points' dtype. Both find the same candidate except where
two lie at the same distance to rounding (a tie goes to the first in both), which moves a
correspondence by less than the float32 resolution of the distance.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

__all__ = ["candidate_grid", "closest_in", "closest_of", "closest_points_cpu"]


# Candidates per cell if they filled their box evenly (a person fills about half of it): a
# query near the surface then looks at a few cells of a few candidates. 0.5, 1, 3 and 6 took
# 6.3, 4.4, 3.3 and 3.4 ms on ten captured searches of a batched refit (the sorted walk 5.6).
_CANDIDATES_PER_CELL = 3.0
# The grid's lower bound on a cell's distance gives way by this much (m): a point's cell comes
# from a rounded division, and no candidate that could win may be skipped.
_BOUND_SLACK = 1e-9


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _grids(c, cand_batch, groups):  # pragma: no cover - compiled
    """Each group's candidates bucketed on a square grid over their (x, y) box: per group its
    corner, cell size and shape, the candidates of every cell (``start``/``items``, in the
    caller's order within a cell) and each cell's depth range (``z_low``/``z_high``; empty
    cells +inf/-inf). Candidates with a non-finite x or y are left out (their distance
    compares false with everything: they never match)."""
    nc = c.shape[0]
    lo = np.full((groups, 2), np.inf)
    hi = np.full((groups, 2), -np.inf)
    count = np.zeros(groups, np.int64)
    for j in range(nc):
        x, y = c[j, 0], c[j, 1]
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        g = cand_batch[j]
        count[g] += 1
        lo[g, 0] = min(lo[g, 0], x)
        lo[g, 1] = min(lo[g, 1], y)
        hi[g, 0] = max(hi[g, 0], x)
        hi[g, 1] = max(hi[g, 1], y)
    size = np.ones(groups)
    shape = np.ones((groups, 2), np.int64)
    first = np.zeros(groups + 1, np.int64)  # each group's first cell
    for g in range(groups):
        if count[g] > 0:
            w = max(hi[g, 0] - lo[g, 0], 1e-6)
            h = max(hi[g, 1] - lo[g, 1], 1e-6)
            # About _CANDIDATES_PER_CELL a cell, and never more cells than a few per candidate
            # (a line of candidates would otherwise get a grid of tiny cells).
            most = 4.0 * count[g] + 16.0
            size[g] = max(
                np.sqrt(w * h * _CANDIDATES_PER_CELL / count[g]),
                np.sqrt(w * h / most),
                max(w, h) / most,
                1e-6,
            )
            shape[g, 0] = int(w / size[g]) + 1
            shape[g, 1] = int(h / size[g]) + 1
        first[g + 1] = first[g] + shape[g, 0] * shape[g, 1]
    cell = np.full(nc, -1, np.int64)
    start = np.zeros(first[groups] + 1, np.int64)
    for j in range(nc):
        x, y = c[j, 0], c[j, 1]
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        g = cand_batch[j]
        ix = min(int((x - lo[g, 0]) / size[g]), shape[g, 0] - 1)
        iy = min(int((y - lo[g, 1]) / size[g]), shape[g, 1] - 1)
        cell[j] = first[g] + iy * shape[g, 0] + ix
        start[cell[j] + 1] += 1
    for k in range(first[groups]):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    items = np.empty(start[-1], np.int64)
    z_low = np.full(first[groups], np.inf)
    z_high = np.full(first[groups], -np.inf)
    for j in range(nc):
        k = cell[j]
        if k >= 0:
            items[fill[k]] = j
            fill[k] += 1
            # A NaN depth leaves the range as it is: its candidate fails the gate anyway.
            z_low[k] = min(z_low[k], c[j, 2])
            z_high[k] = max(z_high[k], c[j, 2])
    return lo, size, shape, first, start, items, z_low, z_high


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _closest(q, q_group, c, grid, gate, max_d2, index, found):  # pragma: no cover - compiled
    """Each query's closest candidate of its group within the depth gate and ``max_d2``:
    the smallest (squared distance, candidate index) of the eligible ones. The query's
    group grid is searched in square rings around its cell, outwards, until a ring's
    nearest possible point is farther than the best distance so far (at first ``max_d2``);
    within a ring, a cell whose box is farther than that, or whose depths all lie beyond the
    gate, is not opened. The bounds give way by ``_BOUND_SLACK`` and compare strictly, so no
    candidate that could win or tie is passed over."""
    lo, size, shape, first, start, items, z_low, z_high = grid
    for i in range(q.shape[0]):
        g = q_group[i]
        qx, qy, qz = q[i, 0], q[i, 1], q[i, 2]
        if not (np.isfinite(qx) and np.isfinite(qy)):  # compares false with every candidate
            continue
        nx, ny, h = shape[g, 0], shape[g, 1], size[g]
        x0, y0 = lo[g, 0], lo[g, 1]
        cx = int(np.floor((qx - x0) / h))
        cy = int(np.floor((qy - y0) / h))
        # The first ring that reaches the grid, and the last that holds any of it.
        r0 = max(0, -cx, cx - (nx - 1), -cy, cy - (ny - 1))
        r1 = max(cx, nx - 1 - cx, cy, ny - 1 - cy)
        # Ring r >= 1 lies (r - 1) cells beyond the sides of the query's own cell, and the
        # query lies ``inside`` from the nearest of those sides.
        fx, fy = qx - (x0 + cx * h), qy - (y0 + cy * h)
        inside = max(0.0, min(fx, h - fx, fy, h - fy))
        best = max_d2
        best_j = -1
        for r in range(r0, r1 + 1):
            bound = max(0.0, (r - 1) * h + inside - _BOUND_SLACK) if r > 0 else 0.0
            if bound * bound > best:
                break
            for iy in range(max(cy - r, 0), min(cy + r, ny - 1) + 1):
                edge_row = iy == cy - r or iy == cy + r
                step = 1 if edge_row else 2 * r
                y_cell = y0 + iy * h
                gap_y = max(0.0, max(y_cell - qy, qy - (y_cell + h)) - _BOUND_SLACK)
                ix = cx - r
                while ix <= cx + r:
                    if 0 <= ix < nx:
                        k = first[g] + iy * nx + ix
                        x_cell = x0 + ix * h
                        gap_x = max(0.0, max(x_cell - qx, qx - (x_cell + h)) - _BOUND_SLACK)
                        gap_z = max(0.0, z_low[k] - qz, qz - z_high[k])
                        near = gap_x * gap_x + gap_y * gap_y + gap_z * gap_z
                        if not (gap_z > gate or near > best):
                            for t in range(start[k], start[k + 1]):
                                j = items[t]
                                dz = qz - c[j, 2]
                                if abs(dz) <= gate:
                                    dx = qx - c[j, 0]
                                    dy = qy - c[j, 1]
                                    d2 = dx * dx + dy * dy + dz * dz
                                    if d2 < best or (d2 == best and (best_j < 0 or j < best_j)):
                                        best = d2
                                        best_j = j
                    ix += step
        if best_j >= 0:
            index[i] = best_j
            found[i] = True


@numba.njit(cache=True, nogil=True, boundscheck=False)
def closest_of(query, query_batch, cand, cand_batch, gate, max_d2):  # pragma: no cover
    """:func:`closest_points_cpu` on numpy arrays (also inside compiled code): index into
    ``cand`` (0 where not found) and found."""
    nq, nc = query.shape[0], cand.shape[0]
    if nq == 0 or nc == 0:
        return np.zeros(nq, np.int64), np.zeros(nq, np.bool_)
    groups = 0
    for i in range(nq):
        groups = max(groups, query_batch[i] + 1)
    return closest_in(query, query_batch, candidate_grid(cand, cand_batch, groups), gate, max_d2)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def candidate_grid(cand, cand_batch, groups):  # pragma: no cover - compiled
    """The candidates as given and in float64, and their grids (:func:`_grids`) over at
    least ``groups`` groups, for :func:`closest_in`: made once, searched by every query set
    of the same candidates (a fit's observed points are the same at every iteration)."""
    c = cand.astype(np.float64)
    for j in range(c.shape[0]):
        groups = max(groups, cand_batch[j] + 1)
    return cand, c, _grids(c, cand_batch, groups)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def closest_in(query, query_batch, candidates, gate, max_d2):  # pragma: no cover - compiled
    """:func:`closest_of` against a :func:`candidate_grid` (groups with no candidates, and
    groups beyond the queries', change no query's search)."""
    _, c, grid = candidates
    nq, nc = query.shape[0], c.shape[0]
    index = np.full(nq, -1, np.int64)
    found = np.zeros(nq, np.bool_)
    if nq == 0 or nc == 0:
        return np.maximum(index, 0), found
    _closest(query.astype(np.float64), query_batch, c, grid, gate, max_d2, index, found)
    return np.maximum(index, 0), found


def closest_points_cpu(
    query: torch.Tensor,
    query_batch: torch.Tensor,
    cand: torch.Tensor,
    cand_batch: torch.Tensor,
    depth_gate: float,
    max_distance: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The same contract as :func:`runtime.tracker.extra_depth_term.closest_points`, for CPU
    tensors: index (N,) into ``cand`` and found (N,) bool; where nothing eligible lies within
    ``max_distance`` the index is 0 (the torch search's is the farther closest one: callers
    read the index only where found)."""
    index, found = closest_of(
        query.detach().numpy(), query_batch.numpy().astype(np.int64, copy=False),
        cand.detach().numpy(), cand_batch.numpy().astype(np.int64, copy=False),
        float(depth_gate), float(max_distance) ** 2,
    )  # fmt: skip
    return torch.from_numpy(index), torch.from_numpy(found)
