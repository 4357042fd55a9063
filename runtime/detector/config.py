"""Settings of the 3D pose detector (Wei section 4.2) and of the Shotton joint-proposal baseline."""

from __future__ import annotations

from dataclasses import dataclass

from shared.config import field_doc

__all__ = ["DetectorConfig", "MeanShiftConfig"]


@dataclass
class DetectorConfig:
    """Forest labels -> RANSAC bone fitting -> class centroids -> IK -> tracker refinement."""

    label_smoothing_window: int = field_doc(
        5,
        help="the forest's posteriors are averaged over this box of pixels (odd; 1: off) among "
        "neighbours within label_smoothing_gate_m in depth before the arg-max "
        "(shared.posterior_smoothing): mean per-class accuracy 81.7% against 75.7% on the dev "
        "recordings; the hybrid's label term and arm checks use the same labels",
    )
    label_smoothing_gate_m: float = field_doc(
        0.05, help="depth difference beyond which a neighbour is not averaged in (m)"
    )
    ransac_samples: int = field_doc(
        2500, help="random point pairs drawn per bone (Wei 4.2: 2,500 are 'more than enough')"
    )
    ransac_scored: int = field_doc(
        128,
        help="of the pairs that pass the length test, at most this many are scored by their "
        "inlier count (the rest are redundant; keeps the cost bounded)",
    )
    ransac_points: int = field_doc(
        400, help="inliers are counted on at most this many points per bone (random subset)"
    )
    min_pair_fraction: float = field_doc(
        0.2, help="pairs closer than this fraction of the bone's reach are discarded (Wei: 1/5)"
    )
    inlier_margin_m: float = field_doc(
        0.03,
        help="slack added to the bone's diameter when testing whether a point lies on or "
        "within the sampled bone (sensor noise, model error), metres",
    )
    min_class_pixels: int = field_doc(
        12, help="a class with fewer surviving pixels gives no centroid (missing / occluded)"
    )
    weight_pixels: float = field_doc(
        30.0,
        help="marker confidence n / (n + this) for a class with n surviving pixels: small "
        "visible parts count less in the IK",
    )
    min_person_pixels: int = field_doc(
        150, help="fewer labelled body pixels than this: no person is detected (frame lost)"
    )
    surface_offset: float = field_doc(
        0.785,
        help="a class centroid lies on the visible surface; it is pushed away from the camera by "
        "this fraction of the segment's radius (pi/4: mean depth of a cylinder's visible half)",
    )
    ik_iterations: int = field_doc(15, help="Levenberg-Marquardt iterations of the IK")
    ik_prior: float = field_doc(
        1e-3, help="IK prior weight towards the rest pose, per squared radian (vs squared metres)"
    )
    orientation_starts: int = field_doc(
        4,
        help="IK starts: torso frame from the centroids, the same turned by 180 degrees, "
        "and upright facing / back to the camera (1-4 of these, in that order)",
    )
    arm_starts: int = field_doc(
        2,
        help="arm configurations per orientation start: hanging, raised sideways, raised "
        "overhead (1-3); every start has its own prior reference",
    )
    refine_iterations: int = field_doc(
        3, help="tracker Gauss-Newton iterations refining the IK pose (Wei: three); 0 = none"
    )
    seed: int = field_doc(0, help="seed of the RANSAC sampling (results are deterministic)")


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
