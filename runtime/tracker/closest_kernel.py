"""The extra depth term's closest-point search as a compiled loop (numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:func:`runtime.tracker.extra_depth_term.closest_points` imports it lazily and keeps its torch
search where numba is missing or the points are on a GPU.

Why: the torch search builds each pose's whole (queries x candidates) table of squared
distances, masks it by the depth gate and takes its minimum, five passes over some million
entries per Gauss-Newton iteration (a sixth of a tracked frame's time on the CPU). Here each
pose's candidates are sorted by height, and each query walks outwards from its own height until
the height difference alone is beyond the best match so far: a few percent of the candidates
instead of all of them.

The distance is the plain sum of squared differences in float64; the torch table expands it
as ``|q|^2 + |c|^2 - 2 q.c`` in the points' dtype. Both find the same candidate except where
two lie at the same distance to rounding (a tie goes to the first in both), which moves a
correspondence by less than the float32 resolution of the distance.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

__all__ = ["closest_of", "closest_points_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _closest(q, q_group, c, c_index, start, end, gate, max_d2, index, found):  # pragma: no cover
    """Each query's closest candidate of its group within the depth gate and ``max_d2``. A
    group's candidates are sorted by height (y, the axis a standing person spreads most
    along), so the scan walks outwards from the query's height and stops where the height
    difference alone exceeds the best distance so far (at first ``max_d2``)."""
    for i in range(q.shape[0]):
        g = q_group[i]
        # Nothing beyond max_d2 is ever a match, so the walk stops there even when no
        # eligible candidate is near (otherwise it would scan the pose's every candidate).
        best = max_d2
        best_j = -1
        qx, qy, qz = q[i, 0], q[i, 1], q[i, 2]
        lo, hi = start[g], end[g]
        mid = lo + np.searchsorted(c[lo:hi, 1], qy)
        for step in (1, -1):
            j = mid if step == 1 else mid - 1
            while lo <= j < hi:
                dy = qy - c[j, 1]
                if dy * dy > best:
                    break
                dz = qz - c[j, 2]
                if abs(dz) <= gate:
                    dx = qx - c[j, 0]
                    d2 = dx * dx + dy * dy + dz * dz
                    # Ties go to the candidate first in the caller's order, as in torch's.
                    if d2 < best or (d2 == best and (best_j < 0 or c_index[j] < c_index[best_j])):
                        best = d2
                        best_j = j
                j += step
        if best_j >= 0:
            index[i] = c_index[best_j]
            found[i] = True


@numba.njit(cache=True, nogil=True, boundscheck=False)
def closest_of(query, query_batch, cand, cand_batch, gate, max_d2):  # pragma: no cover
    """:func:`closest_points_cpu` on numpy arrays (also inside compiled code): index into
    ``cand`` (0 where not found) and found."""
    nq, nc = query.shape[0], cand.shape[0]
    index = np.full(nq, -1, np.int64)
    found = np.zeros(nq, np.bool_)
    if nq == 0 or nc == 0:
        return np.maximum(index, 0), found
    q = query.astype(np.float64)
    c = cand.astype(np.float64)
    groups = 0
    for i in range(nq):
        groups = max(groups, query_batch[i] + 1)
    y_max, y_min = 0.0, 0.0
    for i in range(nc):
        groups = max(groups, cand_batch[i] + 1)
        y_max = max(y_max, c[i, 1])
        y_min = min(y_min, c[i, 1])
    key = cand_batch * (y_max - y_min + 1.0) + c[:, 1]
    presorted = True
    for i in range(1, nc):
        if not key[i] >= key[i - 1]:  # as numpy's all(key[1:] >= key[:-1]): NaN unsorted
            presorted = False
            break
    # Ties in the key may come out in any order: the walk breaks ties by candidate index.
    order = np.arange(nc) if presorted else np.argsort(key)
    sorted_batch = cand_batch[order]
    bounds = np.searchsorted(sorted_batch, np.arange(groups + 1))
    c_sorted = np.ascontiguousarray(c[order])
    _closest(q, query_batch, c_sorted, order, bounds[:-1], bounds[1:], gate, max_d2, index, found)
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
