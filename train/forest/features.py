"""Depth-difference features for training, vectorized over (pixels x offset pairs) in torch.

    f(x) = D(x + u / D(x)) - D(x + v / D(x))

computed on int16 millimetre depth in which every non-person pixel, every pixel without a
reading and everything off the image reads ``background_mm`` (the image is padded by one
background pixel on each side and probe coordinates are clamped into the padding). Probe
coordinates use exactly the arithmetic of the runtime (``runtime/forest/inference.py``):
``c = floor(clamp(u * (1 / D(x)) + (x + 1.5), 0, W + 1))`` in float32 in the padded image, so a
threshold learned here splits the same way there.
"""

from __future__ import annotations

import torch

__all__ = [
    "sample_offset_pairs",
    "person_depth_mm",
    "pad_with_background",
    "sample_pixels",
    "sample_candidates",
    "depth_features_mm",
]


def sample_offset_pairs(
    count: int,
    max_px_m: tuple[float, float],
    unary_fraction: float,
    generator: torch.Generator,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Random offset pairs, uniform in the box ``[-max, max]`` per axis (pixel*metres).

    Returns:
        u, v: (count, 2) float32 (x = column, y = row); ``v = 0`` for a ``unary_fraction`` of
        the pairs (features comparing a probe with the pixel itself).
    """
    scale = torch.tensor(max_px_m, dtype=torch.float32)
    u = (torch.rand(count, 2, generator=generator) * 2 - 1) * scale
    v = (torch.rand(count, 2, generator=generator) * 2 - 1) * scale
    unary = torch.rand(count, generator=generator) < unary_fraction
    v[unary] = 0.0
    return u, v


def person_depth_mm(depth_mm: torch.Tensor, mask: torch.Tensor, background_mm: int) -> torch.Tensor:
    """(F, H, W) int16 depth with pixels outside ``mask`` or without a reading at background.

    Args:
        depth_mm: (F, H, W) uint16/int millimetres, 0 = no reading.
        mask: (F, H, W) bool person mask (training: ``labels > 0``).
    """
    d = depth_mm.to(torch.int32)
    keep = mask & (d > 0) & (d < background_mm)
    return torch.where(keep, d, background_mm).to(torch.int16)


def pad_with_background(depth: torch.Tensor, background_mm: int) -> torch.Tensor:
    """(F, H, W) -> (F, H + 2, W + 2): one background pixel around every frame."""
    return torch.nn.functional.pad(depth, (1, 1, 1, 1), value=background_mm)


def sample_pixels(
    labels: torch.Tensor,
    valid: torch.Tensor,
    count: int,
    class_weights: torch.Tensor,
    generator: torch.Generator,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Draw up to ``count`` valid pixels per frame without replacement, weighted by class.

    Args:
        labels: (F, H, W) uint8 class labels.
        valid: (F, H, W) bool pixels that may be drawn.
        class_weights: (C,) float32 sampling weight of each class (0 = never).
    Returns:
        frame, row, col: (N,) int64 of the drawn pixels, ordered by frame (frames with fewer
        valid pixels give all of them).
    """
    f, h, w = labels.shape
    frame, flat = torch.nonzero(valid.view(f, h * w), as_tuple=True)
    cls = labels.view(f, h * w)[frame, flat].long()
    frame, flat = sample_candidates(frame, flat, cls, f, count, class_weights, generator)
    return frame, flat // w, flat % w


def sample_candidates(
    frame: torch.Tensor,
    flat: torch.Tensor,
    cls: torch.Tensor,
    frames: int,
    count: int,
    class_weights: torch.Tensor,
    generator: torch.Generator,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`sample_pixels` on a list of candidate pixels (frame, flat index, class), sorted
    by frame: weighted sampling without replacement by the Gumbel-top-k trick (each pixel gets
    the key ``log w - log(-log U)``; the ``count`` largest keys of a frame win)."""
    weight = class_weights[cls]
    keep = weight > 0
    frame, flat, weight = frame[keep], flat[keep], weight[keep]
    uniform = torch.rand(frame.shape[0], generator=generator).clamp_min_(1e-12)
    key = torch.log(weight) - torch.log(-torch.log(uniform))
    order = torch.argsort(key, descending=True)
    order = order[torch.sort(frame[order], stable=True).indices]  # by frame, then key
    frame, flat = frame[order], flat[order]
    starts = torch.searchsorted(frame, torch.arange(frames))
    rank = torch.arange(frame.shape[0]) - starts[frame]
    take = rank < count
    return frame[take], flat[take]


def depth_features_mm(
    padded: torch.Tensor,
    frame: torch.Tensor,
    row: torch.Tensor,
    col: torch.Tensor,
    u: torch.Tensor,
    v: torch.Tensor,
    chunk_elements: int = 1 << 16,
) -> torch.Tensor:
    """Features of pixels (frame, row, col) for every offset pair, in millimetres.

    Args:
        padded: (F, H + 2, W + 2) int16 depth from :func:`pad_with_background`.
        frame, row, col: (N,) int64 pixel positions in the unpadded frames (on the person).
        u, v: (P, 2) float32 offset pairs (pixel*metres).
    Returns:
        (N, P) int16 features D(probe u) - D(probe v) in mm.

    Probes are clamped into the one-pixel background border exactly as at runtime. To avoid
    the clamps in the inner loop, the frames are re-padded with a border as wide as the
    largest probe displacement of these pixels; every probe beyond the image then reads the
    same background value that the clamped probe would read.
    """
    f, hp, wp = padded.shape
    n, p = frame.shape[0], u.shape[0]
    device = padded.device
    out = torch.empty(n, p, dtype=torch.int16, device=device)
    if n == 0:
        return out
    u, v = u.to(device), v.to(device)
    flat1 = padded.reshape(-1)
    depth_m = flat1[(frame * hp + row + 1) * wp + col + 1].to(torch.float32) / 1000.0
    invd = 1.0 / depth_m
    reach = float(torch.cat([u, v]).abs().max()) * float(invd.max())
    border = int(reach) + 3
    bg = int(padded[0, 0, 0])
    big = torch.nn.functional.pad(padded[:, 1:-1, 1:-1], (border,) * 4, value=bg)
    hb, wb = big.shape[1:]
    flat = big.reshape(-1)
    ux, uy, vx, vy = u[:, 0], u[:, 1], v[:, 0], v[:, 1]
    # Same float32 arithmetic as the runtime: floor(offset * invd + (x + 1.5)) in the
    # one-pixel-padded frame, here shifted by (border - 1) into the wide frame.
    cx = col.to(torch.float32) + 1.5
    cy = row.to(torch.float32) + 1.5
    origin = frame * (hb * wb) + (border - 1) * (wb + 1)
    step = max(1, chunk_elements // max(1, p))
    for s in range(0, n, step):  # cache-sized chunks of pixels, not a loop over pixels
        e = min(n, s + step)
        inv = invd[s:e, None]
        bx, by, o = cx[s:e, None], cy[s:e, None], origin[s:e, None]
        pu = (uy * inv + by).floor_().mul_(wb).add_((ux * inv + bx).floor_()).to(torch.int64)
        pv = (vy * inv + by).floor_().mul_(wb).add_((vx * inv + bx).floor_()).to(torch.int64)
        du = flat.index_select(0, pu.add_(o).view(-1))
        dv = flat.index_select(0, pv.add_(o).view(-1))
        out[s:e] = (du - dv).view(e - s, p)
    return out
