"""Which pixels each capsule of the body can cover: the ray-caster's candidate (pixel, primitive)
pairs.

Casting every pixel of each primitive's bounding box wastes most of the work on limbs that run
diagonally across the image (about four pairs per hit on the dev recordings). Each row is cut
to a conservative interval instead:

- A capsule lies in the convex hull of two spheres of radius R (its largest semi-axis) around
  its cap centres a and b. A point ``c + d`` with ``|d| <= R`` projects within
  ``rho = f R |c| / (c_z (c_z - R))`` of ``c``'s projection (the 2 x 3 matrix
  ``[[c_z, 0, -c_x], [0, c_z, -c_y]]`` has norm ``|c|``), and perspective keeps the segment
  ab straight, so the capsule projects into the 2D stadium of radius rho around the projected
  segment (rho taken at the nearer, larger end).
- That stadium lies in the band of half-width rho around the projected segment's line, whose
  cut with row v is ``x_line(v) +- rho L / |dy|``; intersected with the box it is the span.

Primitives reaching within 5 cm of the camera plane keep their whole box rows. Over a batch,
each row keeps the hull of the poses' spans. Everything stays on the input's device; the
pairs' count is the one host sync.
"""

from __future__ import annotations

import torch
from depthmocap.shared.camera import Intrinsics

__all__ = ["NEAR", "capsule_ends", "segment_boxes", "segment_row_spans", "span_pairs"]

NEAR = 1e-3  # hits closer than this to the camera (or behind it) are ignored, metres
_SPAN_MIN_DEPTH = 0.05  # nearer than this (capsule's closest point), rows keep the whole box
_SLACK_PX = 1.0  # rounding margin added to every span


def capsule_ends(
    rot: torch.Tensor,
    origin: torch.Tensor,
    basis_axis: torch.Tensor,
    span: torch.Tensor,
    scale: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-frame cap centres (B, P, 2, 3) and bounding radius (B, P, 1) of each primitive.

    Args:
        rot, origin: (B, P, 3, 3), (B, P, 3) primitive frames.
        basis_axis: (P, 3) capsule axis in the local frame; span: (..., P, 2) cap centres along
            it; scale: (..., P, 3) semi-axes.
    """
    B = origin.shape[0]
    axis_w = torch.einsum("bkij,kj->bki", rot, basis_axis)
    centres = origin[:, :, None] + span.expand(B, -1, -1)[..., None] * axis_w[:, :, None]
    radius = scale[..., :2].max(-1).values.expand(B, -1)[..., None]
    return centres, radius


def segment_boxes(centres: torch.Tensor, radius: torch.Tensor, intr: Intrinsics) -> torch.Tensor:
    """Conservative pixel box of each primitive over the batch: (P, 4) float (u0, u1, v0, v1),
    whole pixel numbers, end-exclusive, clamped to the image; empty boxes have u1 <= u0.

    A capsule lies in the convex hull of two spheres around its cap centres; perspective maps
    that hull into the hull of the spheres' projections, whose boxes bound each sphere's
    projection via the extreme x/z and y/z ratios.

    Args:
        centres, radius: from :func:`capsule_ends`.
    """
    x, y, z = centres.unbind(-1)
    near, far = (z - radius).clamp_min(NEAR), z + radius
    visible = far > NEAR
    big = torch.finfo(x.dtype).max

    def extent(c):
        lo = torch.minimum((c - radius) / near, (c - radius) / far)
        hi = torch.maximum((c + radius) / near, (c + radius) / far)
        lo = torch.where(visible, lo, big).amin(dim=(0, 2))
        hi = torch.where(visible, hi, -big).amax(dim=(0, 2))
        return lo, hi

    (ul, uh), (vl, vh) = extent(x), extent(y)
    u0 = (ul * intr.fx + intr.cx).clamp(-1e6, 1e6).floor().clamp_min(0)
    v0 = (vl * intr.fy + intr.cy).clamp(-1e6, 1e6).floor().clamp_min(0)
    u1 = ((uh * intr.fx + intr.cx).clamp(-1e6, 1e6).ceil() + 1).clamp_max(intr.width)
    v1 = ((vh * intr.fy + intr.cy).clamp(-1e6, 1e6).ceil() + 1).clamp_max(intr.height)
    return torch.stack([u0, u1, v0, v1], -1)


def segment_row_spans(
    centres: torch.Tensor, radius: torch.Tensor, intr: Intrinsics, boxes: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """First column and column count of every primitive's candidate pixels on every row.

    Args:
        centres, radius: from :func:`capsule_ends`; boxes: (P, 4) from :func:`segment_boxes`.
    Returns:
        (P, H) int64 first column and (P, H) int64 count (0 off the box).
    """
    z = centres[..., 2]
    zmin = z.amin(-1)  # (B, P)
    near_ok = zmin - radius[..., 0] > _SPAN_MIN_DEPTH
    zsafe = torch.where(near_ok[..., None], z, torch.ones_like(z))
    f = max(intr.fx, intr.fy)
    uv = torch.stack(
        [centres[..., 0] / zsafe * intr.fx + intr.cx, centres[..., 1] / zsafe * intr.fy + intr.cy],
        -1,
    )  # (B, P, 2, 2): end, (u, v)
    zm = torch.where(near_ok, zmin, torch.ones_like(zmin))
    rho = f * radius[..., 0] * centres.norm(dim=-1).amax(-1) / (zm * (zm - radius[..., 0]))
    rho = rho + _SLACK_PX
    a, b = uv[:, :, 0], uv[:, :, 1]
    dx, dy = (b - a).unbind(-1)
    length = (b - a).norm(dim=-1)
    rows = torch.arange(intr.height, dtype=z.dtype, device=z.device)  # (H,)
    steep = dy.abs() > 1e-6
    dys = torch.where(steep, dy, torch.ones_like(dy))
    x_line = a[..., 0, None] + (rows - a[..., 1, None]) * (dx / dys)[..., None]  # (B, P, H)
    half = (rho * length / dys.abs())[..., None].expand_as(x_line)
    tight = (near_ok & steep)[..., None]
    inf = torch.full_like(x_line, float("inf"))
    lo = torch.where(tight, x_line - half, -inf).amin(0)  # hull over the batch: (P, H)
    hi = torch.where(tight, x_line + half, inf).amax(0)
    u0, u1, v0, v1 = boxes.unbind(-1)
    first = torch.maximum(lo.ceil(), u0[:, None])
    last = torch.minimum(hi.floor(), u1[:, None] - 1)
    in_box = (rows >= v0[:, None]) & (rows < v1[:, None])
    count = torch.where(in_box, (last - first + 1).clamp_min(0), torch.zeros_like(first))
    return first.long(), count.long()


def span_pairs(
    first: torch.Tensor, count: torch.Tensor, width: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Every (pixel, primitive) pair of the spans: flat pixel index (N,), primitive (N,),
    column (N,), row (N,).

    Args:
        first, count: (P, H) from :func:`segment_row_spans` (or whole box rows).
    """
    P, H = count.shape
    flat = count.reshape(-1)
    total = int(flat.sum())
    entries = torch.arange(P * H, device=count.device)
    entry = torch.repeat_interleave(entries, flat, output_size=total)
    start = torch.cumsum(flat, 0) - flat
    # index_select, not x[entry]: several times faster on CPU at these sizes.
    offset = (first.reshape(-1) - start).index_select(0, entry)
    col = offset + torch.arange(total, device=count.device)
    row = entry % H
    return row * width + col, entry // H, col, row
