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

from shared.camera import Intrinsics
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
    ransac_score_samples: int = field_doc(
        256, help="sampled points each hypothesis is scored on (the winner is refined on all)"
    )
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


def _valid_np(depth: np.ndarray, cfg: SegmentationConfig) -> np.ndarray:
    """Numpy twin of :func:`depth_valid_mask` (comparisons with NaN are False)."""
    return (depth >= cfg.min_depth_m) & (depth <= cfg.max_depth_m)


def _orient_up(normal: np.ndarray) -> np.ndarray:
    """Flip (..., 3) normals to point up in the camera frame (negative y)."""
    return normal * np.where(normal[..., 1:2] > 0, -1.0, 1.0)


def _plane_fit(pts: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares planes of (B, N, 3) points with (B, N) weights: up normal (B, 3), centre."""
    w = weight / np.maximum(weight.sum(1, keepdims=True), 1.0)
    centre = (w[..., None] * pts).sum(1)
    diff = pts - centre[:, None]
    cov = np.einsum("bn,bni,bnj->bij", w, diff, diff) + np.eye(3) * 1e-9  # nothing fitted
    return _orient_up(np.linalg.eigh(cov)[1][..., 0]), centre


def _sample_floor_pixels(
    valid: np.ndarray, cfg: SegmentationConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniform draws (with replacement) among the valid pixels of the lower image part.

    One cumulative count over the whole batch turns uniform ranks into pixel indices, so no
    image is visited in Python; every image uses the same uniform numbers, so an image gives
    the same sample alone or in a batch.

    Args:
        valid: (B, H, W) bool.
    Returns:
        rows (B, N), cols (B, N) int pixel coordinates and count (B,) of candidate pixels
        (rows/cols are meaningless where count is 0).
    """
    b, h, w = valid.shape
    r0 = min(int(round((1.0 - cfg.floor_region) * h)), h)
    region = valid[:, r0:].reshape(b, -1)
    size = region.shape[1]
    count = region.sum(1)
    cum = np.cumsum(region.reshape(-1), dtype=np.int64)  # (B * S,)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])  # candidates before each image
    ranks = (rng.random(cfg.ransac_samples)[None] * count[:, None]).astype(np.int64)
    flat = np.searchsorted(cum, first[:, None] + ranks + 1)  # (B, N): the rank-th candidate
    local = np.clip(flat - np.arange(b)[:, None] * size, 0, max(size - 1, 0))
    return r0 + local // w, local % w, count


def _fit_floor_np(
    pts: np.ndarray, count: np.ndarray, cfg: SegmentationConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RANSAC floor planes of (B, N, 3) sampled points drawn from ``count`` (B,) candidates.

    Returns up normal (B, 3), centre (B, 3), found (B,) bool (see :func:`fit_floor_plane`).
    """
    b, n, _ = pts.shape
    sample_ok = count >= 3
    tri = rng.integers(0, n, (cfg.ransac_hypotheses, 3))  # shared by the batch (as above)
    p = pts[:, tri]  # (B, K, 3, 3)
    normal = np.cross(p[:, :, 1] - p[:, :, 0], p[:, :, 2] - p[:, :, 0])
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    normal = _orient_up(normal / np.maximum(length, 1e-12))
    cos_max = math.cos(math.radians(cfg.floor_max_tilt_deg))
    hyp_ok = sample_ok[:, None] & (length[..., 0] > 1e-8) & (-normal[..., 1] >= cos_max)
    offset = (normal * p[:, :, 0]).sum(-1)  # (B, K)
    # Hypotheses are scored on the first points only (the sample is random already), the
    # winner's inliers are then taken among all. Single precision is plenty for centimetre
    # bands; a batched matmul treats every image alone, so an image scores the same alone or
    # in a batch.
    m = max(3, min(cfg.ransac_score_samples, n))
    signed = (
        np.matmul(normal.astype(np.float32), pts[:, :m].astype(np.float32).transpose(0, 2, 1))
        - offset.astype(np.float32)[..., None]
    )  # (B, K, M)
    below = np.count_nonzero(signed < -cfg.floor_band_m, axis=-1)
    hyp_ok &= below <= cfg.floor_max_below * m
    np.abs(signed, out=signed)
    votes = np.where(hyp_ok, np.count_nonzero(signed < cfg.floor_band_m, axis=-1), 0)
    best = votes.argmax(1)  # (B,)
    rows = np.arange(b)
    best_dist = ((pts - p[rows, best, 0][:, None]) * normal[rows, best][:, None]).sum(-1)
    best_in = (np.abs(best_dist) < cfg.floor_band_m).astype(np.float64)  # (B, N)

    # Least-squares refinement: the plane through the inliers' centroid, normal along the
    # smallest principal axis; a second pass with half the band drops what merely touches the
    # floor (feet, the bottom of a wall).
    refined, centre = _plane_fit(pts, best_in)
    near = np.abs(((pts - centre[:, None]) * refined[:, None]).sum(-1)) < 0.5 * cfg.floor_band_m
    refined, centre = _plane_fit(pts, best_in * near)
    n_in = best_in.sum(1).astype(np.int64)
    z_in = np.sort(np.where(best_in > 0, pts[..., 2], np.inf), axis=1)
    i05 = np.clip((0.05 * n_in).astype(np.int64), 0, n - 1)
    i95 = np.clip((0.95 * n_in).astype(np.int64) - 1, 0, n - 1)
    span = np.where(n_in > 0, z_in[rows, i95] - z_in[rows, i05], 0.0)
    # A floor recedes continuously; inliers in separate depth clusters (a hand in front of
    # the belly) are not one.
    k = np.arange(n - 1)
    inside = (k[None] >= i05[:, None]) & (k[None] < i95[:, None])
    with np.errstate(invalid="ignore"):  # inf - inf outside the inliers, masked below
        gap = np.where(inside, z_in[:, 1:] - z_in[:, :-1], 0.0).max(1, initial=0.0)
    found = (
        (span >= cfg.floor_min_depth_span_m)
        & (gap <= cfg.floor_max_depth_gap_m)
        & (count >= 50)
        & (n_in >= cfg.floor_min_support * n)
        & (-refined[:, 1] >= cos_max)
        & hyp_ok[rows, best]
        & (np.count_nonzero(best_dist < -cfg.floor_band_m, axis=1) <= cfg.floor_max_below * n)
    )
    return refined, centre, found


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
    rng = np.random.default_rng(cfg.seed)
    rows, cols, count = _sample_floor_pixels(valid.detach().cpu().numpy(), cfg, rng)
    pts = points.detach().cpu().double().numpy()[np.arange(points.shape[0])[:, None], rows, cols]
    normal, centre, found = _fit_floor_np(pts, count, cfg, rng)
    like = dict(dtype=points.dtype, device=points.device)
    return (
        torch.as_tensor(normal, **like),
        torch.as_tensor(centre, **like),
        torch.as_tensor(found, device=points.device),
    )


def _remove_floor(
    z: np.ndarray, valid: np.ndarray, intr: Intrinsics, cfg: SegmentationConfig
) -> np.ndarray:
    """(B, H, W) valid pixels of depth ``z`` without those within the floor band."""
    b, h, w = z.shape
    rng = np.random.default_rng(cfg.seed)
    rows, cols, count = _sample_floor_pixels(valid, cfg, rng)
    zs = z[np.arange(b)[:, None], rows, cols].astype(np.float64)
    pts = np.stack([(cols - intr.cx) / intr.fx * zs, (rows - intr.cy) / intr.fy * zs, zs], -1)
    normal, centre, found = _fit_floor_np(pts, count, cfg, rng)
    if not found.any():
        return valid
    # Height above the plane of every pixel: z * (n . ray) - n . centre, ray = (x/z, y/z, 1).
    n = normal.astype(np.float32)[:, :, None, None]
    ray_dot = (
        n[:, 0] * ((np.arange(w, dtype=np.float32) - intr.cx) / intr.fx)[None, None]
        + n[:, 1] * ((np.arange(h, dtype=np.float32) - intr.cy) / intr.fy)[None, :, None]
        + n[:, 2]
    )  # (B, H, W)
    level = (normal * centre).sum(1).astype(np.float32)[:, None, None]
    floor = (z * ray_dot - level < cfg.floor_band_m) & found[:, None, None]
    return valid & ~floor


class _Canvas:
    """The batch as one 2-D image for OpenCV: each (H, W) image sits below ``pad`` blank rows
    and between ``pad`` blank columns, so filters of radius ``pad`` and 4-neighbour look-ups
    at flat index +-1, +-width never mix images (blank = no reading)."""

    def __init__(self, b: int, h: int, w: int, pad: int):
        self.b, self.h, self.w, self.pad = b, h, w, pad
        self.shape = (pad + b * (h + pad), w + 2 * pad)

    def images(self, canvas: np.ndarray) -> np.ndarray:
        """(B, H, W) view of the images on a canvas."""
        p = self.pad
        return canvas[p:].reshape(self.b, self.h + p, -1)[:, : self.h, p : p + self.w]

    def place(self, images: np.ndarray) -> np.ndarray:
        """A blank canvas with the (B, H, W) ``images`` on it."""
        canvas = np.zeros(self.shape, dtype=images.dtype)
        self.images(canvas)[:] = images
        return canvas

    def image_of(self, labels: np.ndarray, comp_pixels: np.ndarray) -> np.ndarray:
        """(count,) batch index of each component of a label canvas (0 for label 0)."""
        if self.b == 1:
            return np.zeros(len(comp_pixels), dtype=np.intp)
        rows = np.clip((np.arange(self.shape[0]) - self.pad) // (self.h + self.pad), 0, None)
        index = np.broadcast_to(rows[:, None], self.shape).reshape(-1)
        # Every pixel of a component lies in one image: the mean index is that image's.
        total = np.bincount(labels.reshape(-1), index, minlength=len(comp_pixels))
        return np.rint(total / np.maximum(comp_pixels, 1)).astype(np.intp)


def _segment_np(depth: np.ndarray, intr: Intrinsics, cfg: SegmentationConfig) -> np.ndarray:
    """:func:`segment_person` on (B, H, W) float32 metres in numpy/OpenCV -> (B, H, W) bool."""
    import cv2

    b, h, w = depth.shape
    valid = _valid_np(depth, cfg)
    z_img = np.where(valid, depth, np.float32(0.0))
    if cfg.remove_floor:
        valid = _remove_floor(z_img, valid, intr, cfg)

    r = max(cfg.merge_radius_px, 0)
    cv = _Canvas(b, h, w, max(r, 1))
    valid = cv.place(valid)
    z = np.where(valid, cv.place(z_img), np.float32(0.0))
    zf, width = z.reshape(-1), cv.shape[1]

    # Cut the far side of depth discontinuities: a 4-neighbour nearer by more than the jump
    # (the nearest neighbour is a cross-shaped erosion; where a neighbour is unusable the pixel
    # stays: silhouettes against "no reading" are not cuts).
    z2 = z * z
    jump = cfg.edge_jump_m + cfg.edge_jump_per_m2 * z2
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    nearest = cv2.erode(np.where(valid, z, np.float32(np.inf)), cross)
    cut = (z - nearest > jump) & valid
    count, labels = cv2.connectedComponents(
        (valid & ~cut).view(np.uint8), connectivity=4, ltype=cv2.CV_32S
    )
    labels = labels.astype(np.intp)  # bincount and fancy indexing want intp
    lf = labels.reshape(-1)

    # Per-component metric statistics; label 0 (background) is never chosen.
    # Metric area each pixel sees, facing the camera: z^2 / (fx fy).
    comp_pixels = np.bincount(lf, minlength=count)
    comp_area = np.bincount(lf, z2.reshape(-1), minlength=count) / (intr.fx * intr.fy)
    comp_depth = np.bincount(lf, zf, minlength=count) / np.maximum(comp_pixels, 1)
    image_of = cv.image_of(labels, comp_pixels)
    extent_box = _boxes(z, labels, count, cv, intr)

    # Cut pixels and their 4 neighbours: what is seen behind what, and where the person's
    # own self-occlusion edges are.
    cut_px = np.flatnonzero(cut)
    nb = cut_px[:, None] + np.array([-width, width, -1, 1])  # (M, 4), never off the canvas
    lab_nb, z_nb = lf[nb], zf[nb]
    step = zf[cut_px, None] - z_nb
    jump_c = jump.reshape(-1)[cut_px, None]

    behind = _occluded_by_large(lab_nb, step, jump_c, comp_area, count, cfg.occluder_min_area_m2)
    plausible = (
        ~behind & (comp_area >= cfg.min_area_m2) & _plausible_size(_box_sizes(extent_box), cfg)
    )
    plausible[0] = False
    score = np.where(plausible, comp_area, -1.0)
    per_image = np.where(image_of[None] == np.arange(b)[:, None], score[None], -1.0)  # (B, C)
    best = per_image.argmax(1)
    in_person = np.zeros(count, dtype=bool)
    in_person[best[per_image[np.arange(b), best] > 0]] = True
    comps = _Components(labels, comp_pixels, comp_depth, comp_area, extent_box, image_of)
    in_person = _join_nearby_parts(in_person, comps, b, cfg, cv2)
    mask = in_person[labels]

    # Add back cut pixels that join the person at a smooth step (self-occlusion inside it).
    smooth = (mask.reshape(-1)[nb] & (np.abs(step) <= jump_c)).any(1)
    mask.reshape(-1)[cut_px[smooth]] = True
    return cv.images(mask)


def _boxes(
    z: np.ndarray, labels: np.ndarray, count: int, cv: _Canvas, intr: Intrinsics
) -> np.ndarray:
    """(count, 2, 3) metric bounding boxes (min, max of x, y, z) of a canvas's components;
    empty components get (inf, -inf).

    Measured on every second row and column: a pixel or two (centimetres) matters nothing
    against the metre-scale plausibility limits, and it is a quarter of the work.
    """
    rows, cols = np.nonzero(labels[::2, ::2])
    rows, cols = 2 * rows, 2 * cols
    zs = z[rows, cols]
    xs = (cols - cv.pad - intr.cx) / intr.fx * zs
    ys = ((rows - cv.pad) % (cv.h + cv.pad) - intr.cy) / intr.fy * zs
    # One 1-D scatter-max over (max x, y, z, -min x, -min y, -min z) is numpy's fast path.
    signed = np.stack([xs, ys, zs, -xs, -ys, -zs], 1).astype(np.float32)  # (N, 6)
    slots = labels[rows, cols][:, None] * 6 + np.arange(6)
    top = np.full(count * 6, -np.inf, dtype=np.float32)
    np.maximum.at(top, slots.reshape(-1), signed.reshape(-1))
    top = top.reshape(count, 2, 3)
    return np.stack([-top[:, 1], top[:, 0]], 1)


def _box_sizes(box: np.ndarray) -> np.ndarray:
    """(..., 3) extents of (..., 2, 3) boxes, 0 for empty ones."""
    return np.maximum(box[..., 1, :] - box[..., 0, :], 0.0)


def _plausible_size(size: np.ndarray, cfg: SegmentationConfig) -> np.ndarray:
    """(...,) bool: (..., 3) metric extents fit a person."""
    limits = np.array([cfg.max_width_m, cfg.max_height_m, cfg.max_depth_extent_m])
    return (size <= limits).all(-1)


def _extents_fit(
    in_person: np.ndarray,
    join: np.ndarray,
    box: np.ndarray,
    image_of: np.ndarray,
    b: int,
    cfg: SegmentationConfig,
) -> np.ndarray:
    """(count,) bool: joining each candidate keeps its image's person within plausible extents."""
    lo = np.full((b, 3), np.inf)
    hi = np.full((b, 3), -np.inf)
    np.minimum.at(lo, image_of[in_person], box[in_person, 0])
    np.maximum.at(hi, image_of[in_person], box[in_person, 1])
    merged = np.stack([np.minimum(lo[image_of], box[:, 0]), np.maximum(hi[image_of], box[:, 1])], 1)
    return ~join | _plausible_size(_box_sizes(merged), cfg)


def _occluded_by_large(
    lab_nb: np.ndarray,
    step: np.ndarray,
    jump: np.ndarray,
    comp_area: np.ndarray,
    count: int,
    min_area: float,
) -> np.ndarray:
    """(count,) bool: components seen behind a nearer component of at least ``min_area``.

    Every cut pixel sits on the far side of a depth step: its similar-depth neighbours name
    the hidden component, its much nearer neighbours the occluder.

    Args:
        lab_nb: (M, 4) component labels of the 4-neighbours of the M cut pixels (0 = none).
        step: (M, 4) cut pixel's depth minus its neighbours'.
        jump: (M, 1) depth step that separates surfaces at each cut pixel.
    """
    labelled = lab_nb > 0
    nearer = (step > jump) & labelled
    similar = (np.abs(step) <= jump) & labelled
    hidden = np.where(similar, lab_nb, 0).max(1, initial=0)
    # A step inside one component (chin over neck) is self-occlusion, not background.
    other = nearer & (lab_nb != hidden[:, None])
    occluder_area = np.where(other, comp_area[lab_nb], 0.0).max(1, initial=0.0)
    behind = np.zeros(count, dtype=bool)
    behind[hidden[(hidden > 0) & (occluder_area >= min_area)]] = True
    return behind


@dataclass
class _Components:
    """Connected components of a canvas and their statistics.

    Attributes:
        labels: canvas of component labels (0 = none); the arrays below are indexed by label.
        pixels, depth, area: (count,) pixel count, mean depth (m), metric area (m^2).
        box: (count, 2, 3) metric bounding boxes (see :func:`_boxes`).
        image_of: (count,) batch index.
    """

    labels: np.ndarray
    pixels: np.ndarray
    depth: np.ndarray
    area: np.ndarray
    box: np.ndarray
    image_of: np.ndarray


def _join_nearby_parts(
    in_person: np.ndarray, comps: _Components, b: int, cfg: SegmentationConfig, cv2
) -> np.ndarray:
    """Grow the (count,) bool person components by the parts of the body cut off from them.

    Limbs pointing at the camera are foreshortened, so their depth changes faster between
    pixels than the cut threshold and hands come out as separate components; and a limb
    crossing in front of the body cuts off what lies behind it (an arm swung down in front of
    the hips parts the legs from the trunk, a squat's thighs part the trunk from the feet).
    Components within ``merge_radius_px`` of the person join when
    - their depth range overlaps the person's, with ``merge_depth_margin_m`` to spare:
      cut-off parts of the same body, of any size (the legs are half the body), as long as
      the joined person keeps plausible extents (a wall behind lies beyond the person's
      depths; a side wall or a floor reaching into them makes the person too large). An
      object at the person's depth that touches it without a depth step was never cut from
      it in the first place; or
    - their mean depth is at most ``merge_depth_margin_m`` behind the person's and at most
      ``merge_max_front_m`` in front of it (arm reach), and they are small
      (``merge_max_area_fraction`` of the person: a hand, not a second person).
    """
    r = cfg.merge_radius_px
    if r <= 0 or cfg.merge_rounds <= 0 or not in_person.any():
        return in_person
    c = comps
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    margin = cfg.merge_depth_margin_m
    for _ in range(cfg.merge_rounds):
        # The person is a union of whole components: its statistics come from theirs.
        weight = in_person * c.pixels
        person_depth = np.bincount(c.image_of, weight * c.depth, minlength=b) / np.maximum(
            np.bincount(c.image_of, weight, minlength=b), 1
        )
        person_area = np.bincount(c.image_of, in_person * c.area, minlength=b)
        mask = in_person[c.labels]
        near = cv2.dilate(mask.view(np.uint8), kernel).view(bool)
        touching = np.zeros_like(in_person)
        touching[c.labels[near & ~mask]] = True

        z_lo, z_hi = np.full(b, np.inf), np.full(b, -np.inf)
        np.minimum.at(z_lo, c.image_of[in_person], c.box[in_person, 0, 2])
        np.maximum.at(z_hi, c.image_of[in_person], c.box[in_person, 1, 2])
        cut_off = (c.box[:, 0, 2] <= z_hi[c.image_of] + margin) & (
            c.box[:, 1, 2] >= z_lo[c.image_of] - margin
        )
        offset = c.depth - person_depth[c.image_of]
        in_front = (
            (offset >= -cfg.merge_max_front_m)
            & (offset <= margin)
            & (c.area <= cfg.merge_max_area_fraction * person_area[c.image_of])
        )
        join = touching & ~in_person & (cut_off | in_front)
        join[0] = False
        if join.any():
            join &= _extents_fit(in_person, join, c.box, c.image_of, b, cfg)
        if not join.any():
            break
        in_person = in_person | join
    return in_person


def segment_person(
    depth_m: torch.Tensor, intr: Intrinsics, cfg: SegmentationConfig | None = None
) -> torch.Tensor:
    """Mask of the person in depth frames (module docstring).

    Runs on the CPU in numpy/OpenCV whatever the input device (single frames are far too
    small for a GPU to pay off); the mask comes back on the input's device.

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
    depth_np = np.ascontiguousarray(depth.detach().to("cpu", torch.float32).numpy())
    mask = torch.from_numpy(_segment_np(depth_np, intr, cfg).copy()).to(depth_m.device)
    return mask[0] if single else mask
