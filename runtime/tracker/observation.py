"""The observed frame at the tracker's working resolution: depth, silhouette, points, distances.

Computed once per frame, before the Gauss-Newton iterations: the stream's depth and the
caller's person mask are cut to a window around the person, pooled to the working resolution,
back-projected, and the observed silhouette gets a truncated Euclidean distance transform whose
gradient drives the silhouette term beyond the silhouette's boundary.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics, depth_to_points
from depthmocap.shared.compiled import compiled_module

__all__ = [
    "Observation",
    "working_intrinsics",
    "pool_depth",
    "distance_to_mask",
    "distance_to_mask_torch",
    "automatic_factor",
    "person_window",
    "observe",
]


_KERNEL = "depthmocap.runtime.tracker.distance_kernel"


@dataclass
class Observation:
    """Observed data at working resolution (B frames of H x W).

    Attributes:
        intr: working-resolution intrinsics.
        depth: (B, H, W) metres on the person, 0 elsewhere or where the reading is missing.
        silhouette: (B, H, W) bool observed person silhouette O.
        valid: (B, H, W) bool silhouette pixels with a depth reading.
        points: (B, H, W, 3) camera-frame points of ``depth`` (0 where invalid).
        distance: (B, H, W) distance to the nearest silhouette pixel, working pixels,
            truncated (0 inside O).
        distance_grad: (B, H, W, 2) its gradient along (u, v) by central differences.
        labels: (B, H, W) int64 segment the forest labels each pixel as (-1: none), for the
            label term; None when the caller gave no labels.
        label_sure: (B, H, W) bool, the labels the label term may read (the forest sure
            enough of them: ``TrackerConfig.label_min_posterior``); None: all of them. The
            observed-joint support reads every label.
    """

    intr: Intrinsics
    depth: torch.Tensor
    silhouette: torch.Tensor
    valid: torch.Tensor
    points: torch.Tensor
    distance: torch.Tensor
    distance_grad: torch.Tensor
    labels: torch.Tensor | None = None
    label_sure: torch.Tensor | None = None


def label_term_pixels(obs: Observation) -> torch.Tensor:
    """(B, H, W) bool: the pixels the label term reads, valid ones labelled as a limb (and
    sure, where the observation says which are)."""
    if obs.labels is None:
        return torch.zeros_like(obs.valid)
    use = obs.valid & (obs.labels >= sk.FIRST_LIMB_SEGMENT)
    return use if obs.label_sure is None else use & obs.label_sure


def working_intrinsics(intr: Intrinsics, factor: int) -> Intrinsics:
    """Intrinsics of the working image whose pixel (i, j) is the stream's (f i, f j)."""
    if factor == 1:
        return intr
    s = 1.0 / factor
    return Intrinsics(
        intr.width // factor,
        intr.height // factor,
        intr.fx * s,
        intr.fy * s,
        intr.cx * s,
        intr.cy * s,
    )


