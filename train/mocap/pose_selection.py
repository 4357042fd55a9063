"""Pose de-duplication by furthest-point sampling in joint space (Shotton et al. 2011).

Consecutive mocap frames are nearly identical; training on them wastes frames. Furthest-point
sampling picks, one at a time, the candidate furthest from everything picked so far, and stops
when ``count`` poses are picked or when no candidate is further than ``min_distance`` from the
picked set, so no two picked poses are closer than ``min_distance``. The distance between two
poses is the largest distance between corresponding joints after removing position on the floor
and heading (:func:`train.mocap.motion_library.heading_normalized_joints`): viewpoint sampling adds
those back.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["pose_distances", "furthest_point_sample"]


def pose_distances(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Max-over-joints distance between pose sets.

    Args:
        a: (N, J, 3); b: (J, 3) or (M, J, 3).
    Returns:
        (N,) or (N, M) metres.
    """
    if b.dim() == 2:
        return (a - b).norm(dim=-1).amax(-1)
    return (a[:, None] - b[None]).norm(dim=-1).amax(-1)


def furthest_point_sample(
    joints: np.ndarray, count: int, min_distance: float, seed: int = 0
) -> np.ndarray:
    """Indices of at most ``count`` poses, pairwise at least ``min_distance`` apart.

    Args:
        joints: (N, J, 3) heading-normalized joints, metres.
        count: most poses to pick.
        min_distance: stop once every candidate is this close to a picked pose, metres.
        seed: picks the first pose (the rest follow deterministically).
    Returns:
        (K,) int64 indices into ``joints`` in pick order, K <= count.
    """
    x = torch.as_tensor(np.asarray(joints), dtype=torch.float32)
    n = x.shape[0]
    if n == 0 or count <= 0:
        return np.zeros(0, dtype=np.int64)
    first = int(np.random.default_rng(seed).integers(n))
    picked = [first]
    nearest = pose_distances(x, x[first])
    for _ in range(min(count, n) - 1):
        i = int(torch.argmax(nearest))
        if float(nearest[i]) < min_distance:
            break
        picked.append(i)
        nearest = torch.minimum(nearest, pose_distances(x, x[i]))
    return np.asarray(picked, dtype=np.int64)
