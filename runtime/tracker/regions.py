"""Pixel classification of Wei section 3 (figure 4) and pixel sampling helpers.

R: rendered silhouette; O: observed silhouette; G = R - B1 - B2 feeds the depth term;
B1 = R - O (rendered over observed background); B2 = pixels of R and O whose depths differ
by more than the gate (self-occlusion: different segments rendered and observed), split by
which side is in front; B3 = O - R. Observed silhouette pixels without a depth reading
belong to none of the depth regions.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from depthmocap.runtime.raycast import BodyRender
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.compiled import compiled_float32, compiled_module

from .observation import Observation

__all__ = [
    "Regions",
    "classify",
    "sample_pixels",
    "sample_pixels_torch",
    "batch_slots",
    "pixel_rays",
    "rendered_points",
]


@dataclass
class Regions:
    """Boolean (B, H, W) maps of the pixel classes.

    Attributes:
        good: G, pixels of the depth term.
        b1: rendered foreground on observed background (extra depth type 1).
        b2_front: B2 where the rendered surface is in front of the observed (type 3).
        b2_behind: B2 where the rendered surface is behind the observed (type 4).
        b3: observed foreground (with depth) the rendering misses (type 2).
        depth_diff: (B, H, W) observed minus rendered depth (metres; valid on R and O).
    """

    good: torch.Tensor
    b1: torch.Tensor
    b2_front: torch.Tensor
    b2_behind: torch.Tensor
    b3: torch.Tensor
    depth_diff: torch.Tensor


def classify(render: BodyRender, obs: Observation, gate_m: float, occlusion: bool) -> Regions:
    """Split pixels into G, B1, B2 (front/behind), B3. ``occlusion=False``: no B2 (naive)."""
    rendered, valid = render.mask, obs.valid
    kernel = compiled_float32(
        "depthmocap.runtime.tracker.regions_kernel", obs.depth, render.depth
    )  # fmt: skip
    if kernel is not None:  # one compiled pass, the same regions
        return Regions(
            *kernel.classify_cpu(
                rendered, valid, obs.silhouette, obs.depth, render.depth, gate_m, occlusion
            )
        )
    both = rendered & valid
    diff = obs.depth - render.depth
    if occlusion:
        good = both & (diff.abs() <= gate_m)
        front = both & (diff > gate_m)
        behind = both & (diff < -gate_m)
    else:
        good = both
        front = behind = torch.zeros_like(both)
    return Regions(good, rendered & ~obs.silhouette, front, behind, valid & ~rendered, diff)


def sample_pixels(
    mask: torch.Tensor, max_count: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """About ``max_count`` of the True pixels of each of the B masks, on a fixed pseudo-random
    lattice.

    With s = ceil(count / max_count) for a mask's count of True pixels, a pixel is kept when
    a hash of its (v, u) is 0 modulo s, so the kept set depends on the pixel, not on how many
    True pixels precede it: between Gauss-Newton iterations the region masks change a little
    and the samples stay put (taking every s-th True pixel instead moved every sample after
    the first change, and the iterations never settled). The cap is per mask, so a batch of B
    poses on the same frame samples each exactly as a batch of one would.

    Args:
        mask: (B, H, W) bool; max_count: the cap per mask (<= 0: keep every pixel).
    Returns:
        (N, 3) int64 rows (b, v, u), sorted by b; (B,) int64 count of True pixels per mask;
        (N,) float64 ratio of each kept pixel's mask count to its kept count (each kept pixel
        stands for that many), 1 where nothing is dropped. Callers turn a weight made from it
        into their dtype last, so one pose's rows are those of a Python-float ratio to the
        bit.
    """
    kernel = _compiled_kernel() if mask.device.type == "cpu" else None
    if kernel is not None:
        return kernel.sample_pixels_cpu(mask, max_count)
    return sample_pixels_torch(mask, max_count)


def sample_pixels_torch(
    mask: torch.Tensor, max_count: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`sample_pixels` in torch ops (GPUs, and CPUs without numba).

    The lattice test is made on the whole (B, H, W) grid and the kept pixels listed by one
    ``nonzero``: on a GPU that is the call's only host sync (listing the True pixels first
    and filtering them was two, a third of a frame's syncs)."""
    B, H, W = mask.shape
    dev = mask.device
    total = mask.sum((1, 2))  # (B,) int64
    if max_count > 0:
        stride = ((total + max_count - 1) // max_count).clamp_min(1)  # 1: nothing dropped
        v = torch.arange(H, device=dev)[:, None]
        u = torch.arange(W, device=dev)[None]
        key = (u * 73856093) ^ (v * 19349663)  # (H, W)
        mask = mask & (key % stride[:, None, None] == 0)
    kept = mask.sum((1, 2))  # before listing: bincount would sync twice more
    idx = mask.nonzero()
    ratio = (total.double() / kept.clamp_min(1).double())[idx[:, 0]]
    return idx, total, ratio


def _compiled_kernel():
    """:mod:`runtime.tracker.sampling_kernel` (numba's compiled sampler), or None without
    numba."""
    return compiled_module("depthmocap.runtime.tracker.sampling_kernel")


def batch_slots(batch: torch.Tensor, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Rows grouped by their batch index, padded: for rows with pose indices ``batch`` (N,)
    in [0, size), a (size, K) table of row indices (K: the largest group) and a (size, K)
    bool mask of the real entries (padding points at row 0). Lets per-pose work on a
    batch's rows run as one (size, K, ...) tensor op without pairing rows of different
    poses (one host sync for K)."""
    n = batch.shape[0]
    # A scatter, not bincount, which makes the host wait twice on a GPU.
    counts = torch.zeros(size, dtype=torch.long, device=batch.device)
    counts.index_add_(0, batch, torch.ones_like(batch))
    width = int(counts.max()) if n else 0
    order = torch.argsort(batch, stable=True)
    start = torch.cumsum(counts, 0) - counts
    sorted_batch = batch[order]
    pos = torch.arange(n, device=batch.device) - start[sorted_batch]
    slots = torch.full((size, width), -1, dtype=torch.long, device=batch.device)
    slots[sorted_batch, pos] = order
    real = slots >= 0
    return slots.clamp_min(0), real


def pixel_rays(idx: torch.Tensor, intr: Intrinsics, dtype: torch.dtype) -> torch.Tensor:
    """Ray directions (N, 3) with z = 1 through the pixels ``idx`` (b, v, u)."""
    u = idx[:, 2].to(dtype)
    v = idx[:, 1].to(dtype)
    return torch.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, torch.ones_like(u)], -1)


def rendered_points(
    render: BodyRender, idx: torch.Tensor, intr: Intrinsics
) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-frame rendered surface points (N, 3) and their segments (N,) at pixels ``idx``."""
    depth = render.depth
    if depth.device.type == "cpu" and not depth.requires_grad:
        kernel = _compiled_kernel()
        if kernel is not None:
            return kernel.rendered_points_cpu(depth, render.segment, idx, intr)
    b, v, u = idx.unbind(1)
    depth = render.depth[b, v, u]
    return depth[:, None] * pixel_rays(idx, intr, depth.dtype), render.segment[b, v, u]
