"""Kinect v1 depth sensor model for synthetic training frames, and a simple background scene.

:func:`apply_kinect_noise` turns a clean rendered depth image (metric z, 0 = no surface) into
what a Kinect v1 would deliver: uint16 millimetres with 0 where the sensor has no reading, and
the body-part labels with those pixels set to background (the forest must never be trained on a
pixel without depth). Every effect can be switched off in :class:`KinectNoiseConfig`.

Sensor facts used (Khoshelham & Elberink 2012 and the sensor geometry; DESIGN.md):

- The Kinect v1 is a structured-light stereo pair: an IR projector and an IR camera about
  7.5 cm apart along the camera's x axis. Depth comes from the disparity ``d = f b / z``
  (f: focal length of the native 640x480 IR image, about 580 px; b: the baseline), measured in
  1/8-pixel steps. The depth step is therefore ``dz = z^2 / (8 f b)``, about 2.9e-3 z^2 m
  (1.2 cm at 2 m). The disparity is always computed with the 640-pixel focal length
  (``disparity_focal_px``), whatever the output resolution, because the sensor matches at 640
  and a 320x240 stream is a resampling of that.
- The random error is a roughly constant disparity error, so it grows as z^2 in depth: we draw
  Gaussian noise **in disparity space** with ``sigma_d = k f b`` pixels, which is
  ``sigma_z = k z^2`` metres to first order (k = 1.5e-3 /m: 6 mm at 2 m, 4 cm at 5 m).
- Projector shadows: depth is missing where the projector's pattern does not reach a surface
  that the camera sees. For a Kinect v1 seen from behind (looking where it looks), the projector
  sits to the right of the IR camera, i.e. at +x of the camera frame (image right, unmirrored
  OpenCV convention). Light from the right casts the shadow to the **left** (-u) of a foreground
  object, onto the far surface, in a band ``f b (1/z_near - 1/z_far)`` pixels wide
  (f = the output image's fx here, since this is geometry in output pixels). A stream that is
  mirrored left-right has its shadows on the right: set ``projector_side="left"`` for it.
- Surfaces seen at grazing angles return no pattern: dropped with a probability that rises from
  0 at ``grazing_start_deg`` to 1 at ``grazing_full_deg``.
- Small random holes and ragged silhouettes (edge pixels drop out at random).
- Usable range about 0.8-4 m; readings outside ``[min_depth_m, max_depth_m]`` become 0.

Order in :func:`apply_kinect_noise`: shadows and grazing dropout are decided on the clean
geometry (they are properties of the scene, not of the noisy measurement); then disparity noise
and quantization; then the range limit; then random holes and edge erosion (the edges are found
on the clean depth).

:func:`add_floor_and_background` is a pure helper for the renderer: it fills the background of a
rendered body frame with a floor plane, optionally a back wall and a few boxes standing on the
floor, with proper occlusion (a box in front of the body hides it and its labels become 0).
Call it before :func:`apply_kinect_noise`, so that the body casts its projector shadow onto
the background as it does in real frames.

All functions are numpy only and vectorized (loops run over a few shift steps or boxes, never
over pixels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from shared.camera import Intrinsics
from shared.config import field_doc

__all__ = [
    "level_from_camera",
    "KinectNoiseConfig",
    "BackgroundConfig",
    "BackgroundBox",
    "BackgroundScene",
    "apply_kinect_noise",
    "quantize_depth",
    "add_disparity_noise",
    "projector_shadow_mask",
    "incidence_angle",
    "grazing_dropout_mask",
    "edge_erosion_mask",
    "random_holes_mask",
    "floor_depth",
    "wall_depth",
    "box_depth",
    "random_background_scene",
    "add_floor_and_background",
]

UINT16_MAX_M = 65.535  # largest depth a uint16 millimetre image can hold


@dataclass
class KinectNoiseConfig:
    """Kinect v1 depth sensor model; every effect has its own switch (all off = clean depth
    rounded to millimetres)."""

    quantize: bool = field_doc(True, "quantize disparity to 1/disparity_subpixel_steps px")
    disparity_focal_px: float = field_doc(
        580.0,
        "focal length of the sensor's native 640x480 IR image (px), used for disparity at any "
        "output resolution",
    )
    baseline_m: float = field_doc(0.075, "projector-camera baseline (m)")
    disparity_subpixel_steps: int = field_doc(8, "disparity steps per pixel (Kinect v1: 8)")
    noise: bool = field_doc(True, "add Gaussian disparity noise (sigma_z = noise_k * z^2)")
    noise_k: float = field_doc(
        1.5e-3, "depth noise coefficient (1/m): sigma_z = noise_k * z^2, drawn in disparity"
    )
    noise_correlated_fraction: float = field_doc(
        0.5,
        "fraction of the noise variance drawn at half resolution (2x2 blocks): the sensor's "
        "correlation window makes neighbouring errors similar; 0 = independent pixels",
    )
    shadows: bool = field_doc(True, "drop pixels in the projector's shadow beside depth edges")
    projector_side: Literal["right", "left"] = field_doc(
        "right",
        "side of the camera the projector is on, in the image: 'right' (+x) for an unmirrored "
        "Kinect v1 image, shadows then fall left of foreground objects",
    )
    grazing: bool = field_doc(True, "drop pixels seen at grazing angles")
    grazing_start_deg: float = field_doc(
        75.0, "angle between surface normal and viewing ray where dropout starts (deg)"
    )
    grazing_full_deg: float = field_doc(
        88.0, "angle from which every pixel is dropped (deg); linear probability in between"
    )
    holes: bool = field_doc(True, "punch small random elliptic holes into the depth")
    hole_rate: float = field_doc(3.0, "expected number of holes per 100,000 image pixels")
    hole_radius_px: tuple[float, float] = field_doc(
        (1.0, 4.0), "range of hole semi-axes in pixels at 320 px width (scaled with the width)"
    )
    edge_erosion: bool = field_doc(True, "drop silhouette-edge pixels at random (ragged edges)")
    edge_erosion_prob: float = field_doc(0.3, "probability that an edge pixel is dropped")
    edge_jump_m: float = field_doc(
        0.05, "depth step to a neighbour (m) that makes the nearer pixel an edge pixel"
    )
    range_limit: bool = field_doc(True, "zero readings outside [min_depth_m, max_depth_m]")
    min_depth_m: float = field_doc(0.5, "nearest valid reading (m)")
    max_depth_m: float = field_doc(4.5, "farthest valid reading (m)")

    @classmethod
    def disabled(cls) -> KinectNoiseConfig:
        """Every effect off: the output is the clean depth rounded to millimetres."""
        return cls(
            quantize=False,
            noise=False,
            shadows=False,
            grazing=False,
            holes=False,
            edge_erosion=False,
            range_limit=False,
        )

    def validate(self) -> None:
        """Raise ``ValueError`` on values that make no physical sense."""
        if self.disparity_focal_px <= 0 or self.baseline_m <= 0:
            raise ValueError("disparity_focal_px and baseline_m must be positive")
        if self.disparity_subpixel_steps < 1:
            raise ValueError("disparity_subpixel_steps must be >= 1")
        if self.noise_k < 0 or not 0.0 <= self.noise_correlated_fraction <= 1.0:
            raise ValueError("noise_k must be >= 0 and noise_correlated_fraction in [0, 1]")
        if not 0.0 <= self.grazing_start_deg < self.grazing_full_deg <= 90.0:
            raise ValueError("need 0 <= grazing_start_deg < grazing_full_deg <= 90")
        if self.hole_rate < 0 or not 0 < self.hole_radius_px[0] <= self.hole_radius_px[1]:
            raise ValueError("hole_rate must be >= 0 and 0 < hole_radius_px[0] <= [1]")
        if not 0.0 <= self.edge_erosion_prob <= 1.0 or self.edge_jump_m <= 0:
            raise ValueError("edge_erosion_prob must be in [0, 1] and edge_jump_m > 0")
        if not 0.0 <= self.min_depth_m < self.max_depth_m:
            raise ValueError("need 0 <= min_depth_m < max_depth_m")
        if self.projector_side not in ("right", "left"):
            raise ValueError(f"projector_side must be 'right' or 'left', not {self.projector_side}")


# --------------------------------------------------------------------------------------------
# Disparity: quantization and noise


def quantize_depth(
    depth: np.ndarray, focal_px: float = 580.0, baseline_m: float = 0.075, steps: int = 8
) -> np.ndarray:
    """Depth as the sensor reports it after rounding the disparity to ``1/steps`` pixel.

    Args:
        depth: (H, W) float metres, 0 = no reading.
        focal_px: focal length the disparity is measured with (native 640 px sensor).
    Returns:
        (H, W) float32 metres, 0 where ``depth`` was 0. Step ``z^2 / (steps f b)``.
    """
    z = np.asarray(depth, dtype=np.float32)
    valid = z > 0
    fb = np.float32(focal_px * baseline_m)
    d = fb / np.where(valid, z, np.float32(1.0))
    dq = np.round(d * np.float32(steps)) / np.float32(steps)
    # A disparity that rounds to 0 would mean infinite depth: no reading.
    ok = valid & (dq > 0)
    return np.where(ok, fb / np.where(ok, dq, np.float32(1.0)), np.float32(0.0))


def _correlated_normal(shape: tuple[int, int], fraction: float, rng: np.random.Generator):
    """(H, W) float32 standard normal field: ``fraction`` of the variance shared by 2x2 blocks."""
    h, w = shape
    out = rng.standard_normal(shape, dtype=np.float32)
    if fraction <= 0:
        return out
    coarse = rng.standard_normal(((h + 1) // 2, (w + 1) // 2), dtype=np.float32)
    coarse = np.repeat(np.repeat(coarse, 2, axis=0), 2, axis=1)[:h, :w]
    # Mixing with sqrt weights keeps the per-pixel variance at exactly 1.
    return np.float32(math.sqrt(1.0 - fraction)) * out + np.float32(math.sqrt(fraction)) * coarse


def add_disparity_noise(
    depth: np.ndarray,
    k: float,
    rng: np.random.Generator,
    focal_px: float = 580.0,
    baseline_m: float = 0.075,
    correlated_fraction: float = 0.0,
) -> np.ndarray:
    """Add Gaussian disparity noise with ``sigma_d = k f b`` px, i.e. ``sigma_z ~ k z^2`` m.

    Args:
        depth: (H, W) float metres, 0 = no reading (kept 0).
        k: depth noise coefficient in 1/m.
    Returns:
        (H, W) float32 metres; a disparity pushed to <= 0 (never at Kinect ranges) reads 0.
    """
    z = np.asarray(depth, dtype=np.float32)
    valid = z > 0
    fb = np.float32(focal_px * baseline_m)
    d = fb / np.where(valid, z, np.float32(1.0))
    d = d + np.float32(k * focal_px * baseline_m) * _correlated_normal(
        z.shape, correlated_fraction, rng
    )
    ok = valid & (d > 0)
    return np.where(ok, fb / np.where(ok, d, np.float32(1.0)), np.float32(0.0))


# --------------------------------------------------------------------------------------------
# Missing data from the scene geometry


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


# --------------------------------------------------------------------------------------------
# The full sensor model


def _check_image(depth: np.ndarray, labels: np.ndarray | None, intr: Intrinsics) -> None:
    if depth.ndim != 2 or depth.shape != (intr.height, intr.width):
        raise ValueError(
            f"depth must be (H, W) = ({intr.height}, {intr.width}) for these intrinsics, "
            f"got {depth.shape}"
        )
    if labels is not None and labels.shape != depth.shape:
        raise ValueError(f"labels {labels.shape} must match depth {depth.shape}")


def apply_kinect_noise(
    depth_m: np.ndarray,
    labels: np.ndarray | None,
    intr: Intrinsics,
    cfg: KinectNoiseConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Simulate a Kinect v1 reading of a clean rendered depth image.

    Args:
        depth_m: (H, W) float metric depth (camera z), 0 = background / no surface.
        labels: (H, W) uint8 body-part labels (0 = background) or None.
        intr: intrinsics of the H x W image.
        cfg: which effects to apply and how strongly.
        rng: the only source of randomness (same seed and inputs give the same output).
    Returns:
        depth_mm: (H, W) uint16 millimetres, 0 = no reading.
        labels: (H, W) uint8 copy with every pixel without a reading set to 0 (None if None).
    """
    depth_m = np.asarray(depth_m)
    _check_image(depth_m, labels, intr)
    cfg.validate()
    clean = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, 0.0).astype(np.float32)

    # 1. Missing data decided by the clean scene geometry.
    lost = np.zeros(clean.shape, dtype=bool)
    if cfg.shadows:
        lost |= projector_shadow_mask(clean, intr, cfg.baseline_m, cfg.projector_side)
    if cfg.grazing:
        lost |= grazing_dropout_mask(clean, intr, rng, cfg.grazing_start_deg, cfg.grazing_full_deg)

    # 2. Measurement: noisy, then quantized disparity (the sensor rounds its noisy estimate).
    z = clean
    if cfg.noise and cfg.noise_k > 0:
        z = add_disparity_noise(
            z,
            cfg.noise_k,
            rng,
            cfg.disparity_focal_px,
            cfg.baseline_m,
            cfg.noise_correlated_fraction,
        )
    if cfg.quantize:
        z = quantize_depth(z, cfg.disparity_focal_px, cfg.baseline_m, cfg.disparity_subpixel_steps)

    # 3. Range of the sensor, on the measured value as the firmware does.
    if cfg.range_limit:
        lost |= (z < cfg.min_depth_m) | (z > cfg.max_depth_m)

    # 4. Random holes and ragged silhouettes.
    if cfg.holes and cfg.hole_rate > 0:
        lost |= random_holes_mask(clean.shape, cfg.hole_rate, cfg.hole_radius_px, rng)
    if cfg.edge_erosion and cfg.edge_erosion_prob > 0:
        lost |= edge_erosion_mask(clean, cfg.edge_erosion_prob, cfg.edge_jump_m, rng)

    lost |= z >= UINT16_MAX_M  # not representable in uint16 mm: no reading
    depth_mm = np.where(lost, 0.0, np.rint(z * np.float32(1000.0))).astype(np.uint16)
    out_labels = None
    if labels is not None:
        out_labels = np.where(depth_mm == 0, 0, labels).astype(np.uint8)
    return depth_mm, out_labels


