"""Kinect v1 depth sensor model: what a Kinect v1 delivers for a clean rendered depth image.

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

The measurement lives in :mod:`shared.sensor_noise.disparity`, the missing data in
:mod:`shared.sensor_noise.dropout`; this module holds the configuration and the order in which
they are applied.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import field_doc
from depthmocap.shared.sensor_noise.disparity import (
    add_disparity_noise,
    quantize_depth,
    smooth_disparity,
)
from depthmocap.shared.sensor_noise.dropout import (
    edge_erosion_mask,
    grazing_dropout_mask,
    projector_shadow_mask,
    random_holes_mask,
)

__all__ = ["UINT16_MAX_M", "KinectNoiseConfig", "apply_kinect_noise", "check_depth_image"]

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
    correlation_smoothing: bool = field_doc(
        False,
        "smooth disparity as the sensor's correlation window does (small steps on one body "
        "become gradual, as real Kinect v1 depth shows them); off by default",
    )
    correlation_sigma_px: float = field_doc(
        1.3,
        "the window's Gaussian standard deviation in pixels at 320 px width (scaled with the "
        "width): a 9-pixel window of the native 640 x 480 image",
    )
    correlation_gate_m: float = field_doc(
        0.2, "depth steps larger than this (m) keep their edge under the smoothing"
    )
    correlation_noise_gain: float = field_doc(
        3.0,
        "with the smoothing on, the disparity noise is drawn before the window (which makes it "
        "spatially correlated, as real depth's is) and this much larger, so that what is left "
        "after the window is still sigma_z = noise_k * z^2 (3.0 for the default window and "
        "correlated fraction)",
    )
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
        if (
            self.correlation_sigma_px < 0
            or self.correlation_gate_m <= 0
            or self.correlation_noise_gain <= 0
        ):
            raise ValueError(
                "correlation_sigma_px must be >= 0, correlation_gate_m and "
                "correlation_noise_gain > 0"
            )
        if not 0.0 <= self.min_depth_m < self.max_depth_m:
            raise ValueError("need 0 <= min_depth_m < max_depth_m")
        if self.projector_side not in ("right", "left"):
            raise ValueError(f"projector_side must be 'right' or 'left', not {self.projector_side}")


def check_depth_image(depth: np.ndarray, labels: np.ndarray | None, intr: Intrinsics) -> None:
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
    check_depth_image(depth_m, labels, intr)
    cfg.validate()
    clean = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, 0.0).astype(np.float32)

    # 1. Missing data decided by the clean scene geometry.
    lost = np.zeros(clean.shape, dtype=bool)
    if cfg.shadows:
        lost |= projector_shadow_mask(clean, intr, cfg.baseline_m, cfg.projector_side)
    if cfg.grazing:
        lost |= grazing_dropout_mask(clean, intr, rng, cfg.grazing_start_deg, cfg.grazing_full_deg)

    # 2. Measurement: noisy, then quantized disparity (the sensor rounds its noisy estimate).
    # With the correlation window the noise is drawn first: the window averages the matching
    # errors of its pixels along with the surface, so neighbouring errors come out alike.
    z = clean
    window = cfg.correlation_smoothing
    if cfg.noise and cfg.noise_k > 0:
        z = add_disparity_noise(
            z,
            cfg.noise_k * (cfg.correlation_noise_gain if window else 1.0),
            rng,
            cfg.disparity_focal_px,
            cfg.baseline_m,
            cfg.noise_correlated_fraction,
        )
    if window:
        z = smooth_disparity(
            z,
            cfg.correlation_sigma_px * intr.width / 320.0,
            cfg.correlation_gate_m,
            cfg.disparity_focal_px,
            cfg.baseline_m,
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
