"""Kinect v1 missing data decided by the scene: projector shadows, grazing angles, random holes
and ragged silhouettes (the facts and their sources: :mod:`shared.sensor_noise.kinect`).

Every function returns a boolean mask of lost readings; loops run over a few shift steps,
never over pixels.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from depthmocap.shared.camera import Intrinsics

__all__ = [
    "edge_erosion_mask",
    "grazing_dropout_mask",
    "incidence_angle",
    "projector_shadow_mask",
    "random_holes_mask",
]


def projector_shadow_mask(
    depth: np.ndarray,
    intr: Intrinsics,
    baseline_m: float = 0.075,
    projector_side: Literal["right", "left"] = "right",
    gap_fill_px: float = 3.0,
) -> np.ndarray:
    """Pixels that the camera sees but the projector does not light.

    With the projector at +x (``"right"``) and rectified rows, a surface point at column u and
    depth z lies on projector column ``s = u - f b / z`` (up to a constant). Each visible pixel
    covers the projector columns ``[s - 1/2, s + 1/2]``, widened to meet its right-hand
    neighbour when both lie on one surface (``|ds| <= gap_fill_px``). A pixel is in shadow when a
    nearer pixel to its right covers its projector column: at a simple edge this is a band of
    ``round(f b (1/z_near - 1/z_far))`` pixels left of the foreground, and a thin foreground
    object (narrower than that band) casts a correspondingly narrow shadow.

    Args:
        depth: (H, W) clean metric depth, 0 = no surface.
        intr: intrinsics of the image (``fx`` converts the baseline to pixels).
        projector_side: "right" (+x, unmirrored Kinect v1) or "left" (mirrored image).
    Returns:
        (H, W) bool, True where the pixel is shadowed (only ever on pixels with depth > 0).
    """
    z = np.asarray(depth, dtype=np.float32)
    if projector_side == "left":
        # Mirror, solve the "right" case, mirror back (s uses column differences only).
        return projector_shadow_mask(z[:, ::-1], intr, baseline_m, "right", gap_fill_px)[:, ::-1]
    h, w = z.shape
    valid = z > 0
    fb = np.float32(intr.fx * baseline_m)
    cols = np.arange(w, dtype=np.float32)
    s = np.where(valid, cols - fb / np.where(valid, z, np.float32(1.0)), np.float32(np.nan))

    # Coverage interval of each pixel in projector columns; background covers nothing.
    half = np.float32(0.5)
    lo = np.where(valid, s - half, np.inf).astype(np.float32)
    hi = np.where(valid, s + half, -np.inf).astype(np.float32)
    ds = s[:, 1:] - s[:, :-1]
    joined = np.abs(ds) <= gap_fill_px  # NaN (background) compares False
    right = s[:, 1:]
    lo[:, :-1] = np.where(joined, np.minimum(lo[:, :-1], right + half), lo[:, :-1])
    hi[:, :-1] = np.where(joined, np.maximum(hi[:, :-1], right - half), hi[:, :-1])

    # Cheap necessary condition first: something to the right must start at or before s.
    lo_right = np.full_like(lo, np.inf)
    lo_right[:, :-1] = np.minimum.accumulate(lo[:, :0:-1], axis=1)[:, ::-1]
    cand = np.flatnonzero(valid & (lo_right <= s))
    mask = np.zeros(h * w, dtype=bool)
    if cand.size == 0:
        return mask.reshape(h, w)

    # Exact test on the few candidates, one shift at a time. The widest possible band sets the
    # number of shifts (a handful of pixels for a body in front of a wall).
    zv = z[valid]
    max_shift = int(math.ceil(float(fb) * (1.0 / zv.min() - 1.0 / zv.max()) + 1.0 + gap_fill_px))
    max_shift = min(max_shift, w - 1)
    zf, lof, hif, sf = z.ravel(), lo.ravel(), hi.ravel(), s.ravel()
    col = cand % w
    s_c, z_c = sf[cand], zf[cand]
    hit = np.zeros(cand.size, dtype=bool)
    for k in range(1, max_shift + 1):
        inrow = col + k < w
        j = np.where(inrow, cand + k, cand)
        hit |= inrow & (zf[j] > 0) & (zf[j] < z_c) & (lof[j] <= s_c) & (s_c <= hif[j])
    mask[cand[hit]] = True
    return mask.reshape(h, w)


def _min_abs_gradient(z: np.ndarray) -> np.ndarray:
    """Per-pixel one-sided difference ``dz/du`` along rows, the side of smaller magnitude,
    ignoring neighbours without a reading: at a depth edge this takes the side on the same
    surface, so silhouettes do not look like grazing surfaces. 0 where neither neighbour has a
    reading. (Use ``_min_abs_gradient(z.T).T`` for columns.)"""
    zn = np.where(z > 0, z, np.float32(np.nan))
    diff = zn[:, 1:] - zn[:, :-1]  # NaN next to a missing reading
    mag = np.abs(diff)
    mag[np.isnan(mag)] = np.inf
    g = np.zeros(z.shape, dtype=np.float32)
    g_mag = np.full(z.shape, np.inf, dtype=np.float32)
    g[:, 1:] = diff  # backward difference z[i] - z[i-1] ...
    g_mag[:, 1:] = mag
    use_fwd = mag < g_mag[:, :-1]  # ... unless the forward one z[i+1] - z[i] is smaller
    g[:, :-1][use_fwd] = diff[use_fwd]
    g[np.isnan(g)] = 0.0
    return g


def _incidence_cos(z: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """(H, W) float32 cosine of the incidence angle (see :func:`incidence_angle`); 1 where
    ``z`` is 0."""
    h, w = z.shape
    a = np.float32(intr.fx) * _min_abs_gradient(z)
    b = np.float32(intr.fy) * _min_abs_gradient(z.T).T
    rx = ((np.arange(w, dtype=np.float32) - np.float32(intr.cx)) / np.float32(intr.fx))[None, :]
    ry = ((np.arange(h, dtype=np.float32) - np.float32(intr.cy)) / np.float32(intr.fy))[:, None]
    nz = a * rx + b * ry + z
    n_norm = np.sqrt(a * a + b * b + nz * nz)
    r_norm = np.sqrt(rx * rx + ry * ry + np.float32(1.0))
    cos = np.where(z > 0, z / np.maximum(n_norm * r_norm, np.float32(1e-12)), np.float32(1.0))
    return np.clip(cos, np.float32(0.0), np.float32(1.0))


def incidence_angle(depth: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Angle between the surface normal (from the depth gradient) and the viewing ray.

    For ``P = z r`` with ``r = ((u-cx)/fx, (v-cy)/fy, 1)``, the normal ``dP/du x dP/dv`` is
    parallel to ``(-a, -b, a r_x + b r_y + z)`` with ``a = fx dz/du``, ``b = fy dz/dv``, and its
    dot product with ``r`` is ``z``, so ``cos = z / (|n| |r|)`` elementwise, no 3-vectors needed.
    The depth derivatives are one-sided (the smoother side), so a depth edge does not make
    its pixels look grazing.

    Args:
        depth: (H, W) clean metric depth, 0 = no surface.
    Returns:
        (H, W) float32 radians in [0, pi/2]; 0 where depth is 0.
    """
    z = np.asarray(depth, dtype=np.float32)
    return np.arccos(_incidence_cos(z, intr))


