"""Per-pixel prediction for evaluation on the training side (``train`` may not import
``runtime``); the tree walk is :mod:`shared.forest_walk`, the same as the runtime's."""

from __future__ import annotations

import torch
from depthmocap.shared.forest_format import Forest, traversal_table
from depthmocap.shared.forest_walk import walk_posteriors

__all__ = ["predict_posteriors"]


def predict_posteriors(
    forest: Forest,
    depth_m: torch.Tensor,
    mask: torch.Tensor,
    scale: tuple[float, float] = (1.0, 1.0),
) -> tuple[torch.Tensor, torch.Tensor]:
    """Posteriors of the masked pixels with a reading.

    Args:
        depth_m: (B, H, W) float32 metres, 0 = no reading.
        mask: (B, H, W) bool person mask.
        scale: offset scale (fx'/fx, fy'/fy) of the evaluation camera.
    Returns:
        pixels (N, 3) int64 (frame, row, col) and posteriors (N, C) float32.
    """
    device = depth_m.device
    valid = mask & (depth_m > 0)
    pix = torch.nonzero(valid)
    table = torch.from_numpy(traversal_table(forest)).to(device)
    roots = torch.from_numpy(forest.roots).to(device, torch.int64)
    dist = torch.from_numpy(forest.leaf_dist).to(device, torch.float32)
    post = walk_posteriors(
        table, roots, dist, forest.max_depth, float(forest.background_m), depth_m, valid, pix, scale
    )
    return pix, post
