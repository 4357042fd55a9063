"""Person segmentation from a raw depth frame (issue 4 item 3): real sensor frames come without
a clean person mask, so the runtime makes one before tracking.

Steps (all batched over (B, H, W) images; device and dtype follow the input):

1. Depth gate: keep finite readings within ``[min_depth_m, max_depth_m]`` (the Kinect v1 is
   usable at about 0.8-4 m, DESIGN.md).
2. Floor removal: RANSAC plane fit on points of the lower image part. Hypotheses whose normal
   is more than ``floor_max_tilt_deg`` away from the camera's up direction (-y) are refused,
   so the torso or a wall never counts as floor, and so are planes with more than a few
   points below them (nothing stands under a floor; a plane slicing through a body has half
   of it below). The winner is refined by least squares on its inliers, and every point less
   than ``floor_band_m`` above it (or below it) is removed. A plane with too little support,
   or whose inliers do not recede in depth as a floor does, is ignored (no floor in view).
3. Depth-discontinuity cut: a pixel with a 4-neighbour nearer by more than
   ``edge_jump_m + edge_jump_per_m2 * z^2`` (the Kinect error grows as z^2) is cut, which
   separates the person from the wall behind while the nearer silhouette stays whole.
4. Connected components (OpenCV, 4-connectivity, all images of the batch in one call, stacked
   with a blank row between them). Components of implausible size for a person (metric width,
   height, depth extent) or too small a metric area are dropped; the largest remaining one by
   metric area (sum of z^2 / (fx fy)) is the person. A component seen partly behind a large
   nearer one (the wall or a second person behind the subject) is background and never
   chosen. Small components just in front of the person (hands, foreshortened forearms)
   join it, and cut pixels that touch the person at a smooth depth step (self-occlusion
   edges inside the body) are added back.

An image with no plausible component gives an empty mask: the caller reports the frame as lost.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from shared.camera import Intrinsics, depth_to_points
from shared.config import field_doc

__all__ = ["SegmentationConfig", "segment_person", "fit_floor_plane", "depth_valid_mask"]


@dataclass
class SegmentationConfig:
    """How :func:`segment_person` finds the person in a depth frame."""

    min_depth_m: float = field_doc(0.4, help="nearest depth kept, metres")
    max_depth_m: float = field_doc(4.5, help="farthest depth kept, metres")
    remove_floor: bool = field_doc(True, help="fit and remove the floor plane")
    floor_region: float = field_doc(
        0.5, help="lower fraction of the image rows searched for floor points"
    )
    floor_band_m: float = field_doc(
        0.05, help="points less than this above the floor plane are floor, metres"
    )
    floor_max_tilt_deg: float = field_doc(
        45.0, help="largest angle between the floor normal and the camera's up axis (-y)"
    )
    floor_min_support: float = field_doc(
        0.05, help="fraction of sampled lower-image points the floor plane must explain"
    )
    floor_min_depth_span_m: float = field_doc(
        0.4,
        help="the floor's inliers must span this much depth (5-95 percentile), metres: a "
        "floor recedes from the camera, a slice through a body does not",
    )
    floor_max_below: float = field_doc(
        0.03,
        help="largest fraction of sampled points allowed below the floor plane (nothing "
        "stands under a floor; a plane slicing through the body has half of it below)",
    )
    floor_max_depth_gap_m: float = field_doc(
        0.25, help="largest gap between the depths of floor inliers (5-95 percentile), metres"
    )
    ransac_samples: int = field_doc(1024, help="points sampled per image for the floor fit")
    ransac_hypotheses: int = field_doc(96, help="plane hypotheses per image")
    edge_jump_m: float = field_doc(
        0.08, help="depth step between neighbours that separates surfaces, metres"
    )
    edge_jump_per_m2: float = field_doc(
        0.01, help="extra depth-step allowance per squared metre of depth (sensor noise ~ z^2)"
    )
    occluder_min_area_m2: float = field_doc(
        0.15,
        help="a component partly hidden behind a nearer one of at least this area is "
        "background (the wall behind the person), square metres; smaller occluders (a hand "
        "in front of the chest) do not count",
    )
    merge_radius_px: int = field_doc(
        3, help="components this close to the person (pixels) may join it (hands, forearms)"
    )
    merge_depth_margin_m: float = field_doc(
        0.1,
        help="a nearby component joins the person only if its mean depth is at most this "
        "much behind the person's: parts in front of the body join, the background never",
    )
    merge_max_area_fraction: float = field_doc(
        0.2,
        help="a joining component has at most this fraction of the person's metric area "
        "(a hand or forearm, not a second person)",
    )
    merge_max_front_m: float = field_doc(
        0.8, help="a joining component is at most this far in front of the person (arm reach)"
    )
    merge_rounds: int = field_doc(3, help="rounds of joining (hand -> forearm -> body chains)")
    min_area_m2: float = field_doc(
        0.04, help="smallest frontal area of a person, square metres (smaller: no person)"
    )
    max_width_m: float = field_doc(2.5, help="widest plausible person (x extent), metres")
    max_height_m: float = field_doc(2.6, help="tallest plausible person (y extent), metres")
    max_depth_extent_m: float = field_doc(1.5, help="deepest plausible person (z extent), metres")
    seed: int = field_doc(0, help="seed of the RANSAC sampling (results are deterministic)")


def depth_valid_mask(depth_m: torch.Tensor, cfg: SegmentationConfig) -> torch.Tensor:
    """(B, H, W) bool: finite depth inside the configured range (NaN and 0 are invalid)."""
    return torch.isfinite(depth_m) & (depth_m >= cfg.min_depth_m) & (depth_m <= cfg.max_depth_m)


def _neighbours(x: torch.Tensor, fill: float | bool) -> torch.Tensor:
    """4-neighbours of every pixel: (B, H, W) -> (B, 4, H, W) (up, down, left, right)."""
    b, h, w = x.shape
    pad = torch.full((b, h + 2, w + 2), fill, dtype=x.dtype, device=x.device)
    pad[:, 1:-1, 1:-1] = x
    return torch.stack(
        [pad[:, :-2, 1:-1], pad[:, 2:, 1:-1], pad[:, 1:-1, :-2], pad[:, 1:-1, 2:]], dim=1
    )


def _orient_up(normal: torch.Tensor) -> torch.Tensor:
    """Flip (..., 3) unit normals to point up in the camera frame (negative y)."""
    sign = torch.where(normal[..., 1:2] > 0, -1.0, 1.0).to(normal.dtype)
    return normal * sign


def _plane_fit(pts: torch.Tensor, weight: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Least-squares planes of (B, N, 3) points with (B, N) weights: up normal (B, 3), centre."""
    w = weight / weight.sum(1, keepdim=True).clamp_min(1.0)
    centre = (w[..., None] * pts).sum(1)
    diff = pts - centre[:, None]
    cov = torch.einsum("bn,bni,bnj->bij", w, diff, diff)
    cov = cov + torch.eye(3, dtype=pts.dtype, device=pts.device) * 1e-9  # nothing fitted
    return _orient_up(torch.linalg.eigh(cov)[1][..., 0]), centre


