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

from .observation import Observation

__all__ = ["Regions", "classify", "sample_pixels", "pixel_rays", "rendered_points"]


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


def sample_pixels(mask: torch.Tensor, max_count: int) -> tuple[torch.Tensor, int, float]:
    """About ``max_count`` of the True pixels, on a fixed pseudo-random lattice.

    With s = ceil(count / max_count), a pixel is kept when a hash of its (v, u) is 0 modulo
    s, so the kept set depends on the pixel, not on how many True pixels precede it: between
    Gauss-Newton iterations the region masks change a little and the samples stay put (taking
    every s-th True pixel instead moved every sample after the first change, and the
    iterations never settled).

    Returns:
        (N, 3) int64 rows (b, v, u); the number of True pixels; their ratio to the N kept
        (each kept pixel stands for that many), 1.0 when nothing is dropped.
    """
    idx = mask.nonzero()
    total = idx.shape[0]
    if total > max_count > 0:
        stride = -(-total // max_count)
        key = (idx[:, 2] * 73856093) ^ (idx[:, 1] * 19349663)
        idx = idx[key % stride == 0]
    ratio = total / max(1, idx.shape[0])
    return idx, total, ratio


def pixel_rays(idx: torch.Tensor, intr: Intrinsics, dtype: torch.dtype) -> torch.Tensor:
    """Ray directions (N, 3) with z = 1 through the pixels ``idx`` (b, v, u)."""
    u = idx[:, 2].to(dtype)
    v = idx[:, 1].to(dtype)
    return torch.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, torch.ones_like(u)], -1)


def rendered_points(
    render: BodyRender, idx: torch.Tensor, intr: Intrinsics
) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-frame rendered surface points (N, 3) and their segments (N,) at pixels ``idx``."""
    b, v, u = idx.unbind(1)
    depth = render.depth[b, v, u]
    return depth[:, None] * pixel_rays(idx, intr, depth.dtype), render.segment[b, v, u]
