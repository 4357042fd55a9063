"""Extra depth term (Wei eq. 5, 10, 17): 3D closest points for the pixels the depth term skips.

The four correspondence types of Wei figure 4(c):

1. rendered pixel in B1 (over observed background): push its surface point towards the
   closest observed point;
2. observed pixel in B3 (missed by the rendering): pull the closest rendered point to it;
3. B2 pixel rendered in front of the observation: as type 1;
4. B2 pixel rendered behind the observation: as type 2.

So correspondences are searched in both directions (rendered -> observed for types 1, 3,
observed -> rendered for 2, 4). A candidate whose depth differs from the query's by more than
``extra_gate_m`` (15 cm; Wei: 8) is not eligible, i.e. each query takes its closest point
among the eligible ones, and matches farther than ``EXTRA_MAX_DISTANCE_M`` in 3D are dropped.
The residual is the 3D offset, one row per camera axis, all on the model point's Jacobian.
Offsets on the torso, neck, head and clavicles are weighed with ``SIGMA_EXTRA_TORSO_M``
(4 cm) instead of ``cfg.sigma_extra_m`` (5 mm): there they mostly measure how far the capsule
torso's shape is from the person's, not a pose error, and at full weight they twisted the
chest against the pelvis in near-profile views.

Pixels within ``EXTRA_MARGIN_PX`` of the other silhouette (B1, B3) or of G (B2) are skipped:
there the region is a one-pixel quantization band of an edge, and its closest-point offsets
(a whole pixel for any sub-pixel misalignment) made Gauss-Newton chatter and drift by several
millimetres on exact data; edges that far off are aligned by the depth and silhouette terms.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from depthmocap.runtime.raycast import BodyRender
from depthmocap.shared import skeleton as sk
from depthmocap.shared.compiled import compiled_float32, compiled_module

from .config import TrackerConfig
from .gauss_newton import Rows
from .observation import Observation
from .regions import Regions, batch_slots, rendered_points, sample_pixels

__all__ = [
    "MAX_EXTRA_POINTS",
    "MAX_CANDIDATES",
    "EXTRA_MARGIN_PX",
    "EXTRA_MAX_DISTANCE_M",
    "SIGMA_EXTRA_TORSO_M",
    "ObservedCandidates",
    "observed_candidates",
    "closest_points",
    "closest_points_torch",
    "extra_rows",
]

# At most this many query pixels per iteration, half for each direction (a strided subsample),
# for speed: every query is compared with every candidate. Each kept pixel is weighed for the
# ones it stands for, so the cap does not shift the balance between the terms.
MAX_EXTRA_POINTS = 400
# Closest-point candidates per side (observed points, rendered points) at most, for the same
# reason; the tracker draws the observed ones once per frame with this cap too.
MAX_CANDIDATES = 1500
# B1 / B3 pixels within this many working pixels of the other silhouette, and B2 pixels this
# close to G, get no correspondence: there the offset is a pixel-quantization artefact of an
# edge that would demand a whole-pixel move for any sub-pixel misalignment (Gauss-Newton
# chattered and drifted by millimetres on exact data); the depth and silhouette terms align
# the last pixel. 0: no margin.
EXTRA_MARGIN_PX = 1
# Correspondences farther apart than this in 3D are dropped (m): a closest point that far off
# is rather another part of the body than the same surface displaced, and its pull would drag
# the model across the gap.
EXTRA_MAX_DISTANCE_M = 0.3
# Noise scale of correspondences on the torso, neck, head and clavicles (m; the limbs keep
# cfg.sigma_extra_m, theirs carry the large corrections). The capsule torso matches a real
# one's shape only roughly (an anny body's silhouette is covered to 0.75-0.8): at full weight,
# closest points on the unmatched chest and back turned the chest against the pelvis in
# near-profile views, the lower back's twist to its 50 degree limit and the far shoulder
# 25-35 cm off (docs/experiments.md).
SIGMA_EXTRA_TORSO_M = 0.04


@dataclass
class ObservedCandidates:
    """Observed points that rendered queries may match (fixed for the frame).

    Attributes:
        batch: (M,) int64; points: (M, 3) camera frame.
    """

    batch: torch.Tensor
    points: torch.Tensor


def observed_candidates(obs: Observation, max_count: int) -> ObservedCandidates:
    """A strided subsample of the observed foreground points with depth, ordered by pose and
    then by height: the compiled closest-point search then need not sort them at every
    iteration (:mod:`runtime.tracker.closest_kernel`)."""
    idx, _, _ = sample_pixels(obs.valid, max_count)
    b, v, u = idx.unbind(1)
    points = obs.points[b, v, u]
    if points.shape[0]:
        y = points[:, 1].double()
        order = torch.argsort(b.double() * (y.max() - y.min() + 1.0) + y)
        b, points = b[order], points[order]
    return ObservedCandidates(b, points)


def _closest_kernel():
    """:mod:`runtime.tracker.closest_kernel` (numba's compiled search), or None without numba."""
    return compiled_module("depthmocap.runtime.tracker.closest_kernel")


def closest_points(
    query: torch.Tensor,
    query_batch: torch.Tensor,
    cand: torch.Tensor,
    cand_batch: torch.Tensor,
    depth_gate: float,
    max_distance: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Index of each query's closest candidate of the same pose within the depth gate.

    On the CPU with numba, a compiled loop (:mod:`runtime.tracker.closest_kernel`);
    otherwise :func:`closest_points_torch`. Queries and candidates are compared within their
    pose only.

    Args:
        query: (N, 3); cand: (M, 3); *_batch: pose index of each.
    Returns:
        index (N,) into cand, and found (N,) bool (eligible match within max_distance);
        the index is meaningful only where found.
    """
    kernel = _closest_kernel() if query.device.type == "cpu" else None
    if kernel is not None and query.shape[0] and cand.shape[0]:
        return kernel.closest_points_cpu(
            query, query_batch, cand, cand_batch, depth_gate, max_distance
        )
    return closest_points_torch(query, query_batch, cand, cand_batch, depth_gate, max_distance)


def closest_points_torch(
    query: torch.Tensor,
    query_batch: torch.Tensor,
    cand: torch.Tensor,
    cand_batch: torch.Tensor,
    depth_gate: float,
    max_distance: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`closest_points` with torch on any device: queries and candidates are grouped by
    pose (:func:`~runtime.tracker.regions.batch_slots`), so B poses cost B times one pose's
    (n, m) distance table, not a (B n, B m) one."""
    n = query.shape[0]
    index = torch.zeros(n, dtype=torch.long, device=query.device)
    found = torch.zeros(n, dtype=torch.bool, device=query.device)
    if cand.shape[0] == 0 or n == 0:
        return index, found
    B = int(torch.maximum(query_batch.max(), cand_batch.max())) + 1
    c_real = None
    if B == 1:  # one pose: no grouping to do
        q, c = query[None], cand[None]
    else:
        q_slot, q_real = batch_slots(query_batch, B)  # (B, K), (B, K)
        c_slot, c_real = batch_slots(cand_batch, B)  # (B, L), (B, L)
        q, c = query[q_slot], cand[c_slot]  # (B, K, 3), (B, L, 3)
    norms = (q * q).sum(-1)[:, :, None] + (c * c).sum(-1)[:, None, :]
    d2 = torch.baddbmm(norms, q, c.transpose(1, 2), alpha=-2.0)  # (B, K, L)
    # Padding candidates get an infinite depth, so the depth gate drops them too.
    cz = c[..., 2] if c_real is None else c[..., 2].masked_fill(~c_real, float("inf"))
    far = (q[:, :, 2, None] - cz[:, None, :]).abs_() > depth_gate
    best, local = d2.masked_fill_(far, float("inf")).min(2)  # (B, K)
    if B == 1:
        return local[0], best[0] <= max_distance * max_distance
    rows = q_slot[q_real]
    index[rows] = c_slot.gather(1, local)[q_real]
    found[rows] = (best <= max_distance * max_distance)[q_real]
    return index, found


def _dilate(mask: torch.Tensor, radius: int) -> torch.Tensor:
    """(B, H, W) bool dilated by a (2 radius + 1)^2 square (separable OR of shifted copies)."""
    out = mask
    for dim in (1, 2):
        grown = out.clone()
        n = out.shape[dim]
        for s in range(1, radius + 1):
            if s >= n:
                break
            grown.narrow(dim, s, n - s).logical_or_(out.narrow(dim, 0, n - s))
            grown.narrow(dim, 0, n - s).logical_or_(out.narrow(dim, s, n - s))
        out = grown
    return out


@dataclass
class ExtraResult:
    """Rows of the extra depth term plus its error statistic.

    Attributes:
        rows: the linearized rows (3 per accepted correspondence).
        error_sum: (B,) estimated sum over all query pixels of the 3D distance to the match,
            counting queries without an eligible match as ``depth_gate_m`` (metres: the
            signal's scale does not move with the correspondence gate).
        count: (B,) number of query pixels.
    """

    rows: Rows
    error_sum: torch.Tensor
    count: torch.Tensor


def extra_rows(
    render: BodyRender,
    obs: Observation,
    regions: Regions,
    observed: ObservedCandidates,
    cfg: TrackerConfig,
    batch_size: int,
) -> ExtraResult:
    """Correspondences of types 1-4 and their linearized rows."""
    # One compiled call, the same rows (float64 keeps the torch code, whose norms' fused
    # multiply-adds the compiled one cannot reproduce to the bit there).
    kernel = compiled_float32("depthmocap.runtime.tracker.extra_kernel", render.depth)
    if kernel is not None:
        points, segment, batch, offset, weight, error, count = kernel.extra_correspondences_cpu(
            render, obs, regions, observed, batch_size, EXTRA_MARGIN_PX,
            max(1, MAX_EXTRA_POINTS // 2), MAX_CANDIDATES, cfg.extra_gate_m,
            EXTRA_MAX_DISTANCE_M, cfg.depth_gate_m, SIGMA_EXTRA_TORSO_M, cfg.sigma_extra_m,
            sk.FIRST_LIMB_SEGMENT,
        )  # fmt: skip
        return ExtraResult(_rows(points, segment, batch, offset, weight), error, count)
    intr, dtype = obs.intr, render.depth.dtype
    half = max(1, MAX_EXTRA_POINTS // 2)
    error = render.depth.new_zeros(batch_size)
    count = render.depth.new_zeros(batch_size)

    # Types 1 and 3: rendered point -> closest observed point.
    m = EXTRA_MARGIN_PX
    b1, b3 = regions.b1, regions.b3
    front, behind = regions.b2_front, regions.b2_behind
    if m > 0:
        b1 = b1 & ~_dilate(obs.silhouette, m)
        b3 = b3 & ~_dilate(render.mask, m)
        near_good = _dilate(regions.good, m)
        front, behind = front & ~near_good, behind & ~near_good
    q_idx, _, q_ratio64 = sample_pixels(b1 | front, half)
    q_ratio = q_ratio64.to(dtype)
    q_pts, q_seg = rendered_points(render, q_idx, intr)
    j, found = closest_points(
        q_pts,
        q_idx[:, 0],
        observed.points,
        observed.batch,
        cfg.extra_gate_m,
        EXTRA_MAX_DISTANCE_M,
    )
    target = observed.points[j] if observed.points.shape[0] else q_pts
    off_r = torch.where(found[:, None], target - q_pts, torch.zeros_like(q_pts))
    dist_r = torch.where(found, off_r.norm(dim=-1), torch.full_like(q_pts[:, 0], cfg.depth_gate_m))
    error.index_add_(0, q_idx[:, 0], dist_r * q_ratio)
    count.index_add_(0, q_idx[:, 0], q_ratio)

    # Types 2 and 4: observed point -> closest rendered point (a model point to pull).
    o_idx, _, o_ratio64 = sample_pixels(b3 | behind, half)
    o_ratio = o_ratio64.to(dtype)
    b, v, u = o_idx.unbind(1)
    o_pts = obs.points[b, v, u]
    c_idx, _, _ = sample_pixels(render.mask, MAX_CANDIDATES)
    c_pts, c_seg = rendered_points(render, c_idx, intr)
    k, found_o = closest_points(
        o_pts, b, c_pts, c_idx[:, 0], cfg.extra_gate_m, EXTRA_MAX_DISTANCE_M
    )
    model = c_pts[k] if c_pts.shape[0] else o_pts
    model_seg = c_seg[k] if c_pts.shape[0] else torch.zeros_like(b)
    off_o = torch.where(found_o[:, None], o_pts - model, torch.zeros_like(o_pts))
    dist_o = torch.where(
        found_o, off_o.norm(dim=-1), torch.full_like(o_pts[:, 0], cfg.depth_gate_m)
    )
    error.index_add_(0, b, dist_o * o_ratio)
    count.index_add_(0, b, o_ratio)

    points = torch.cat([q_pts, model])
    segment = torch.cat([q_seg, model_seg])
    batch = torch.cat([q_idx[:, 0], b])
    offset = torch.cat([off_r, off_o])
    weight = torch.cat([found * (q_ratio64**0.5).to(dtype), found_o * (o_ratio64**0.5).to(dtype)])
    sigma = weight.new_tensor([SIGMA_EXTRA_TORSO_M, cfg.sigma_extra_m])
    weight = weight / sigma[(segment >= sk.FIRST_LIMB_SEGMENT).long()]
    return ExtraResult(_rows(points, segment, batch, offset, weight), error, count)


def _rows(points, segment, batch, offset, weight) -> Rows:
    """One row per camera axis of each correspondence."""
    n = points.shape[0]
    eye = torch.eye(3, dtype=points.dtype, device=points.device)
    return Rows(
        batch.repeat_interleave(3),
        points.repeat_interleave(3, 0),
        segment.repeat_interleave(3),
        eye.repeat(n, 1),
        offset.reshape(-1),
        weight.repeat_interleave(3),
    )