def grazing_dropout_mask(
    depth: np.ndarray,
    intr: Intrinsics,
    rng: np.random.Generator,
    start_deg: float = 75.0,
    full_deg: float = 88.0,
) -> np.ndarray:
    """Drop pixels seen at grazing angles: probability 0 below ``start_deg``, rising linearly to
    1 at ``full_deg``.

    Args:
        depth: (H, W) clean metric depth, 0 = no surface.
    Returns:
        (H, W) bool, True where the reading is lost.
    """
    cos = _incidence_cos(np.asarray(depth, dtype=np.float32), intr).ravel()
    mask = cos <= math.cos(math.radians(full_deg))
    # Angles and random numbers only for the (few) pixels with a partial probability.
    part = np.flatnonzero(~mask & (cos < math.cos(math.radians(start_deg))))
    if part.size:
        ang = np.degrees(np.arccos(cos[part]))
        mask[part] = rng.random(part.size) < (ang - start_deg) / (full_deg - start_deg)
    return mask.reshape(np.shape(depth))


def edge_erosion_mask(
    depth: np.ndarray, prob: float, jump_m: float, rng: np.random.Generator
) -> np.ndarray:
    """Randomly drop silhouette pixels: pixels with a reading whose 4-neighbour has none or is
    farther by more than ``jump_m`` (the near side of a depth edge), each with ``prob``.

    Returns:
        (H, W) bool, True where the reading is lost.
    """
    z = np.asarray(depth, dtype=np.float32)
    # Treat no-reading neighbours as infinitely far so they count as an edge.
    far = np.where(z > 0, z, np.float32(1e6))  # finite: avoids inf - inf warnings
    edge = np.zeros(z.shape, dtype=bool)
    edge[:, :-1] |= far[:, 1:] - far[:, :-1] > jump_m
    edge[:, 1:] |= far[:, :-1] - far[:, 1:] > jump_m
    edge[:-1, :] |= far[1:, :] - far[:-1, :] > jump_m
    edge[1:, :] |= far[:-1, :] - far[1:, :] > jump_m
    edge &= z > 0
    idx = np.flatnonzero(edge)
    mask = np.zeros(z.size, dtype=bool)
    mask[idx[rng.random(idx.size) < prob]] = True
    return mask.reshape(z.shape)


def random_holes_mask(
    shape: tuple[int, int],
    rate_per_100k: float,
    radius_px: tuple[float, float],
    rng: np.random.Generator,
) -> np.ndarray:
    """Small axis-aligned elliptic blobs of missing data at random places.

    The count is Poisson with mean ``rate_per_100k * H * W / 1e5``; semi-axes are uniform in
    ``radius_px`` (given for 320 px width, scaled by ``W / 320``).

    Returns:
        (H, W) bool, True inside a hole.
    """
    h, w = shape
    mask = np.zeros(shape, dtype=bool)
    n = int(rng.poisson(rate_per_100k * h * w / 1e5))
    if n == 0:
        return mask
    scale = w / 320.0
    r = rng.uniform(radius_px[0] * scale, radius_px[1] * scale, size=(n, 2))  # (n, [ry, rx])
    cy = rng.uniform(0, h, size=n)
    cx = rng.uniform(0, w, size=n)
    rmax = int(math.ceil(r.max()))
    off = np.arange(-rmax, rmax + 1)
    dy, dx = np.meshgrid(off, off, indexing="ij")
    dy, dx = dy.ravel()[None, :], dx.ravel()[None, :]  # (1, K)
    yy = np.floor(cy)[:, None].astype(np.int64) + dy  # (n, K)
    xx = np.floor(cx)[:, None].astype(np.int64) + dx
    inside = (dy / r[:, :1]) ** 2 + (dx / r[:, 1:]) ** 2 <= 1.0
    inside &= (yy >= 0) & (yy < h) & (xx >= 0) & (xx < w)
    mask[yy[inside], xx[inside]] = True
    return mask