# --------------------------------------------------------------------------------------------
# Floor, wall and boxes behind (or in front of) the rendered body


@dataclass
class BackgroundConfig:
    """Random background scenes for :func:`random_background_scene`."""

    wall_prob: float = field_doc(0.7, "probability that a back wall is present")
    wall_distance_m: tuple[float, float] = field_doc(
        (3.0, 6.0), "range of the wall's horizontal distance from the camera (m)"
    )
    max_boxes: int = field_doc(3, "at most this many boxes (uniform count from 0)")
    box_width_m: tuple[float, float] = field_doc((0.3, 1.2), "box extent along x (m)")
    box_depth_m: tuple[float, float] = field_doc((0.3, 1.0), "box extent along the floor (m)")
    box_height_m: tuple[float, float] = field_doc((0.2, 1.5), "box height above the floor (m)")
    box_x_m: tuple[float, float] = field_doc((-2.5, 2.5), "range of box centres across (m)")
    box_near_m: tuple[float, float] = field_doc(
        (1.0, 5.5), "range of a box's near face distance from the camera (m)"
    )
    max_distance_m: float = field_doc(
        10.0, "background farther than this (camera z, m) is left empty (e.g. floor at horizon)"
    )


@dataclass(frozen=True)
class BackgroundBox:
    """Axis-aligned box standing on the floor, in the level floor frame: the camera frame
    un-pitched (x right, y down, z horizontal forward, origin at the camera)."""

    x_min: float
    x_max: float
    z_min: float
    z_max: float
    height: float


