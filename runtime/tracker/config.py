"""Settings of the MAP tracker (Wei section 3): resolution, term switches, gates and weights.

Each energy term is a sum of squared, weighted residuals. Weights are the reciprocals of the
noise scales ``sigma_*`` of Wei eq. 9-12, each with its unit stated, so ``residual / sigma`` is
dimensionless. Data terms are sums over working-resolution pixels: when a term subsamples its
pixels for speed, each kept pixel counts for the ones it stands for, so the balance between the
terms does not depend on the sampling caps (it does depend on the working resolution).

Wei's values (1, 100, 0.29, 14.3 for depth, silhouette, extra depth, prior) have no stated
units; the defaults below were tuned on procedural motions rendered from the cylinder model
(clean, and with shared.sensor_noise's Kinect v1 model: 2-4 mm mean joint error) and on a few
anny-body renders, and keep Wei's ordering: the extra depth term weighs a 3D point more than
the depth term weighs a pixel (it acts on few pixels that carry the large corrections), the
prior is weak and settles what the data leave free.

:class:`TrackerConfig` keeps only the knobs worth turning per run (issue 34): the working
resolution (``downsample``, ``person_pixels``), the solver (``iterations``, ``max_step_rad``,
``damping``), the term switches (``use_*``, ``occlusion_handling``), the two correspondence
gates, the noise scales of Wei's terms and of the label term, and when a joint counts as
observed. Everything else is a documented module-level constant next to the code that reads
it, with the value it had as a setting:

- :mod:`runtime.tracker.tracker`: the person window (``CROP_MARGIN``), the distance transform's
  truncation (``SILHOUETTE_MAX_PX``), the stop tests (``STOP_ANGLE_RAD``,
  ``STOP_TRANSLATION_M``, ``STOP_DECREASE``), the prior's prediction (``PRIOR_VELOCITY_GAIN``)
  and the shoulder's branch move (``SHOULDER_BRANCH_TURN_RAD``);
- :mod:`runtime.tracker.depth_term`: ``MAX_DEPTH_PIXELS``, ``MIN_COSINE``;
- :mod:`runtime.tracker.extra_depth_term`: ``MAX_EXTRA_POINTS``, ``MAX_CANDIDATES``,
  ``EXTRA_MARGIN_PX``, ``EXTRA_MAX_DISTANCE_M``, ``SIGMA_EXTRA_TORSO_M``;
- :mod:`runtime.tracker.silhouette_term`: ``MAX_SILHOUETTE_PIXELS``, ``SILHOUETTE_DEADZONE_PX``;
- :mod:`runtime.tracker.label_term`: ``MAX_LABEL_PIXELS``, ``LABEL_GATE_M``;
- :mod:`runtime.tracker.collision_term`: ``SIGMA_COLLISION_M``, ``COLLISION_TOLERANCE_M``,
  ``COLLISION_HAND_TOLERANCE_M``, ``COLLISION_LEG_TOLERANCE_M``;
- :mod:`runtime.tracker.signals`: ``MAX_SURFACE_POINTS``.

The tracker always starts a frame from the previous pose (as Wei does), keeps the joint angles
within :data:`shared.skeleton.DOF_LIMITS`, computes the surface-error quantile, and takes the
failure signals from the last iteration's rendering. :meth:`TrackerConfig.__post_init__` is the
one place the settings are checked.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from depthmocap.shared.config import ConfigError, field_doc

__all__ = ["TrackerConfig", "TrackerConfigError"]


class TrackerConfigError(ConfigError):
    """Tracker settings out of range."""


@dataclass
class TrackerConfig:
    """MAP tracker settings; every term can be switched off for ablations."""

    downsample: int = field_doc(
        0,
        "working resolution = stream resolution / downsample (2: 320x240 -> 160x120); "
        "observed depth is pooled over each block ignoring missing readings. 0: chosen per "
        "frame from the person's size (person_pixels)",
    )
    person_pixels: int = field_doc(
        2500,
        "with downsample 0, the factor (rounded) at which the observed person covers about "
        "this many working pixels: a person far away keeps the stream's resolution, one close "
        "by is pooled",
    )
    iterations: int = field_doc(5, "Gauss-Newton iterations per frame at most (Wei: about 5)")
    damping: float = field_doc(
        1e-3, "Levenberg damping added to the Gauss-Newton diagonal, relative to its mean"
    )
    max_step_rad: float = field_doc(
        0.2,
        "largest joint-angle change of one Gauss-Newton step, radians: longer steps are "
        "shortened along their direction (a trust region; 0 = none). The data terms' "
        "correspondences change as the model moves, so a full step can overshoot into a "
        "wrong basin, and on the dev recordings unlimited steps diverged on a third of the clips",
    )
    # ---------------- term switches ----------------
    use_depth: bool = field_doc(True, "depth image term (Wei eq. 9, 15) over G = R - B1 - B2")
    use_extra_depth: bool = field_doc(
        True, "extra depth term (Wei eq. 10, 17): 3D closest points for pixels in B1, B2, B3"
    )
    use_silhouette: bool = field_doc(
        True, "silhouette term (Wei eq. 11, 16) on the rendered silhouette's boundary"
    )
    use_prior: bool = field_doc(True, "constant-acceleration prior (Wei eq. 12, 18)")
    use_labels: bool = field_doc(
        False,
        "label term (not in Wei; runtime.tracker.label_term): observed pixels the forest "
        "labels as a limb pull that limb's surface; needs the frame's part labels (the hybrid "
        "passes them), otherwise it is skipped",
    )
    label_min_posterior: float = field_doc(
        0.0,
        "the label term reads only the pixels whose label the forest gives at least this "
        "posterior (the arg-max class's, after smoothing): on real depth the forest calls "
        "forearms held in front of the belly belly and puts confident-looking forearm labels "
        "where a hanging forearm would be, and those pull the arm down. 0: every labelled "
        "pixel. Only labels that come with a confidence are gated (the forest's in the "
        "hybrid; a recording's ground-truth labels are not). Off in the shipped preset: 0.4 "
        "gave real depth (UTD-MHAD) 53.5 -> 53.3 mm, frames over 20 cm 19.9 -> 19.1% (jog "
        "in place 39.8 -> 34.3%), and the synthetic tuning sets +0.02 / -0.13 mm with "
        "classes moving 2-7 mm either way (docs/experiments.md, fiftieth session)",
    )
    use_collision: bool = field_doc(
        False,
        "collision term (not in Wei; runtime.tracker.collision_term): points on the arms' "
        "axes deeper than a tolerance inside the torso capsules are pushed out",
    )
    leg_collision: bool = field_doc(
        False,
        "with use_collision, points on each leg's axis (thigh and shank) are kept out of the "
        "other leg's capsules too: the far leg in profile is otherwise laid onto the near one, "
        "where the depth cannot tell them apart (runtime.tracker.collision_term)",
    )
    leg_collision_tolerance_m: float = field_doc(
        0.0,
        "with leg_collision, how deep (m) a leg's axis may lie inside the other leg's capsules "
        "before the term acts: 0 keeps the axes a capsule radius apart (legs pressed together "
        "stay legal), larger values touch only legs laid deep into each other",
    )
    occlusion_handling: bool = field_doc(
        True,
        "Wei's pixel classification: exclude B2 (|depth difference| > gate) from the depth "
        "term and use all four correspondence types; false = naive: depth term on all of "
        "R and O, extra depth term only for B1 and B3 (types 1, 2)",
    )
    # ---------------- gates ----------------
    depth_gate_m: float = field_doc(
        0.08, "B2 threshold: pixels whose rendered/observed depths differ more (m) leave G"
    )
    extra_gate_m: float = field_doc(
        0.15,
        "extra depth correspondences with a larger depth difference are rejected (m). Wei: 8 "
        "cm; at 30 frames/s a kicking foot moves farther than that between frames and then "
        "finds nothing to pull it back (dev recordings, tracker alone: 8 cm 47-54 mm, "
        "15 cm 37.5 mm, 20 cm 42.4 mm)",
    )
    # ---------------- weights (noise scales) ----------------
    sigma_depth_m: float = field_doc(
        0.01,
        "depth term noise scale per working pixel (m); the residual is the depth difference "
        "times the cosine of the viewing angle (distance along the surface normal)",
    )
    sigma_extra_m: float = field_doc(
        0.005, "extra depth term noise scale per correspondence and axis (m)"
    )
    sigma_silhouette_px: float = field_doc(
        1.0,
        "silhouette term noise scale per rendered boundary pixel, in working-resolution "
        "pixels of distance to the observed silhouette",
    )
    sigma_label_m: float = field_doc(
        0.015, "label term noise scale per labelled pixel, distance to its limb's surface (m)"
    )
    sigma_prior_rad: float = field_doc(
        0.05, "prior noise scale of joint angles and root rotation (rad per frame^2)"
    )
    sigma_prior_m: float = field_doc(0.02, "prior noise scale of the root position (m per frame^2)")
    pose_prior_weight: float = field_doc(
        0.0,
        "weight w of the learned pose prior (not in Wei; runtime.tracker.pose_prior_term): "
        "w^2 times the Mahalanobis distance squared of the joint angles to their most likely "
        "mixture component; 0 = off",
    )
    pose_prior_model: str = field_doc(
        "pose_prior.json",
        "the pose prior's file (shared.pose_prior; relative: under the shipped models/)",
    )
    # ---------------- reporting ----------------
    observed_joint_area_cm2: float = field_doc(
        5.0,
        "a named joint is reported observed (not inferred) when at least this much of the "
        "model's surface within its radius is seen and confirmed by the depth image "
        "(runtime.tracker.joint_support; about 5 pixels at 3 m in a 320x240 stream)",
    )

    def __post_init__(self) -> None:
        if self.downsample < 0 or self.person_pixels < 1:
            raise TrackerConfigError(
                f"downsample must be >= 0 (0: automatic) and person_pixels >= 1, got "
                f"{self.downsample}, {self.person_pixels}"
            )
        # The weights are 1 / sigma: zero, negative or NaN scales would divide by zero or
        # silently flip or drop a term.
        scales = {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if f.name.startswith("sigma_")
        }
        bad = {k: v for k, v in scales.items() if not (v > 0 and math.isfinite(v))}
        if not (self.pose_prior_weight >= 0 and math.isfinite(self.pose_prior_weight)):
            bad["pose_prior_weight"] = self.pose_prior_weight
        if not (0.0 <= self.label_min_posterior < 1.0):
            bad["label_min_posterior"] = self.label_min_posterior
        area = self.observed_joint_area_cm2
        if not (area >= 0 and math.isfinite(area)):
            bad["observed_joint_area_cm2"] = area
        leg = self.leg_collision_tolerance_m
        if not (leg >= 0 and math.isfinite(leg)):
            bad["leg_collision_tolerance_m"] = leg
        if bad:
            raise TrackerConfigError(
                f"noise scales must be positive and finite (the observed-joint area, the pose "
                f"prior's weight and the leg collision tolerance may be 0; the label posterior "
                f"gate in [0, 1)), got {bad}"
            )
