"""Reference per-pixel prediction for evaluation on the training side.

``train`` may not import ``runtime``, so evaluation uses this small level-synchronous traversal
(the runtime's ``ForestClassifier`` adds leaf compaction, strides and onnxruntime). The
arithmetic is the same, so the labels are the same; ``tests/runtime/test_forest_inference.py``
checks it.
"""

from __future__ import annotations

import torch

from shared.forest_format import Forest, traversal_table

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
    b, h, w = depth_m.shape
    hp, wp = h + 2, w + 2
    bg = float(forest.background_m)
    valid = mask & (depth_m > 0)
    padded = torch.nn.functional.pad(torch.where(valid, depth_m, bg), (1, 1, 1, 1), value=bg)
    flat = padded.reshape(-1)
    pix = torch.nonzero(valid)
    table = torch.from_numpy(traversal_table(forest)).to(device)
    roots = torch.from_numpy(forest.roots).to(device, torch.int64)
    n, t = pix.shape[0], roots.shape[0]
    pf = pix.to(torch.float32)
    dx = depth_m[pix[:, 0], pix[:, 1], pix[:, 2]]
    invd = torch.tensor(scale, dtype=torch.float32, device=device).view(1, 2) / dx.view(-1, 1)
    inv = invd.repeat(1, 2).view(n, 1, 4)
    base = (torch.stack([pf[:, 2], pf[:, 1]], 1) + 1.5).repeat(1, 2).view(n, 1, 4)
    hi = torch.tensor([w + 1, h + 1, w + 1, h + 1], dtype=torch.float32, device=device)
    frame0 = (pix[:, 0] * (hp * wp)).view(n, 1, 1)
    node = roots.view(1, t).expand(n, t)
    for _ in range(forest.max_depth):
        row = table[node]  # (N, T, 8)
        c = torch.minimum((row[..., 0:4] * inv + base).clamp_(min=0.0), hi).floor_()
        lin = (c[..., 1::2] * wp).add_(c[..., 0::2]).to(torch.int64) + frame0
        d = flat[lin]
        node = torch.where(d[..., 0] - d[..., 1] > row[..., 4], row[..., 6], row[..., 5]).long()
    leaf = table[node, 7].to(torch.int64)
    dist = torch.from_numpy(forest.leaf_dist).to(device, torch.float32)
    return pix, dist[leaf].mean(1)