def pool_depth(
    depth: torch.Tensor, mask: torch.Tensor, factor: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Subsample depth and mask by ``factor``, filling missing readings from the block.

    Working pixel (i, j) is the stream's pixel (f i, f j): the silhouette and the depth are
    that pixel's, so the working image is exactly what a ray-cast through that pixel sees (no
    half-pixel shift or dilation of thin limbs at the silhouette). Where that reading is
    missing or off the mask, the nearest valid masked reading of the f x f block fills in.

    Args:
        depth: (B, H, W) metres, 0 = no reading; mask: (B, H, W) bool.
    Returns:
        depth (B, H // f, W // f) (0 where no valid reading), mask (B, H // f, W // f).
    """
    if factor == 1:
        return depth * mask, mask
    B, H, W = depth.shape
    h, w = H // factor, W // factor
    d = depth[:, : h * factor, : w * factor].reshape(B, h, factor, w, factor)
    m = mask[:, : h * factor, : w * factor].reshape(B, h, factor, w, factor)
    ok = m & (d > 0)
    near = torch.where(ok, d, torch.full_like(d, float("inf"))).amin((2, 4))
    near = torch.where(torch.isfinite(near), near, torch.zeros_like(near))
    silhouette = m[:, :, 0, :, 0]
    here = torch.where(ok[:, :, 0, :, 0], d[:, :, 0, :, 0], near)
    return here * silhouette, silhouette


def distance_to_mask(mask: torch.Tensor, max_px: float) -> torch.Tensor:
    """Euclidean distance (pixels) of every pixel to the nearest True pixel, capped at max_px.

    Exact up to the cap (separable: row distances, then the column pass); the loops run over
    the (2T + 1) shifts, not over pixels. (B, H, W) bool -> (B, H, W) float32. On the CPU
    with numba, one compiled loop (:mod:`runtime.tracker.distance_kernel`, the same values).
    """
    kernel = compiled_module(_KERNEL) if mask.device.type == "cpu" else None
    if kernel is not None:
        return kernel.distance_to_mask_cpu(mask, max_px)
    return distance_to_mask_torch(mask, max_px)


def distance_to_mask_torch(mask: torch.Tensor, max_px: float) -> torch.Tensor:
    """:func:`distance_to_mask` in torch ops (GPUs, and CPUs without numba)."""
    T = int(max_px) + 1
    B, H, W = mask.shape
    far = float(T)
    pad = torch.nn.functional.pad(mask, (T, T))
    row = torch.full(mask.shape, far, dtype=torch.float32, device=mask.device)
    for s in range(-T, T + 1):
        hit = pad[:, :, T + s : T + s + W]
        row = torch.where(hit, torch.minimum(row, torch.full_like(row, abs(s))), row)
    row2 = torch.nn.functional.pad(row * row, (0, 0, T, T), value=far * far)
    best = row * row
    for s in range(-T, T + 1):
        if s != 0:
            best = torch.minimum(best, row2[:, T + s : T + s + H] + s * s)
    return best.sqrt().clamp_max(max_px)


def _central_gradient(image: torch.Tensor) -> torch.Tensor:
    """(B, H, W) -> (B, H, W, 2) central differences along (u, v), one-sided at borders."""
    p = torch.nn.functional.pad(image[:, None], (1, 1, 1, 1), mode="replicate")[:, 0]
    gu = 0.5 * (p[:, 1:-1, 2:] - p[:, 1:-1, :-2])
    gv = 0.5 * (p[:, 2:, 1:-1] - p[:, :-2, 1:-1])
    return torch.stack([gu, gv], -1)


def automatic_factor(mask: torch.Tensor, person_pixels: int) -> int:
    """Pooling factor at which the largest of the (B, H, W) silhouettes covers about
    ``person_pixels`` working pixels (rounded, at least 1; one host sync)."""
    count = float(mask.sum((-2, -1)).max()) if mask.numel() else 0.0
    return max(1, round(math.sqrt(count / max(1, person_pixels))))


def person_window(
    mask: torch.Tensor, factor: int, margin: float, min_margin_px: int
) -> tuple[int, int, int, int] | None:
    """Stream-pixel window (u0, u1, v0, v1), end-exclusive, around all B silhouettes.

    The silhouettes' bounding box grows on every side by ``margin`` times its larger side, and
    by at least ``min_margin_px`` working pixels, clipped to the image. The corner is a
    multiple of ``factor``, so the working pixels inside are those of the whole image. None
    when the masks are empty.
    """
    H, W = mask.shape[-2:]
    flat = mask.reshape(-1, H, W).any(0)
    rows, cols = flat.any(1).nonzero()[:, 0], flat.any(0).nonzero()[:, 0]
    if rows.numel() == 0:
        return None
    v0, v1, u0, u1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    pad = max(math.ceil(margin * max(v1 - v0, u1 - u0)), factor * min_margin_px)
    u0, v0 = max(0, u0 - pad) // factor * factor, max(0, v0 - pad) // factor * factor
    return u0, min(W, u1 + pad), v0, min(H, v1 + pad)


def observe(
    depth: torch.Tensor,
    mask: torch.Tensor,
    intr: Intrinsics,
    factor: int,
    max_distance_px: float,
    window: tuple[int, int, int, int] | None = None,
    labels: torch.Tensor | None = None,
    label_sure: torch.Tensor | None = None,
) -> Observation:
    """Working-resolution observation of full-resolution frames.

    Args:
        depth: (B, H, W) metres at the stream resolution ``intr``, 0 = no reading.
        mask: (B, H, W) bool person silhouette from the caller's segmentation.
        factor: integer downsampling factor; max_distance_px: distance-transform cap.
        window: stream-pixel window (u0, u1, v0, v1) to work in (:func:`person_window`;
            its corner a multiple of ``factor``), None for the whole image. The observation's
            intrinsics are the window's, so everything downstream costs what the person
            covers, not what the image does.
        labels: (B, H, W) int64 segment per stream pixel (-1: none), optional; working pixel
            (i, j) takes stream pixel (f i, f j)'s, like the silhouette.
        label_sure: (B, H, W) bool, which of the labels the label term may read, optional
            (None: all); taken like the labels.
    """
    if window is not None:
        u0, u1, v0, v1 = window
        depth, mask = depth[..., v0:v1, u0:u1], mask[..., v0:v1, u0:u1]
        labels = None if labels is None else labels[..., v0:v1, u0:u1]
        label_sure = None if label_sure is None else label_sure[..., v0:v1, u0:u1]
        intr = intr.cropped(u0, v0, u1 - u0, v1 - v0)
    work = working_intrinsics(intr, factor)
    pooled, silhouette = pool_depth(depth, mask.bool(), factor)
    valid = silhouette & (pooled > 0)
    pooled = pooled * valid
    points = depth_to_points(pooled, work)
    distance = distance_to_mask(silhouette, max_distance_px).to(depth.dtype)
    grad = _central_gradient(distance)
    if labels is not None:
        h, w = pooled.shape[-2:]
        labels = labels[..., ::factor, ::factor][..., :h, :w]
        if label_sure is not None:
            label_sure = label_sure[..., ::factor, ::factor][..., :h, :w].bool()
    else:
        label_sure = None
    return Observation(work, pooled, silhouette, valid, points, distance, grad, labels, label_sure)
