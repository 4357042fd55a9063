"""Level-synchronous walk of a forest's trees for many pixels at once (torch, any device).

Shared by the runtime's ``ForestClassifier`` and the training side's evaluation, so both give
the same labels by construction. Depth probes follow Shotton et al. 2011:
``f = D(x + u / D(x)) - D(x + v / D(x))`` on a depth image padded by one background pixel, so
probes off the image read the background constant.
"""

from __future__ import annotations

import torch

__all__ = ["traverse", "walk_leaf_rows", "walk_posteriors"]

_COMPACT_EVERY = 4  # levels between dropping (pixel, tree) pairs that sit on a leaf


def traverse(
    table: torch.Tensor,
    roots: torch.Tensor,
    padded_flat: torch.Tensor,
    lin0: torch.Tensor,
    invd4: torch.Tensor,
    base4: torch.Tensor,
    hi4: torch.Tensor,
    wp: int,
    levels: int,
    is_leaf: torch.Tensor | None = None,
) -> torch.Tensor:
    """Leaf node reached by every (pixel, tree) pair.

    Args:
        table: (Nn, 8) float32 node table (``traversal_table``).
        roots: (T,) int64 root nodes.
        padded_flat: flattened (B, H + 2, W + 2) float32 depth, background outside the person.
        lin0: (N,) int64 flat index of each pixel's frame origin in ``padded_flat``.
        invd4: (N, 4) float32 (sx / D, sy / D, sx / D, sy / D) at each pixel.
        base4: (N, 4) float32 (x + 1.5, y + 1.5, x + 1.5, y + 1.5) at each pixel (padded
            coordinates plus 0.5 for rounding to the nearest pixel).
        hi4: (4,) float32 (W + 1, H + 1, W + 1, H + 1), the last padded column/row.
        wp: padded row length W + 2.
        levels: steps to take (the forest's max depth).
        is_leaf: (Nn,) bool; when given, pairs that reached a leaf are dropped every few levels
            (pays off on the CPU, where the work is proportional to the pairs).
    Returns:
        (N, T) int32 leaf node of each pair.
    """
    n, t = lin0.shape[0], roots.shape[0]
    m = n * t
    node = roots.to(torch.int32).repeat(n)  # pair p * T + tree
    inv = invd4.repeat_interleave(t, dim=0)
    base = base4.repeat_interleave(t, dim=0)
    # Frame offsets are added after the float part, so any batch size is exact.
    l0 = None if not bool(lin0.any()) else lin0.repeat_interleave(t).view(-1, 1)
    out = torch.empty(m, dtype=torch.int32, device=node.device)
    slot = torch.arange(m, device=node.device)
    for level in range(levels):
        row = table.index_select(0, node)  # (M, 8)
        c = torch.minimum((row[:, 0:4] * inv + base).clamp_(min=0.0), hi4).floor_()
        lin = (c[:, 1::2] * wp).add_(c[:, 0::2])  # (M, 2) exact integers in float32 (< 2**24)
        lin = lin.to(torch.int64) if l0 is None else lin.to(torch.int64) + l0
        d = padded_flat.index_select(0, lin.view(-1)).view(-1, 2)
        node = torch.where(d[:, 0] - d[:, 1] > row[:, 4], row[:, 6], row[:, 5]).to(torch.int32)
        if is_leaf is not None and (level + 1) % _COMPACT_EVERY == 0 and level + 1 < levels:
            moving = ~is_leaf[node]
            if not bool(moving.all()):
                done = ~moving
                out[slot[done]] = node[done]
                node, slot = node[moving], slot[moving]
                inv, base = inv[moving], base[moving]
                l0 = None if l0 is None else l0[moving]
                if node.numel() == 0:
                    break
    out[slot] = node
    return out.view(n, t)


def walk_leaf_rows(
    table: torch.Tensor,
    roots: torch.Tensor,
    levels: int,
    background: float,
    depth: torch.Tensor,
    valid: torch.Tensor,
    pix: torch.Tensor,
    scale: tuple[float, float] = (1.0, 1.0),
    is_leaf: torch.Tensor | None = None,
) -> torch.Tensor:
    """Leaf row (index into ``leaf_dist``) reached by pixels ``pix`` (N, 3) in every tree.

    Args:
        table, roots, levels, is_leaf: as in :func:`traverse`.
        background: depth read by probes outside ``valid`` or off the image, metres.
        depth: (B, H, W) float32 metres; valid: (B, H, W) bool pixels that are the person.
        pix: (N, 3) int64 (frame, row, col).
        scale: offset scale (fx'/fx, fy'/fy) of the camera against the trained one.
    Returns:
        (N, T) int64 leaf rows.
    """
    b, h, w = depth.shape
    hp, wp = h + 2, w + 2
    dev = depth.device
    person = torch.where(valid, depth, background)
    padded = torch.nn.functional.pad(person, (1, 1, 1, 1), value=background)
    pf = pix.to(torch.float32)
    dx = depth[pix[:, 0], pix[:, 1], pix[:, 2]]
    invd4 = (
        torch.tensor(scale, dtype=torch.float32, device=dev).view(1, 2) / dx.view(-1, 1)
    ).repeat(1, 2)
    base4 = (torch.stack([pf[:, 2], pf[:, 1]], dim=1) + 1.5).repeat(1, 2)
    hi4 = torch.tensor([w + 1, h + 1, w + 1, h + 1], dtype=torch.float32, device=dev)
    lin0 = pix[:, 0] * (hp * wp)
    leaves = traverse(
        table, roots, padded.reshape(-1), lin0, invd4, base4, hi4, wp, levels, is_leaf
    )
    return table[:, 7].index_select(0, leaves.view(-1)).to(torch.int64).view(leaves.shape)


def walk_posteriors(
    table: torch.Tensor,
    roots: torch.Tensor,
    leaf_dist: torch.Tensor,
    levels: int,
    background: float,
    depth: torch.Tensor,
    valid: torch.Tensor,
    pix: torch.Tensor,
    scale: tuple[float, float] = (1.0, 1.0),
    is_leaf: torch.Tensor | None = None,
) -> torch.Tensor:
    """Posteriors (N, C) of pixels ``pix`` (N, 3) (frame, row, col) averaged over the trees.

    Args:
        leaf_dist: (L, C) float32; the others as in :func:`walk_leaf_rows`.
    """
    rows = walk_leaf_rows(table, roots, levels, background, depth, valid, pix, scale, is_leaf)
    return leaf_dist.index_select(0, rows.view(-1)).view(*rows.shape, -1).mean(1)
