"""The CPU path of :func:`shared.part_evidence.image_part_evidence`: one compiled pass over
the image (numba, an optional dependency; ``shared.compiled`` loads it, the torch code stays
for GPUs and installs without numba).

Why: the torch path measures every labelled pixel against every joint (16 x ~7,000 distances)
and sorts them, about 1.5 ms a frame on one thread, a tenth of a tracked frame; here each
pixel is measured only against the joints whose parts it carries (one to three) and each
joint keeps its ``k`` nearest as it goes.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["part_evidence_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _part_evidence(depth, mask, labels, member, intr, joints, k, near, count):  # pragma: no cover
    H, W = depth.shape
    J = joints.shape[0]
    C = member.shape[0]
    best = np.full((J, k), np.inf)
    for j in range(J):
        count[j] = 0.0
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    for v in range(H):
        for u in range(W):
            z = depth[v, u]
            c = labels[v, u]
            if not mask[v, u] or z <= 0 or c <= 0 or c >= C:
                continue
            # As depth_to_points: float32 arithmetic, then the distance in float64.
            x = np.float32(np.float32(np.float32(u) - cx) / fx) * z
            y = np.float32(np.float32(np.float32(v) - cy) / fy) * z
            for j in range(J):
                if not member[c, j]:
                    continue
                count[j] += 1.0
                dx = np.float64(x) - joints[j, 0]
                dy = np.float64(y) - joints[j, 1]
                dz = np.float64(z) - joints[j, 2]
                d = math.sqrt(dx * dx + dy * dy + dz * dz)
                if d < best[j, k - 1]:  # insert, keeping the k nearest sorted
                    i = k - 1
                    while i > 0 and best[j, i - 1] > d:
                        best[j, i] = best[j, i - 1]
                        i -= 1
                    best[j, i] = d
    for j in range(J):
        near[j] = best[j, k - 1]


def part_evidence_cpu(depth, mask, labels, member, intr, joints, k):
    """(J, 2) float64 (near_m, count) as ``image_part_evidence`` gives them, from numpy arrays:
    ``depth`` (H, W) float32 metres, ``mask`` (H, W) bool, ``labels`` (H, W) int64,
    ``member`` (C, J) bool, ``intr`` (4,) float32 fx, fy, cx, cy, ``joints`` (J, 3) float64."""
    J = joints.shape[0]
    near = np.empty(J)
    count = np.empty(J)
    _part_evidence(depth, mask, labels, member, intr, joints, k, near, count)
    return np.stack([near, count], -1)
