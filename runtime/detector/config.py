"""Settings of the 3D pose detector (Wei section 4.2) and of the Shotton joint-proposal baseline."""

from __future__ import annotations

from dataclasses import dataclass

from depthmocap.shared.config import ConfigError, field_doc

__all__ = ["DetectorConfig", "MeanShiftConfig"]


@dataclass
class DetectorConfig:
    """Forest labels -> RANSAC bone fitting -> class centroids -> IK -> tracker refinement.

    The pipeline's fixed choices (RANSAC scoring caps, inlier margin, centroid offset and
    weights, IK iterations, prior and starts) are documented constants in
    :mod:`runtime.detector.detect`; these are the knobs an experiment turns.
    """

    label_smoothing_window: int = field_doc(
        5,
        help="the forest's posteriors are averaged over this box of pixels (odd; 1: off) among "
        "neighbours within 5 cm in depth before the arg-max (shared.posterior_smoothing): "
        "mean per-class accuracy 81.7% against 75.7% on the dev recordings; the hybrid's "
        "label term and arm checks use the same labels",
    )
    ransac_samples: int = field_doc(
        2500, help="random point pairs drawn per bone (Wei 4.2: 2,500 are 'more than enough')"
    )
    min_person_pixels: int = field_doc(
        150, help="fewer labelled body pixels than this: no person is detected (frame lost)"
    )
    refine_iterations: int = field_doc(
        3, help="tracker Gauss-Newton iterations refining the IK pose (Wei: three); 0 = none"
    )
    reset_limbs: str = field_doc(
        "limbs",
        help="more refinement starts: the IK pose with one limb set back to its rest angles "
        "(a straight leg, a hanging arm), for each leg ('legs') or each limb ('limbs'), the "
        "best fit of all starts kept; the forest can label another part as a hidden limb (a "
        "forearm as the far shank in a side view) and the IK then bends that limb to reach "
        "it. 'none': the four limb swaps only (Wei). Tuning sets: 42.6 -> 40.5 mm and 42.4 "
        "-> 41.3 mm (docs/experiments.md, twenty-fifth session)",
    )
    seed: int = field_doc(0, help="seed of the RANSAC sampling (results are deterministic)")

    def __post_init__(self) -> None:
        # The smoothing window is checked where it is used (shared.posterior_smoothing).
        if not (self.ransac_samples >= 1 and self.min_person_pixels >= 1):
            raise ConfigError(
                f"detector: ransac_samples and min_person_pixels must be >= 1, got "
                f"{self.ransac_samples}, {self.min_person_pixels}"
            )
        if self.reset_limbs not in ("none", "legs", "limbs"):
            raise ConfigError(
                f"detector: reset_limbs must be none, legs or limbs, got {self.reset_limbs!r}"
            )
        if self.refine_iterations < 0:
            raise ConfigError(
                f"detector: refine_iterations must be >= 0, got {self.refine_iterations}"
            )


@dataclass
class MeanShiftConfig:
    """Shotton et al. 2011 joint proposals: weighted mean shift on per-class posteriors."""

    bandwidth_m: float = field_doc(
        0.065, help="Gaussian kernel bandwidth b of the density estimator, metres (Shotton 0.065)"
    )
    probability_threshold: float = field_doc(
        0.14, help="pixels whose joint score is above this start mean shift (Shotton lambda_c)"
    )
    max_points: int = field_doc(2000, help="pixels entering the density estimate at most")
    max_seeds: int = field_doc(32, help="mean-shift starting points per joint at most")
    iterations: int = field_doc(12, help="mean-shift iterations")
    boundary_window_px: int = field_doc(
        7,
        help="joints between two parts are scored on the parts' boundary: the geometric mean "
        "of both parts' posteriors box-filtered over this window (pixels)",
    )
    z_offset: float = field_doc(
        0.785,
        help="the strongest mode lies on the surface; it is pushed back by this fraction of "
        "the segment radius (Shotton learns zeta_c per part; fixed here from the body model)",
    )
    min_weight: float = field_doc(
        1e-3, help="joints whose best mode gathers less score mass than this are missing (NaN)"
    )