def fit_floor_plane(
    points: torch.Tensor, valid: torch.Tensor, cfg: SegmentationConfig
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """RANSAC floor plane per image, from the valid points of the lower image part.

    Args:
        points: (B, H, W, 3) camera-frame points, metres.
        valid: (B, H, W) bool, points that may be floor.
    Returns:
        normal (B, 3) unit, pointing up (-y side); centre (B, 3) a point on the plane;
        found (B,) bool, False where no plane has enough support (ignore normal/centre there).
    """
    b, h, w, _ = points.shape
    dev, dt = points.device, points.dtype
    gen = torch.Generator(device=dev).manual_seed(cfg.seed)
    rows = torch.arange(h, device=dev) >= int(round((1.0 - cfg.floor_region) * h))
    candidates = (valid & rows[None, :, None]).reshape(b, -1)
    n = min(cfg.ransac_samples, h * w)
    score = torch.rand(b, h * w, generator=gen, device=dev, dtype=dt)
    score = torch.where(candidates, score, torch.full_like(score, -1.0))
    top, idx = score.topk(n, dim=1)
    sample_ok = top >= 0  # (B, N)
    pts = points.reshape(b, -1, 3).gather(1, idx[..., None].expand(-1, -1, 3))  # (B, N, 3)

    k = cfg.ransac_hypotheses
    tri = torch.randint(0, n, (b, k, 3), generator=gen, device=dev)
    p = pts.gather(1, tri.reshape(b, -1, 1).expand(-1, -1, 3)).reshape(b, k, 3, 3)
    tri_ok = sample_ok.gather(1, tri.reshape(b, -1)).reshape(b, k, 3).all(-1)
    normal = torch.linalg.cross(p[:, :, 1] - p[:, :, 0], p[:, :, 2] - p[:, :, 0])
    length = normal.norm(dim=-1, keepdim=True)
    normal = _orient_up(normal / length.clamp_min(1e-12))
    cos_max = math.cos(math.radians(cfg.floor_max_tilt_deg))
    hyp_ok = tri_ok & (length[..., 0] > 1e-8) & (-normal[..., 1] >= cos_max)  # (B, K)
    signed = ((pts[:, None] - p[:, :, None, 0]) * normal[:, :, None]).sum(-1)  # (B, K, N)
    inliers = (signed.abs() < cfg.floor_band_m) & sample_ok[:, None]
    below = ((signed < -cfg.floor_band_m) & sample_ok[:, None]).sum(-1)
    n_ok = sample_ok.sum(1, keepdim=True).clamp_min(1)
    hyp_ok = hyp_ok & (below <= cfg.floor_max_below * n_ok)
    count = torch.where(hyp_ok, inliers.sum(-1), torch.zeros_like(hyp_ok, dtype=torch.long))
    best = count.argmax(1)  # (B,)
    best_in = inliers.gather(1, best[:, None, None].expand(-1, 1, n))[:, 0].to(dt)  # (B, N)

    # Least-squares refinement: the plane through the inliers' centroid, normal along the
    # smallest principal axis; a second pass with half the band drops what merely touches the
    # floor (feet, the bottom of a wall).
    refined, centre = _plane_fit(pts, best_in)
    near = ((pts - centre[:, None]) * refined[:, None]).sum(-1).abs() < 0.5 * cfg.floor_band_m
    refined, centre = _plane_fit(pts, best_in * near.to(dt))
    support = best_in.sum(1) / sample_ok.sum(1).clamp_min(1)
    z_in = torch.where(best_in > 0, pts[..., 2], torch.full_like(pts[..., 2], math.inf)).sort(1)[0]
    n_in = best_in.sum(1).long()
    i05 = (0.05 * n_in).long().clamp(0, n - 1)
    i95 = ((0.95 * n_in).long() - 1).clamp(0, n - 1)
    span = z_in.gather(1, i95[:, None])[:, 0] - z_in.gather(1, i05[:, None])[:, 0]
    span = torch.where(n_in > 0, span, torch.zeros_like(span))
    # A floor recedes continuously; inliers in separate depth clusters (a hand in front of
    # the belly) are not one.
    step = z_in[:, 1:] - z_in[:, :-1]
    k = torch.arange(n - 1, device=dev)
    inside = (k[None] >= i05[:, None]) & (k[None] < i95[:, None])
    gap = torch.where(inside, step, torch.zeros_like(step)).amax(1)
    found = (
        (span >= cfg.floor_min_depth_span_m)
        & (gap <= cfg.floor_max_depth_gap_m)
        & (sample_ok.sum(1) >= 50)
        & (support >= cfg.floor_min_support)
        & (-refined[:, 1] >= cos_max)
        & hyp_ok.gather(1, best[:, None])[:, 0]
    )
    return refined, centre, found


def _components(keep: torch.Tensor) -> tuple[torch.Tensor, int]:
    """4-connected components of (B, H, W) bool masks in one OpenCV call.

    Returns (B, H, W) int64 labels (0 = not kept), unique across the batch, and their count
    (labels run from 1 to count - 1).
    """
    import cv2

    b, h, w = keep.shape
    stacked = np.zeros((b, h + 1, w), dtype=np.uint8)  # a blank row keeps images apart
    stacked[:, :h] = keep.detach().cpu().numpy()
    count, labels = cv2.connectedComponents(stacked.reshape(b * (h + 1), w), connectivity=4)
    labels = torch.from_numpy(labels.reshape(b, h + 1, w)[:, :h].astype(np.int64))
    return labels.to(keep.device), int(count)


def _occluded_by_large(
    labels: torch.Tensor,
    z: torch.Tensor,
    cut: torch.Tensor,
    jump: torch.Tensor,
    comp_area: torch.Tensor,
    min_area: float,
) -> torch.Tensor:
    """(count,) bool: components seen behind a nearer component of at least ``min_area``.

    Every cut pixel sits on the far side of a depth step: its similar-depth neighbours name
    the hidden component, its much nearer neighbours the occluder.
    """
    lab_nb = _neighbours(labels, 0)  # (B, 4, H, W)
    z_nb = _neighbours(z, 0.0)
    nearer = (z[:, None] - z_nb > jump[:, None]) & (lab_nb > 0)
    similar = ((z[:, None] - z_nb).abs() <= jump[:, None]) & (lab_nb > 0)
    hidden = torch.where(similar, lab_nb, torch.zeros_like(lab_nb)).amax(1)
    # A step inside one component (chin over neck) is self-occlusion, not background.
    other = nearer & (lab_nb != hidden[:, None])
    occluder_area = torch.where(other, comp_area[lab_nb], torch.zeros_like(z_nb)).amax(1)
    pick = cut & (hidden > 0)
    worst = torch.zeros_like(comp_area).scatter_reduce(
        0, hidden[pick], occluder_area[pick], "amax", include_self=True
    )
    return worst >= min_area


def _join_nearby_parts(
    mask: torch.Tensor,
    labels: torch.Tensor,
    z: torch.Tensor,
    pixel_area: torch.Tensor,
    comp_area: torch.Tensor,
    image_of: torch.Tensor,
    cfg: SegmentationConfig,
) -> torch.Tensor:
    """Grow (B, H, W) person masks by the components that touch them and lie in front.

    Limbs pointing at the camera are foreshortened, so their depth changes faster between
    pixels than the cut threshold and hands come out as separate components. They are never
    behind the body, while the background always is: join components within
    ``merge_radius_px`` whose mean depth is at most ``merge_depth_margin_m`` behind the
    person's, at most ``merge_max_front_m`` in front of it (arm reach), and small
    (``merge_max_area_fraction`` of the person: a hand, not a second person).
    """
    count = comp_area.shape[0]
    flat = labels.reshape(-1)
    zeros = torch.zeros(count, dtype=z.dtype, device=z.device)
    n_pix = zeros.index_add(0, flat, torch.ones_like(z).reshape(-1))
    comp_depth = zeros.index_add(0, flat, z.reshape(-1)) / n_pix.clamp_min(1)
    r = cfg.merge_radius_px
    for _ in range(cfg.merge_rounds if r > 0 else 0):
        m = mask.to(z.dtype)
        person_depth = (m * z).sum((1, 2)) / m.sum((1, 2)).clamp_min(1)  # (B,)
        person_area = (m * pixel_area).sum((1, 2))  # (B,)
        # Separable square dilation (two 1-D max pools cost far less than one 2-D window).
        near = torch.nn.functional.max_pool2d(m[:, None], (1, 2 * r + 1), 1, (0, r))
        near = torch.nn.functional.max_pool2d(near, (2 * r + 1, 1), 1, (r, 0))[:, 0] > 0
        touching = torch.zeros(count, dtype=torch.bool, device=z.device)
        touching[flat[(near & ~mask).reshape(-1)]] = True
        join = (
            touching
            & (comp_depth <= person_depth[image_of] + cfg.merge_depth_margin_m)
            & (comp_depth >= person_depth[image_of] - cfg.merge_max_front_m)
            & (comp_area <= cfg.merge_max_area_fraction * person_area[image_of])
        )
        join[0] = False
        grown = mask | join[labels]
        if torch.equal(grown, mask):
            break
        mask = grown
    return mask


def segment_person(
    depth_m: torch.Tensor, intr: Intrinsics, cfg: SegmentationConfig | None = None
) -> torch.Tensor:
    """Mask of the person in depth frames (module docstring).

    Args:
        depth_m: (H, W) or (B, H, W) metric depth; 0 or NaN where there is no reading.
        intr: intrinsics of the H x W images.
        cfg: settings (defaults when None).
    Returns:
        bool mask of the same shape as ``depth_m``; all False where no person is found.
    """
    cfg = cfg or SegmentationConfig()
    single = depth_m.ndim == 2
    depth = depth_m[None] if single else depth_m
    if depth.ndim != 3 or depth.shape[-2:] != (intr.height, intr.width):
        raise ValueError(
            f"depth must be (H, W) or (B, H, W) with H x W = {intr.height}x{intr.width}, "
            f"got {tuple(depth_m.shape)}"
        )
    if not depth.is_floating_point():
        depth = depth.to(torch.get_default_dtype())
    valid = depth_valid_mask(depth, cfg)
    z = torch.where(valid, depth, torch.zeros_like(depth))
    points = depth_to_points(z, intr)  # (B, H, W, 3)

    if cfg.remove_floor:
        normal, centre, found = fit_floor_plane(points, valid, cfg)
        height = ((points - centre[:, None, None]) * normal[:, None, None]).sum(-1)
        valid = valid & ~(found[:, None, None] & (height < cfg.floor_band_m))

    # Cut the far side of depth discontinuities (and where a neighbour is unusable the pixel
    # stays: silhouettes against "no reading" are not cuts).
    z_nb = _neighbours(torch.where(valid, z, torch.full_like(z, math.inf)), math.inf)
    jump = cfg.edge_jump_m + cfg.edge_jump_per_m2 * z * z
    cut = ((z[:, None] - z_nb) > jump[:, None]).any(1) & valid
    labels, count = _components(valid & ~cut)

    # Per-component metric statistics; label 0 (background) is never chosen.
    flat = labels.reshape(-1)
    pixel_area = z * z / (intr.fx * intr.fy)  # metric area each pixel sees, facing the camera
    comp_area = torch.zeros(count, dtype=z.dtype, device=z.device).index_add_(
        0, flat, pixel_area.reshape(-1)
    )
    pts = points.reshape(-1, 3)
    big = torch.full((count, 3), math.inf, dtype=z.dtype, device=z.device)
    lo = big.scatter_reduce(0, flat[:, None].expand(-1, 3), pts, "amin", include_self=True)
    hi = (-big).scatter_reduce(0, flat[:, None].expand(-1, 3), pts, "amax", include_self=True)
    extent = hi - lo
    image_of = torch.zeros(count, dtype=torch.long, device=z.device).scatter_reduce(
        0,
        flat,
        torch.arange(depth.shape[0], device=z.device).repeat_interleave(z[0].numel()),
        "amax",
        include_self=False,
    )
    behind = _occluded_by_large(labels, z, cut, jump, comp_area, cfg.occluder_min_area_m2)
    plausible = (
        ~behind
        & (comp_area >= cfg.min_area_m2)
        & (extent[:, 0] <= cfg.max_width_m)
        & (extent[:, 1] <= cfg.max_height_m)
        & (extent[:, 2] <= cfg.max_depth_extent_m)
    )
    plausible[0] = False
    score = torch.where(plausible, comp_area, torch.full_like(comp_area, -1.0))
    per_image = torch.where(
        image_of[None] == torch.arange(depth.shape[0], device=z.device)[:, None],
        score[None],
        torch.full_like(score[None], -1.0),
    )  # (B, count)
    best_score, best = per_image.max(1)
    mask = (labels == best[:, None, None]) & (best_score > 0)[:, None, None]
    mask = _join_nearby_parts(mask, labels, z, pixel_area, comp_area, image_of, cfg)

    # Add back cut pixels that join the person at a smooth step (self-occlusion inside it).
    mask_nb = _neighbours(mask, False)
    zm_nb = _neighbours(torch.where(mask, z, torch.full_like(z, math.inf)), math.inf)
    smooth = (mask_nb & ((z[:, None] - zm_nb).abs() <= jump[:, None])).any(1)
    mask = mask | (cut & smooth)
    return mask[0] if single else mask