@dataclass(frozen=True)
class BackgroundScene:
    """A background: floor always, an optional back wall (horizontal distance) and boxes."""

    wall_distance: float | None
    boxes: tuple[BackgroundBox, ...] = ()


def _rays(intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Pixel ray components ``r_x`` (1, W) and ``r_y`` (H, 1) of ``r = (r_x, r_y, 1)``; a hit at
    ray parameter t has camera depth z = t."""
    rx = (np.arange(intr.width, dtype=np.float64) - intr.cx) / intr.fx
    ry = (np.arange(intr.height, dtype=np.float64) - intr.cy) / intr.fy
    return rx[None, :], ry[:, None]


def _level_rays(intr: Intrinsics, pitch: float, level_from_camera: np.ndarray | None = None):
    """Pixel rays in the level floor frame, each (H, W): ``p_level = R p_cam`` where the camera
    looks down by ``pitch`` radians (its optical axis is (0, sin, cos) in the level frame), or
    ``R = level_from_camera`` (3, 3) when given (any pitch and roll; see
    :func:`level_from_camera`)."""
    rx, ry = _rays(intr)
    if level_from_camera is None:
        c, s = math.cos(pitch), math.sin(pitch)
        rot = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])
    else:
        rot = np.asarray(level_from_camera, dtype=np.float64)
    shape = (intr.height, intr.width)
    return tuple(
        np.broadcast_to(rot[i, 0] * rx + rot[i, 1] * ry + rot[i, 2], shape) for i in range(3)
    )


def level_from_camera(cam_from_world: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) from a camera frame to its level floor frame, for a y-up world.

    The level frame has y pointing down along world -y, z along the camera's optical axis
    projected on the floor, x = y cross z; camera pitch and roll both end up in it.

    Args:
        cam_from_world: (4, 4) or (3, 3) OpenCV camera pose, ``p_cam = R p_world + t``.
    """
    rot = np.asarray(cam_from_world, dtype=np.float64)[:3, :3]
    forward = rot[2].copy()  # optical axis in world coordinates
    forward[1] = 0.0
    forward /= max(np.linalg.norm(forward), 1e-12)
    down = np.array([0.0, -1.0, 0.0])
    level_from_world = np.stack([np.cross(down, forward), down, forward])
    return level_from_world @ rot.T


def floor_depth(
    intr: Intrinsics, camera_height: float, pitch: float, level_rot: np.ndarray | None = None
) -> np.ndarray:
    """Camera depth of the floor plane ``y_level = camera_height`` (y down), camera pitched down
    by ``pitch`` radians: ``z = h / (cos(pitch) r_y + sin(pitch))``.

    Returns:
        (H, W) float64 metres, ``inf`` where the ray does not reach the floor (above horizon).
    """
    _, dy, _ = _level_rays(intr, pitch, level_rot)
    with np.errstate(divide="ignore"):
        return np.where(dy > 1e-9, camera_height / np.where(dy > 1e-9, dy, 1.0), np.inf)


def wall_depth(
    intr: Intrinsics, pitch: float, distance: float, level_rot: np.ndarray | None = None
) -> np.ndarray:
    """Camera depth of a vertical wall facing the camera at horizontal distance ``distance``.

    Returns:
        (H, W) float64 metres, ``inf`` for rays that never reach it.
    """
    _, _, dz = _level_rays(intr, pitch, level_rot)
    return np.where(dz > 1e-9, distance / np.where(dz > 1e-9, dz, 1.0), np.inf)


def box_depth(
    intr: Intrinsics,
    camera_height: float,
    pitch: float,
    box: BackgroundBox,
    level_rot: np.ndarray | None = None,
):
    """Camera depth of the visible face of one box on the floor (slab ray-box intersection).

    Returns:
        (H, W) float64 metres, ``inf`` where the ray misses the box.
    """
    dirs = _level_rays(intr, pitch, level_rot)
    lows = (box.x_min, camera_height - box.height, box.z_min)
    highs = (box.x_max, camera_height, box.z_max)
    t_near = np.zeros((intr.height, intr.width))
    t_far = np.full((intr.height, intr.width), np.inf)
    for d, lo, hi in zip(dirs, lows, highs):
        # A zero direction component never crosses that slab; a tiny value gives the same
        # +-inf limits without 0/0.
        d = np.where(np.abs(d) < 1e-12, 1e-12, d)
        t0, t1 = lo / d, hi / d
        t_near = np.maximum(t_near, np.minimum(t0, t1))
        t_far = np.minimum(t_far, np.maximum(t0, t1))
    return np.where((t_near <= t_far) & (t_near > 0), t_near, np.inf)


def random_background_scene(rng: np.random.Generator, cfg: BackgroundConfig) -> BackgroundScene:
    """Draw a wall (with ``cfg.wall_prob``) and 0..``cfg.max_boxes`` boxes."""
    wall = None
    if rng.random() < cfg.wall_prob:
        wall = float(rng.uniform(*cfg.wall_distance_m))
    boxes = []
    for _ in range(int(rng.integers(0, cfg.max_boxes + 1))):
        width = rng.uniform(*cfg.box_width_m)
        depth = rng.uniform(*cfg.box_depth_m)
        x = rng.uniform(*cfg.box_x_m)
        z0 = rng.uniform(*cfg.box_near_m)
        boxes.append(
            BackgroundBox(
                float(x - width / 2),
                float(x + width / 2),
                float(z0),
                float(z0 + depth),
                float(rng.uniform(*cfg.box_height_m)),
            )
        )
    return BackgroundScene(wall, tuple(boxes))


def add_floor_and_background(
    depth: np.ndarray,
    labels: np.ndarray | None,
    intr: Intrinsics,
    camera_height: float,
    pitch: float,
    rng: np.random.Generator | None = None,
    cfg: BackgroundConfig | None = None,
    scene: BackgroundScene | None = None,
    level_rot: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Composite a floor, optional back wall and boxes with a rendered body frame.

    The nearer surface wins at every pixel (a z-buffer): the background fills pixels with no
    surface and hides body pixels that lie behind a box (or behind the floor/wall, if the
    body was rendered through them); labels of every background pixel are 0.

    Args:
        depth: (H, W) float metric depth of the body, 0 = nothing rendered.
        labels: (H, W) uint8 body-part labels or None.
        intr: intrinsics of the image.
        camera_height: height of the camera centre above the floor (m).
        pitch: downward tilt of the camera (rad; positive looks down).
        rng: draws the scene when ``scene`` is None.
        cfg: ranges for the random scene (defaults if None).
        scene: a fixed background instead of a random one.
        level_rot: (3, 3) :func:`level_from_camera` of the camera pose; overrides ``pitch``
            and also accounts for roll.
    Returns:
        depth: (H, W) float32 metres; 0 where nothing is within ``cfg.max_distance_m``.
        labels: (H, W) uint8 with background/occluded pixels 0 (None if None).
    """
    depth = np.asarray(depth)
    _check_image(depth, labels, intr)
    cfg = BackgroundConfig() if cfg is None else cfg
    if scene is None:
        if rng is None:
            raise ValueError("give rng (to draw a random scene) or scene")
        scene = random_background_scene(rng, cfg)

    bg = floor_depth(intr, camera_height, pitch, level_rot)
    if scene.wall_distance is not None:
        bg = np.minimum(bg, wall_depth(intr, pitch, scene.wall_distance, level_rot))
    for box in scene.boxes:
        bg = np.minimum(bg, box_depth(intr, camera_height, pitch, box, level_rot))
    bg = np.where(bg <= cfg.max_distance_m, bg, np.inf)

    body = np.where(depth > 0, depth, np.inf)
    use_bg = bg < body
    out = np.where(use_bg, bg, body)
    out = np.where(np.isfinite(out), out, 0.0).astype(np.float32)
    out_labels = None
    if labels is not None:
        out_labels = np.where(use_bg, 0, labels).astype(np.uint8)
    return out, out_labels
