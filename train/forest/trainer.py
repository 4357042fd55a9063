"""From a training set to a :class:`shared.forest_format.Forest`: pixels, features, trees.

1. **Frames and pixels.** Each tree gets a random ``frames_per_tree`` subset of the frames and
   draws ``pixels_per_frame`` person pixels from each (class-balanced when configured: weights
   ``frequency^-balance_power`` from the set's class pixel counts). Only person pixels
   (``labels > 0``) with a depth reading are drawn; the depth they are featurized on has every
   other pixel at the background constant, exactly as the runtime sees a segmented person.
2. **Feature pool.** Each tree draws ``feature_pool`` random offset pairs (uniform within
   ``offset_max_m`` in the scene, converted to pixel*metres with the set's focal lengths) and
   computes all of them for all its pixels once, in int16 millimetres, in one streaming pass
   over the shards (all trees at once, so every shard is read and decompressed once).
3. **Quantile bins.** Each pool feature is cut into ``thresholds_per_candidate`` quantile bins,
   with edges taken from the first shard's pixels of that tree and placed half-way between
   millimetre values (so no feature value ever equals a threshold). Pixels keep only the uint8
   bin code: a (pixels x pool) byte matrix per tree.
4. **Growing** (:mod:`train.forest.grow`), then the trees' split features become offset pairs
   and their bin thresholds become metres; leaves keep their normalized class counts as float16
   distributions.
5. **Leaf re-estimation** (optional, :mod:`train.forest.refit`): one more pass pushes
   ``refit_pixels_per_frame`` pixels of every frame down the grown trees and re-estimates the
   leaf distributions from them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
from depthmocap.shared.config import config_to_dict
from depthmocap.shared.forest_format import Forest

from .config import ForestConfig
from .features import (
    depth_features_mm,
    pad_with_background,
    person_depth_mm,
    sample_candidates,
    sample_offset_pairs,
)
from .grow import GrownTree, GrowParams, grow_tree

__all__ = ["TreeData", "resolve_device", "class_weights", "collect_tree_data", "train_forest"]


@dataclass
class TreeData:
    """Training pixels of one tree.

    Attributes:
        bins: (N, P) uint8 quantile bin of each pool feature for each pixel.
        labels: (N,) int64 class of each pixel.
        u, v: (P, 2) float32 offset pairs of the pool (pixel*metres).
        edges_mm: (P, B - 1) float32 bin edges (half-integer millimetres), ascending.
    """

    bins: torch.Tensor
    labels: torch.Tensor
    u: torch.Tensor
    v: torch.Tensor
    edges_mm: torch.Tensor


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' requested but CUDA is not available")
    return torch.device(name)


def class_weights(pixel_counts: np.ndarray, cfg: ForestConfig) -> torch.Tensor:
    """(C,) float32 sampling weight per class: 0 for background and absent classes."""
    counts = np.asarray(pixel_counts, dtype=np.float64)
    w = np.zeros_like(counts)
    present = counts > 0
    present[0] = False
    if cfg.class_balanced:
        freq = counts[present] / counts[present].sum()
        w[present] = freq ** (-cfg.balance_power)
    else:
        w[present] = 1.0
    return torch.as_tensor(w / max(w.max(), 1e-12), dtype=torch.float32)


def _quantile_edges(features: torch.Tensor, num_bins: int, max_rows: int = 20000) -> torch.Tensor:
    """(P, num_bins - 1) half-integer mm edges from (n, P) int16 features (first rows)."""
    ordered = features[:max_rows].T.to(torch.float32).sort(dim=1).values  # (P, n)
    n = ordered.shape[1]
    pos = ((torch.arange(1, num_bins) * n) // num_bins).clamp(max=n - 1)
    return (ordered[:, pos.to(ordered.device)] + 0.5).contiguous()


def _bin_table(edges: torch.Tensor, max_abs_mm: int) -> torch.Tensor:
    """(P, 2 * max_abs_mm + 1) uint8: the bin of every integer feature value in mm."""
    p = edges.shape[0]
    values = torch.arange(-max_abs_mm, max_abs_mm + 1, dtype=torch.float32, device=edges.device)
    return torch.searchsorted(edges, values.expand(p, -1).contiguous()).to(torch.uint8)


def _bin(features: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
    """(n, P) int16 features -> (n, P) uint8 bin codes by table lookup."""
    p, width = table.shape
    offset = (torch.arange(p, device=table.device) * width + width // 2).view(1, p)
    index = features.to(torch.int64).add_(offset)
    return table.view(-1).index_select(0, index.view(-1)).view(features.shape)


def plan_trees(
    cfg: ForestConfig, total_frames: int, fx: float, fy: float, device: torch.device
) -> list[dict]:
    """Per tree: its frame subset (total_frames,) bool, offset pool u, v (P, 2) and a seed for
    its pixel draws; all from ``cfg.seed``, so a tree does not depend on how trees are grouped
    into passes over the data."""
    gen = torch.Generator().manual_seed(cfg.seed)
    max_px_m = (cfg.offset_max_m * fx, cfg.offset_max_m * fy)
    take = max(1, int(round(cfg.frames_per_tree * total_frames)))
    plans = []
    for t in range(cfg.trees):
        chosen = torch.zeros(total_frames, dtype=torch.bool)
        chosen[torch.randperm(total_frames, generator=gen)[:take]] = True
        u, v = sample_offset_pairs(cfg.feature_pool, max_px_m, cfg.unary_fraction, gen)
        plans.append(
            {"frames": chosen, "u": u.to(device), "v": v.to(device), "seed": cfg.seed * 1009 + t}
        )
    return plans


def collect_tree_data(
    shards, plans: list[dict], pixel_counts: np.ndarray, cfg: ForestConfig,
    device: torch.device, log=print,
) -> list[TreeData]:  # fmt: skip
    """One pass over the shards: pixels, pool features and bins of the planned trees.

    Args:
        shards: iterable of shards with ``depth`` (n, H, W) uint16 mm and ``labels`` (n, H, W).
        plans: from :func:`plan_trees`.
        pixel_counts: (C,) class pixel counts of the set (class balancing).
    """
    bg_mm = int(round(cfg.background_m * 1000))
    weights = class_weights(pixel_counts, cfg)
    num_bins = cfg.thresholds_per_candidate
    trees = [
        {**p, "gen": torch.Generator().manual_seed(p["seed"]), "edges": None, "bins": [],
         "labels": []}
        for p in plans
    ]  # fmt: skip
    start = 0
    t0 = time.perf_counter()
    for i, shard in enumerate(shards):
        n = len(shard)
        depth = torch.from_numpy(shard.depth.astype(np.int32))
        labels = torch.from_numpy(shard.labels)
        person = labels > 0
        valid = person & (depth > 0) & (depth < bg_mm)
        padded = pad_with_background(person_depth_mm(depth, person, bg_mm), bg_mm).to(device)
        h, w = labels.shape[1:]
        cand_frame, cand_flat = torch.nonzero(valid.view(n, h * w), as_tuple=True)
        cand_cls = labels.view(n, h * w)[cand_frame, cand_flat].long()
        for tree in trees:
            chosen = tree["frames"][start : start + n]
            if not bool(chosen.any()):
                continue
            mine = chosen[cand_frame]
            # Random draws on the CPU generator: the same pixels on every device.
            fr, flat = sample_candidates(
                cand_frame[mine], cand_flat[mine], cand_cls[mine], n, cfg.pixels_per_frame,
                weights, tree["gen"],
            )  # fmt: skip
            r, c = flat // w, flat % w
            cls = labels[fr, r, c].to(torch.int64)
            fr, r, c = fr.to(device), r.to(device), c.to(device)
            feats = depth_features_mm(padded, fr, r, c, tree["u"], tree["v"])
            if tree["edges"] is None:
                tree["edges"] = _quantile_edges(feats, num_bins)
                tree["table"] = _bin_table(tree["edges"], bg_mm)
            tree["bins"].append(_bin(feats, tree["table"]))
            tree["labels"].append(cls.to(device))
        start += n
        if log is not None and (i % 10 == 9 or i == 0):
            px = sum(sum(b.shape[0] for b in t["bins"]) for t in trees)
            log(f"  shard {i + 1}: {start} frames, {px} pixels ({time.perf_counter() - t0:.0f} s)")
    out = []
    for t in trees:  # concatenate tree by tree, freeing the pieces: bounded peak memory
        if not t["bins"]:
            continue
        bins = torch.cat(t["bins"])
        t["bins"].clear()
        out.append(TreeData(bins, torch.cat(t["labels"]), t["u"], t["v"], t["edges"]))
    return out


def _tree_arrays(tree: GrownTree, data: TreeData, offset: int, leaf_offset: int) -> dict:
    """Node arrays of one grown tree with global node and leaf indices."""
    feature = tree.feature.cpu()
    inner = feature >= 0
    f = feature.clamp(min=0)
    u = torch.where(inner.view(-1, 1), data.u.cpu()[f], 0.0)
    v = torch.where(inner.view(-1, 1), data.v.cpu()[f], 0.0)
    b = tree.bin_threshold.cpu().clamp(min=0)
    thr_mm = data.edges_mm.cpu()[f, b]
    threshold = torch.where(inner, thr_mm / 1000.0, 0.0)
    leaf_rows = torch.cumsum(~inner, 0) - 1 + leaf_offset
    counts = tree.counts.cpu()[~inner]
    dist = counts / counts.sum(1, keepdim=True).clamp(min=1.0)
    return {
        "u": u.numpy(),
        "v": v.numpy(),
        "threshold": threshold.numpy(),
        "left": torch.where(inner, tree.left.cpu() + offset, -1).numpy(),
        "right": torch.where(inner, tree.right.cpu() + offset, -1).numpy(),
        "leaf": torch.where(inner, -1, leaf_rows).numpy(),
        "leaf_dist": dist.numpy(),
    }


def _limited(trainset, max_frames: int | None):
    """Shards of ``trainset`` and their frame counts, cut after ``max_frames`` frames."""
    counts = [int(s["frames"]) for s in trainset.manifest["shards"]]
    if max_frames is None:
        return iter(trainset), counts
    keep, total = [], 0
    for n in counts:
        if total >= max_frames:
            break
        keep.append(min(n, max_frames - total))
        total += keep[-1]

    def gen():
        for i, n in enumerate(keep):
            shard = trainset.shard(i)
            if n < len(shard):
                shard = type(shard)(
                    shard.depth[:n], shard.labels[:n], shard.joints[:n], shard.q[:n],
                    shard.body[:n], shard.intrinsics,
                )  # fmt: skip
            yield shard

    return gen(), keep


def train_forest(trainset, cfg: ForestConfig, log=print, max_frames: int | None = None) -> Forest:
    """Train a forest on a :class:`train.synth.trainset.TrainSet` (see module docstring).

    ``max_frames`` trains on the first frames only (quick runs, timing extrapolation).
    """
    cfg.validate()
    log = log or (lambda _msg: None)
    device = resolve_device(cfg.device)
    if device.type == "cpu":
        torch.set_num_threads(cfg.threads)
    intr = trainset.intrinsics
    class_names = trainset.class_names
    counts = trainset.manifest.get("class_pixel_counts")
    _, frame_counts = _limited(trainset, max_frames)
    if not counts or sum(counts[1:]) == 0:
        counts = np.bincount(trainset.shard(0).labels.ravel(), minlength=len(class_names))
    t0, cpu0 = time.perf_counter(), time.process_time()
    frames = sum(frame_counts)
    plans = plan_trees(cfg, frames, intr.fx, intr.fy, device)
    per_pass = cfg.trees_per_pass if cfg.trees_per_pass > 0 else cfg.trees
    params = GrowParams(
        max_depth=cfg.max_depth,
        min_samples=cfg.min_samples,
        min_gain=cfg.min_gain,
        candidates=cfg.candidates_per_node,
        histogram_budget=cfg.histogram_budget,
    )
    parts, roots, tree_stats = [], [], []
    offset = leaf_offset = 0
    t_features = 0.0
    for first in range(0, cfg.trees, per_pass):
        group = plans[first : first + per_pass]
        t1 = time.perf_counter()
        log(
            f"trees {first + 1}-{first + len(group)}: pixels and {cfg.feature_pool} features "
            f"per tree from {frames} frames"
        )
        shards, _ = _limited(trainset, max_frames)
        data = collect_tree_data(shards, group, np.asarray(counts), cfg, device, log)
        t_features += time.perf_counter() - t1
        while data:
            d = data.pop(0)
            t = len(roots)
            t1 = time.perf_counter()
            log(f"tree {t + 1}/{cfg.trees}: {d.bins.shape[0]} pixels")
            gen = torch.Generator().manual_seed(plans[t]["seed"] + 1)
            grown = grow_tree(
                d.bins, d.labels, len(class_names), cfg.thresholds_per_candidate, params, gen,
                log,
            )  # fmt: skip
            arrays = _tree_arrays(grown, d, offset, leaf_offset)
            parts.append(arrays)
            roots.append(offset)
            offset += arrays["left"].shape[0]
            leaf_offset += arrays["leaf_dist"].shape[0]
            st = {k: grown.stats[k] for k in ("nodes", "leaves", "depth")}
            st.update(pixels=int(d.bins.shape[0]), seconds=round(time.perf_counter() - t1, 2))
            tree_stats.append(st)
            log(f"tree {t + 1}: {st}")
            del d, grown
    merged = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    t_refit, refit_stats = 0.0, {}
    if cfg.refit_pixels_per_frame > 0:
        from .refit import leaf_class_counts, refit_leaves

        t1 = time.perf_counter()
        log(f"re-estimating leaves from {cfg.refit_pixels_per_frame} pixels of every frame")
        grown = Forest(
            **merged, roots=np.asarray(roots, dtype=np.int32), class_names=tuple(class_names),
            camera=intr.as_dict(), background_m=cfg.background_m,
        )  # fmt: skip
        shards, _ = _limited(trainset, max_frames)
        gen = torch.Generator().manual_seed(cfg.seed * 1009 + 7)
        weights = class_weights(np.asarray(counts), cfg)
        leaf_counts = leaf_class_counts(
            grown, shards, weights, cfg.refit_pixels_per_frame, gen, device, log
        )
        refit = refit_leaves(grown, leaf_counts, cfg.refit_prior)
        merged["leaf_dist"] = refit.leaf_dist
        refit_stats = {"leaf_refit": refit.stats["leaf_refit"]}
        t_refit = time.perf_counter() - t1
    stats = {
        "frames": frames,
        "content_hash": trainset.manifest.get("content_hash"),
        "feature_seconds": round(t_features, 2),
        "refit_seconds": round(t_refit, 2),
        "total_seconds": round(time.perf_counter() - t0, 2),
        "cpu_seconds": round(time.process_time() - cpu0, 2),
        "device": str(device),
        "threads": cfg.threads,
        "trees": tree_stats,
        **refit_stats,
    }
    return Forest(
        **merged,
        roots=np.asarray(roots, dtype=np.int32),
        class_names=tuple(class_names),
        camera=intr.as_dict(),
        background_m=cfg.background_m,
        config=config_to_dict(cfg),
        stats=stats,
    )
