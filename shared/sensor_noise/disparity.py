"""Kinect v1 depth measurement: disparity quantization and disparity-space noise.

The sensor measures disparity ``d = f b / z`` in ``1/8`` pixel steps with a roughly constant
random error, so both the depth step and the depth noise grow as ``z^2`` (the facts and their
sources: :mod:`shared.sensor_noise.kinect`). It finds that disparity by correlating a window of
the projected speckle pattern (about 9 x 9 pixels of the native 640 x 480 image), so what it
reports is a local average: a forearm a few centimetres in front of the belly comes out as a
smooth bump rather than a step (:func:`smooth_disparity`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["add_disparity_noise", "quantize_depth", "smooth_disparity"]


def _to_disparity(z: np.ndarray, fb: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """(disparity ``f b / z`` in px, where ``z`` is a reading); no reading gives ``f b``."""
    valid = z > 0
    return fb / np.where(valid, z, np.float32(1.0)), valid


def _to_depth(d: np.ndarray, ok: np.ndarray, fb: np.float32) -> np.ndarray:
    """Depth ``f b / d`` where ``ok``, 0 (no reading) elsewhere."""
    return np.where(ok, fb / np.where(ok, d, np.float32(1.0)), np.float32(0.0))


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
    fb = np.float32(focal_px * baseline_m)
    d, valid = _to_disparity(np.asarray(depth, dtype=np.float32), fb)
    dq = np.round(d * np.float32(steps)) / np.float32(steps)
    # A disparity that rounds to 0 would mean infinite depth: no reading.
    return _to_depth(dq, valid & (dq > 0), fb)


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
    fb = np.float32(focal_px * baseline_m)
    d, valid = _to_disparity(z, fb)
    d = d + np.float32(k * focal_px * baseline_m) * _correlated_normal(
        z.shape, correlated_fraction, rng
    )
    return _to_depth(d, valid & (d > 0), fb)


def smooth_disparity(
    depth: np.ndarray,
    sigma_px: float,
    gate_m: float,
    focal_px: float = 580.0,
    baseline_m: float = 0.075,
) -> np.ndarray:
    """Depth as a correlation window reports it: each pixel's disparity the Gaussian-weighted
    mean of its neighbours' whose depth is within ``gate_m`` of its own.

    Small steps on one body (an arm laid on the belly, the gap between touching legs) are
    smoothed over a few pixels, as real Kinect v1 depth shows them; larger ones (the person
    against the wall, a hand held well forward) keep their edge, where the sensor reports no
    blend but the nearer surface or nothing.

    Args:
        depth: (H, W) float metres, 0 = no reading (kept 0 and never averaged in).
        sigma_px: the window's Gaussian standard deviation in pixels (0: unchanged).
        gate_m: neighbours further in depth than this are left out (m).
    Returns:
        (H, W) float32 metres.
    Raises:
        ValueError: a negative ``sigma_px`` or a gate of 0 or less (nothing would be taken).
    """
    if not (sigma_px >= 0 and gate_m > 0):
        raise ValueError(f"need sigma_px >= 0 and gate_m > 0, got {sigma_px} and {gate_m}")
    z = np.asarray(depth, dtype=np.float32)
    if sigma_px == 0:
        return z.copy()
    fb = np.float32(focal_px * baseline_m)
    d, valid = _to_disparity(z, fb)
    r = int(math.ceil(2.5 * sigma_px))
    h, w = z.shape
    zp, dp = np.pad(z, r), np.pad(d, r)  # padding reads 0: no reading, never taken
    num = np.zeros_like(d)
    den = np.zeros_like(d)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            g = np.float32(math.exp(-(dy * dy + dx * dx) / (2.0 * sigma_px * sigma_px)))
            rows, cols = slice(r + dy, r + dy + h), slice(r + dx, r + dx + w)
            zn = zp[rows, cols]
            take = (zn > 0) & (np.abs(zn - z) <= gate_m)  # a neighbour without reading: never
            num += np.where(take, g * dp[rows, cols], 0.0)
            den += np.where(take, g, 0.0)
    # The centre always takes itself, so every valid pixel has den > 0.
    return _to_depth(num / np.where(valid, den, np.float32(1.0)), valid, fb)
