"""Step 2 of person segmentation: the RANSAC floor plane and the removal of the floor band
(:mod:`runtime.segmentation`)."""

from __future__ import annotations

import math

import numpy as np
import torch
from depthmocap.shared.camera import Intrinsics

from .config import SegmentationConfig

__all__ = ["fit_floor_plane", "remove_floor"]


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
        & _supported(best_dist, count, cfg)
        & (-refined[:, 1] >= cos_max)
        & hyp_ok[rows, best]
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


def _supported(dist: np.ndarray, count: np.ndarray, cfg: SegmentationConfig) -> np.ndarray:
    """(B,) bool: a plane at signed distances ``dist`` (B, N) from the sampled points, drawn
    from ``count`` (B,) candidates, is a floor's: enough points within the band, few below
    it (nothing stands under a floor)."""
    n = dist.shape[1]
    return (
        (count >= 50)
        & (np.count_nonzero(np.abs(dist) < cfg.floor_band_m, axis=1) >= cfg.floor_min_support * n)
        & (np.count_nonzero(dist < -cfg.floor_band_m, axis=1) <= cfg.floor_max_below * n)
    )


def _plane_holds(
    pts: np.ndarray, count: np.ndarray, normal: np.ndarray, centre: np.ndarray,
    cfg: SegmentationConfig,
) -> np.ndarray:  # fmt: skip
    """(B,) bool: the planes (B, 3) still explain this frame's sampled points (B, N, 3)."""
    return _supported(((pts - centre[:, None]) * normal[:, None]).sum(-1), count, cfg)


def remove_floor(
    z: np.ndarray,
    valid: np.ndarray,
    intr: Intrinsics,
    cfg: SegmentationConfig,
    previous: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(B, H, W) valid pixels of depth ``z`` without those within the floor band.

    Args:
        previous: the floor (normal (B, 3), centre (B, 3), found (B,)) of the previous frame
            of a stream. Where this frame's fit fails (the person covers most of the floor in
            view, crouching close to a low camera) and the previous floor still explains the
            floor points, the previous one is removed: a camera does not move between frames.
    Returns:
        the valid pixels, and the floor used (normal, centre, found) for the next frame.
    """
    b, h, w = z.shape
    rng = np.random.default_rng(cfg.seed)
    rows, cols, count = _sample_floor_pixels(valid, cfg, rng)
    zs = z[np.arange(b)[:, None], rows, cols].astype(np.float64)
    pts = np.stack([(cols - intr.cx) / intr.fx * zs, (rows - intr.cy) / intr.fy * zs, zs], -1)
    normal, centre, found = _fit_floor_np(pts, count, cfg, rng)
    if previous is not None and cfg.keep_floor:
        p_normal, p_centre, p_found = previous
        reuse = ~found & p_found & _plane_holds(pts, count, p_normal, p_centre, cfg)
        normal = np.where(reuse[:, None], p_normal, normal)
        centre = np.where(reuse[:, None], p_centre, centre)
        found = found | reuse
    if not found.any():
        return valid, (normal, centre, found)
    # Height above the plane of every pixel: z * (n . ray) - n . centre, ray = (x/z, y/z, 1).
    n = normal.astype(np.float32)[:, :, None, None]
    ray_dot = (
        n[:, 0] * ((np.arange(w, dtype=np.float32) - intr.cx) / intr.fx)[None, None]
        + n[:, 1] * ((np.arange(h, dtype=np.float32) - intr.cy) / intr.fy)[None, :, None]
        + n[:, 2]
    )  # (B, H, W)
    level = (normal * centre).sum(1).astype(np.float32)[:, None, None]
    floor = (z * ray_dot - level < cfg.floor_band_m) & found[:, None, None]
    return valid & ~floor, (normal, centre, found)
