"""Leaf re-estimation: the grown trees' leaf distributions from many more pixels.

Growing a tree is the expensive part: its cost is (pixels x candidate features) per level, so
each tree sees a few million pixels and a depth-20 leaf ends up with a few dozen of them. The
leaf distributions are then noisy estimates. Pushing pixels down a fixed tree costs one probe
pair per level, about a thousand times less than growing per pixel, so the leaves can be
re-estimated from every frame of the set and many more pixels (Shotton et al. 2011 grew trees on
a subset of the data for the same reason). The split structure is unchanged.

Re-estimated distribution of leaf l: ``(n_l + prior * p_l) / (|n_l| + prior)``, with n_l the
class counts of the (class-balanced, as in training) re-estimation pixels reaching l and p_l the
grown distribution: leaves that no new pixel reaches keep their grown distribution.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import torch
from depthmocap.shared.forest_format import Forest, traversal_table
from depthmocap.shared.forest_walk import walk_leaf_rows

from .features import sample_candidates

__all__ = ["leaf_class_counts", "refit_leaves"]


def leaf_class_counts(
    forest: Forest,
    shards,
    class_weights: torch.Tensor,
    pixels_per_frame: int,
    generator: torch.Generator,
    device: torch.device,
    log=print,
) -> torch.Tensor:
    """(L, C) float64 counts of class-balanced person pixels of ``shards`` reaching each leaf.

    Args:
        shards: iterable of shards with ``depth`` (n, H, W) uint16 mm and ``labels`` (n, H, W).
        class_weights: (C,) pixel sampling weight per class (:func:`trainer.class_weights`).
        pixels_per_frame: person pixels drawn per frame (all of them when a frame has fewer).
    """
    table = torch.from_numpy(traversal_table(forest)).to(device)
    roots = torch.from_numpy(forest.roots).to(device, torch.int64)
    is_leaf = torch.from_numpy(forest.leaf >= 0).to(device)
    c = forest.num_classes
    counts = torch.zeros(forest.num_leaves * c, dtype=torch.float64, device=device)
    bg = float(forest.background_m)
    t0, frames = time.perf_counter(), 0
    for i, shard in enumerate(shards):
        n = len(shard)
        labels = torch.from_numpy(shard.labels)
        depth_mm = torch.from_numpy(shard.depth.astype(np.int32))
        valid = (labels > 0) & (depth_mm > 0) & (depth_mm < int(bg * 1000))
        h, w = labels.shape[1:]
        frame, flat = torch.nonzero(valid.view(n, h * w), as_tuple=True)
        cls = labels.view(n, h * w)[frame, flat].long()
        fr, flat = sample_candidates(
            frame, flat, cls, n, pixels_per_frame, class_weights, generator
        )
        pix = torch.stack([fr, flat // w, flat % w], 1).to(device)
        depth = (depth_mm.to(torch.float32) / 1000.0).to(device)
        rows = walk_leaf_rows(
            table, roots, forest.max_depth, bg, depth, valid.to(device), pix, is_leaf=is_leaf
        )  # (N, T)
        truth = labels[fr, flat // w, flat % w].to(device, torch.int64)
        index = (rows * c + truth.view(-1, 1)).view(-1)
        counts.index_add_(0, index, torch.ones_like(index, dtype=torch.float64))
        frames += n
        if log is not None and (i % 10 == 9 or i == 0):
            log(f"  leaf refit: {frames} frames ({time.perf_counter() - t0:.0f} s)")
    return counts.view(forest.num_leaves, c)


def refit_leaves(forest: Forest, counts: torch.Tensor, prior: float) -> Forest:
    """``forest`` with leaf distributions re-estimated from ``counts`` (L, C) (module docstring)."""
    grown = torch.from_numpy(forest.leaf_dist.astype(np.float64))
    counts = counts.cpu().to(torch.float64)
    dist = (counts + prior * grown) / (counts.sum(1, keepdim=True) + prior)
    stats = dict(forest.stats)
    reached = counts.sum(1)
    stats["leaf_refit"] = {
        "pixels_per_tree": int(reached.sum().item() / max(forest.num_trees, 1)),
        "leaves_reached": round(float((reached > 0).double().mean()), 4),
        "median_pixels_per_leaf": float(reached.median()),
        "prior": prior,
    }
    return replace(forest, leaf_dist=dist.to(torch.float16).numpy(), stats=stats)
