"""Growing one tree breadth-first, a whole level at a time, on pre-binned features.

Input: ``bins`` (N, P) uint8, the quantile bin of each of the tree's P pool features for each
of its N training pixels, and the pixels' class labels. The rows are kept physically grouped by
node (re-ordered once per level), so that every read below is a contiguous slice. Every level:

1. a random cyclic window of ``candidates`` pool features is drawn for the level (the pool is
   random, so a window is a random subset; contiguous columns make the reads cheap);
2. for the splittable nodes, a histogram of class counts per (node, candidate, bin) is
   accumulated with ``index_add_`` over all (pixel, candidate) pairs, in cache-sized chunks of
   pixels and in node ranges bounded by ``histogram_budget`` entries;
3. cumulative sums over the bins give the left/right class counts of every threshold; the
   Shannon information gain of every (node, candidate, threshold) follows in closed form and the
   best one per node is kept;
4. pixels are routed to the children with one gather; pixels that reach a leaf are dropped and
   the rest regrouped by child with a stable sort.

The histogram's class axis holds only as many classes as the most mixed node of the level has
(classes are renumbered per node; exact). When a level has many nodes for its pixels (deep
levels), adjacent bins are merged (bin codes shifted right) so that the histogram work stays
proportional to the pixel work: a threshold is then every 2nd, 4th, ... quantile edge. There is
no Python loop over pixels, candidates or nodes; loops run over levels and memory-sized chunks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import torch

__all__ = ["GrowParams", "GrownTree", "grow_tree", "best_splits"]

_PIXEL_CHUNK_ELEMENTS = 1 << 19  # (pixels x candidates) per histogram update: fits in L2


@dataclass
class GrowParams:
    """Stopping rules and search sizes of :func:`grow_tree`."""

    max_depth: int
    min_samples: int
    min_gain: float
    candidates: int
    histogram_budget: int = 1 << 24
    bin_work_ratio: float = 1.0  # histogram entries allowed per (pixel x candidate) pair


@dataclass
class GrownTree:
    """One tree in breadth-first order (node 0 = root; children of a node are adjacent).

    Attributes:
        feature: (n,) int64 pool index of the split feature, -1 at leaves.
        bin_threshold: (n,) int64 go right iff the pixel's bin > this, -1 at leaves.
        left, right: (n,) int64 child indices, -1 at leaves.
        counts: (n, C) float32 class counts of the training pixels that reached each node.
        depth: (n,) int64 node depth.
    """

    feature: torch.Tensor
    bin_threshold: torch.Tensor
    left: torch.Tensor
    right: torch.Tensor
    counts: torch.Tensor
    depth: torch.Tensor
    stats: dict = field(default_factory=dict)


def _xlogx(x: torch.Tensor) -> torch.Tensor:
    return torch.special.xlogy(x, x)


def _gather_window(bins: torch.Tensor, rows: torch.Tensor, start: int, count: int) -> torch.Tensor:
    """(n, count) uint8: rows ``rows`` of the pool columns ``start, start + 1, ...`` (cyclic)."""
    k1 = min(count, bins.shape[1] - start)
    first = bins[:, start : start + k1].index_select(0, rows)
    if k1 == count:
        return first
    return torch.cat([first, bins[:, : count - k1].index_select(0, rows)], dim=1)


def best_splits(
    window: torch.Tensor,
    node: torch.Tensor,
    labels: torch.Tensor,
    num_nodes: int,
    num_classes: int,
    num_bins: int,
    shift: int,
    min_samples: int,
    histogram_budget: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Best (candidate, threshold) of every node by Shannon information gain.

    Args:
        window: (n, K) uint8 bins of the pixels for the K candidate features, rows grouped
            by node.
        node: (n,) int64 node of each pixel in [0, num_nodes), ascending.
        labels: (n,) int64 class of each pixel in [0, num_classes).
        shift: merge 2**shift adjacent bins (coarse bin = bin >> shift).
    Returns:
        candidate (M,) int64 in [0, K), coarse threshold bin (M,) int64 (go right iff the
        coarse bin > it), gain (M,) float32 in nats (-inf where no threshold leaves
        ``min_samples`` pixels on both sides).
    """
    k, c = window.shape[1], num_classes
    nb = ((num_bins - 1) >> shift) + 1
    device = window.device
    per_node = k * nb * c
    nodes_per_chunk = max(1, histogram_budget // per_node)
    counts = torch.bincount(node, minlength=num_nodes)
    ends = torch.cumsum(counts, 0).tolist()
    cand = torch.empty(num_nodes, dtype=torch.int64, device=device)
    thr = torch.empty(num_nodes, dtype=torch.int64, device=device)
    gain = torch.empty(num_nodes, dtype=torch.float32, device=device)
    k_off = (torch.arange(k, device=device, dtype=torch.int32) * (nb * c)).view(1, k)
    rows_per_step = max(1, _PIXEL_CHUNK_ELEMENTS // k)
    for n0 in range(0, num_nodes, nodes_per_chunk):  # node ranges: bounded histogram memory
        n1 = min(num_nodes, n0 + nodes_per_chunk)
        s0 = ends[n0 - 1] if n0 else 0
        s1 = ends[n1 - 1]
        hist = torch.zeros((n1 - n0) * per_node, dtype=torch.int32, device=device)
        base = ((node[s0:s1] - n0) * per_node + labels[s0:s1]).to(torch.int32)
        buf = torch.empty(min(rows_per_step, s1 - s0), k, dtype=torch.int32, device=device)
        ones = torch.ones(1, dtype=torch.int32, device=device).expand(buf.numel())
        for r0 in range(s0, s1, rows_per_step):  # cache-sized pixel chunks
            r1 = min(s1, r0 + rows_per_step)
            idx = buf[: r1 - r0]
            idx.copy_(window[r0:r1])
            if shift:
                idx.bitwise_right_shift_(shift)
            idx.mul_(c).add_(base[r0 - s0 : r1 - s0].view(-1, 1)).add_(k_off)
            hist.index_add_(0, idx.view(-1), ones[: idx.numel()])
        hist = hist.view(n1 - n0, k, nb, c).to(torch.float32)
        total = hist[:, 0].sum(1)  # (m, C) class counts of each node
        n = total.sum(1)
        left = hist.cumsum_(2)[:, :, :-1]  # (m, K, nb - 1, C): pixels with bin <= threshold
        right = total.view(-1, 1, 1, c) - left
        n_left = left.sum(-1)
        n_right = n.view(-1, 1, 1) - n_left
        score = _xlogx(left).sum(-1).add_(_xlogx(right).sum(-1))
        score = _xlogx(n_left).add_(_xlogx(n_right)).sub_(score)  # n_L H(L) + n_R H(R)
        ok = (n_left >= min_samples) & (n_right >= min_samples)
        score = score.masked_fill_(~ok, torch.inf).view(n1 - n0, -1)
        best, arg = score.min(1)
        parent = _xlogx(n) - _xlogx(total).sum(1)
        cand[n0:n1] = arg // (nb - 1)
        thr[n0:n1] = arg % (nb - 1)
        gain[n0:n1] = torch.where(torch.isfinite(best), (parent - best) / n, -torch.inf)
    return cand, thr, gain


def _splittable(totals: torch.Tensor, depth: int, params: GrowParams) -> torch.Tensor:
    n = totals.sum(1)
    ok = (n >= 2 * params.min_samples) & ((totals > 0).sum(1) > 1)
    return ok & (depth < params.max_depth)


def grow_tree(
    bins: torch.Tensor,
    labels: torch.Tensor,
    num_classes: int,
    num_bins: int,
    params: GrowParams,
    generator: torch.Generator,
    log=None,
) -> GrownTree:
    """Grow one tree; see the module docstring.

    Args:
        bins: (N, P) uint8 bin codes in [0, num_bins) of P pool features for N pixels. Not
            modified.
        labels: (N,) int64 class of each pixel in [0, num_classes).
        generator: CPU torch generator (candidate windows).
        log: optional callable taking a progress string per level.
    """
    device = bins.device
    p = bins.shape[1]
    c = num_classes
    k = min(params.candidates, p)
    labels = labels.to(device=device, dtype=torch.int64)
    node = torch.zeros(labels.shape[0], dtype=torch.int64, device=device)
    totals = torch.bincount(labels, minlength=c).view(1, c)
    splittable = _splittable(totals, 0, params)
    cls = labels
    sample = torch.arange(labels.shape[0], device=device)  # rows of ``bins``, grouped by node
    if not bool(splittable.all()):
        sample, cls, node = sample[:0], cls[:0], node[:0]
    next_id = 1
    out: dict[str, list[torch.Tensor]] = {
        name: [] for name in ("feature", "bin_threshold", "left", "right", "counts", "depth")
    }
    levels = []
    for depth in range(params.max_depth + 1):
        t0 = time.perf_counter()
        m = totals.shape[0]
        if m == 0:
            break
        feature = torch.full((m,), -1, dtype=torch.int64, device=device)
        bthr = torch.full((m,), -1, dtype=torch.int64, device=device)
        split_idx = torch.nonzero(splittable).view(-1)
        ms, ns, shift, width = split_idx.numel(), node.numel(), 0, 0
        if ms:
            # Renumber classes per node (present classes first): exact, narrower histograms.
            present = totals[split_idx] > 0
            width = int(present.sum(1).max())
            local = torch.cumsum(present, 1) - 1
            cls_local = local[node, cls]
            nb = num_bins
            while nb > 4 and ms * nb * width > params.bin_work_ratio * ns:
                shift += 1
                nb = ((num_bins - 1) >> shift) + 1
            start = int(torch.randint(p, (1,), generator=generator))
            window = _gather_window(bins, sample, start, k)
            best_c, best_t, gain = best_splits(
                window, node, cls_local, ms, width, num_bins, shift,
                params.min_samples, params.histogram_budget,
            )  # fmt: skip
            good = gain > params.min_gain
            feature[split_idx[good]] = (best_c[good] + start) % p
            bthr[split_idx[good]] = ((best_t[good] + 1) << shift) - 1  # fine bin of the edge
        is_split = feature >= 0
        rank = torch.cumsum(is_split, 0) - 1
        num_split = int(is_split.sum())
        left = torch.where(is_split, next_id + 2 * rank, -1)
        out["feature"].append(feature)
        out["bin_threshold"].append(bthr)
        out["left"].append(left)
        out["right"].append(torch.where(is_split, left + 1, -1))
        out["counts"].append(totals.to(torch.float32))
        out["depth"].append(torch.full((m,), depth, dtype=torch.int64, device=device))
        next_id += 2 * num_split
        # Route the pixels of split nodes; keep those whose child may split again.
        level_node = split_idx[node] if ms else node
        f_s = feature[level_node]
        moving = f_s >= 0
        rows = torch.nonzero(moving).view(-1)
        level_node = level_node[rows]
        go_right = bins.view(-1)[sample[rows] * p + f_s[rows]].to(torch.int64) > bthr[level_node]
        child = 2 * rank[level_node] + go_right
        child_cls = cls[rows]
        totals = torch.bincount(child * c + child_cls, minlength=2 * num_split * c)
        totals = totals.view(2 * num_split, c)
        splittable = _splittable(totals, depth + 1, params)
        stay = splittable[child]
        child, order = torch.sort(child[stay], stable=True)
        rows = rows[stay][order]
        sample, cls = sample[rows], child_cls[stay][order]
        node = (torch.cumsum(splittable, 0) - 1)[child]
        levels.append(
            {
                "depth": depth,
                "nodes": m,
                "split": num_split,
                "pixels": ns,
                "classes": width,
                "bin_shift": shift,
                "seconds": round(time.perf_counter() - t0, 3),
            }
        )
        if log is not None:
            log(
                f"  depth {depth:2d}: {m:6d} nodes, {num_split:6d} split, {ns:8d} px, "
                f"{width:2d} classes, bins/{1 << shift}, {levels[-1]['seconds']:.2f} s"
            )
    cat = {name: torch.cat(v) for name, v in out.items()}
    stats = {
        "nodes": int(cat["left"].numel()),
        "leaves": int((cat["left"] < 0).sum()),
        "depth": int(cat["depth"].max()),
        "levels": levels,
    }
    return GrownTree(**cat, stats=stats)
