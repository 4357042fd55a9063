"""Settings of the MAP tracker (Wei section 3): resolution, term weights and gates, solver.

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
"""

from __future__ import annotations

from dataclasses import dataclass

from shared.config import field_doc

__all__ = ["TrackerConfig"]


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
    crop_margin: float = field_doc(
        0.25,
        "work in a window around the observed silhouette's bounding box, grown on every side "
        "by this fraction of its larger side (and at least silhouette_max_px + 2 working "
        "pixels): model parts outside it are not seen. Negative: the whole image",
    )
    iterations: int = field_doc(5, "Gauss-Newton iterations per frame at most (Wei: about 5)")
    stop_angle_rad: float = field_doc(
        2e-3, "stop when every joint-angle / root-rotation update is below this (rad)"
    )
    stop_translation_m: float = field_doc(
        1e-3, "... and every root-translation update is below this (m)"
    )
    stop_decrease: float = field_doc(
        800.0,
        "... or, from the second step on, when a step's predicted energy decrease dq^T H dq "
        "falls below this (noise scales squared; 0: off). On noisy data the angles the data "
        "hardly see keep moving by degrees per iteration, so the update test alone never "
        "stops; on the dev recordings the first step removes ~20,000, the fifth ~250",
    )
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
    init_from_prediction: bool = field_doc(
        False,
        "start each frame from the constant-velocity prediction 2 q_prev - q_prev2 instead of "
        "q_prev (Wei starts from the previous pose)",
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
    use_collision: bool = field_doc(
        False,
        "collision term (not in Wei; runtime.tracker.collision_term): points on the arms' "
        "axes deeper than collision_tolerance_m inside the torso capsules are pushed out",
    )
    use_limits: bool = field_doc(True, "keep joint angles within shared.skeleton.DOF_LIMITS")
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
    extra_margin_px: int = field_doc(
        1,
        "B1 / B3 pixels within this many working pixels of the other silhouette, and B2 pixels "
        "this close to G, get no extra depth correspondence: there the offset is a "
        "pixel-quantization artefact of an edge that would demand a whole-pixel move for any "
        "sub-pixel misalignment; the depth and silhouette terms align the last pixel",
    )
    extra_max_distance_m: float = field_doc(
        0.3, "extra depth correspondences farther apart in 3D are rejected (m)"
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
    sigma_extra_torso_m: float = field_doc(
        0.04,
        "extra depth term noise scale for correspondences on the torso, neck, head and "
        "clavicles (m). The capsule torso matches a real one's shape only roughly (an anny "
        "body's silhouette is covered to 0.75-0.8): at full weight, closest points on the "
        "unmatched chest and back turned the chest against the pelvis in near-profile views, "
        "the lower back's twist to its 50 degree limit and the far shoulder 25-35 cm off "
        "(docs/experiments.md). The limbs keep sigma_extra_m: theirs carry the large corrections",
    )
    sigma_silhouette_px: float = field_doc(
        1.0,
        "silhouette term noise scale per rendered boundary pixel, in working-resolution "
        "pixels of distance to the observed silhouette",
    )
    sigma_label_m: float = field_doc(
        0.015, "label term noise scale per labelled pixel, distance to its limb's surface (m)"
    )
    label_gate_m: float = field_doc(
        0.15,
        "labelled pixels farther than this from their limb's surface are ignored (m): a "
        "left/right swap of the forest must not drag a limb across the body",
    )
    sigma_collision_m: float = field_doc(
        0.001,
        "collision term noise scale per arm sample point, depth beyond the tolerance (m); "
        "strong: a hidden arm has no data to hold it, and the forest's arm labels on the "
        "torso pull it in (at 5 mm arm axes still lay 3-5 cm inside)",
    )
    collision_tolerance_m: float = field_doc(
        0.02,
        "arm axis points may lie this deep inside the torso capsules before the collision "
        "term acts (m): the capsules only approximate the body (ground-truth poses: upper arm "
        "axis at most 1.1 cm inside on the 39 dev takes)",
    )
    collision_hand_tolerance_m: float = field_doc(
        0.04,
        "the same for the hand half of each forearm (m): hands rest on the hips and the belly "
        "(ground truth: the wrist up to 3.4 cm inside in 1% of the 39 dev takes' frames)",
    )
    sigma_prior_rad: float = field_doc(
        0.05, "prior noise scale of joint angles and root rotation (rad per frame^2)"
    )
    sigma_prior_m: float = field_doc(0.02, "prior noise scale of the root position (m per frame^2)")
    prior_velocity_gain: float = field_doc(
        1.0,
        "prediction q_prev + gain (q_prev - q_prev2) the prior pulls towards: 1 = Wei's "
        "constant velocity, 0 = the previous pose",
    )
    shoulder_branch_turn_rad: float = field_doc(
        0.7,
        "before each frame a shoulder pinned at its limits moves to its other Euler form when "
        "that turns the upper arm by less than this (rad; 0: never), see "
        "runtime/tracker/shoulder_branch.py",
    )
    # ---------------- sampling caps (speed) ----------------
    max_depth_pixels: int = field_doc(
        1200, "depth term: at most this many G pixels per iteration (strided subsample)"
    )
    max_extra_points: int = field_doc(
        400, "extra depth term: at most this many query pixels per iteration"
    )
    max_candidates: int = field_doc(
        1500, "closest-point candidates per side (observed / rendered) at most"
    )
    max_label_pixels: int = field_doc(
        300, "label term pixels per frame at most (a fixed-lattice subsample of the limbs')"
    )
    max_silhouette_pixels: int = field_doc(
        600, "silhouette term: at most this many rendered boundary pixels per iteration"
    )
    silhouette_deadzone_px: float = field_doc(
        0.5,
        "silhouette residual = distance to the observed silhouette minus this (working px, "
        ">= 0): pixel-centre distances overstate the distance to the boundary between pixels",
    )
    silhouette_max_px: float = field_doc(
        10.0, "distance transform of the observed silhouette is truncated here (working px)"
    )
    min_cosine: float = field_doc(
        0.2, "depth term ignores pixels seen at grazing angles (|cos| below this)"
    )
    exact_signals: bool = field_doc(
        False,
        "ray-cast once more at the result for the failure signals when the last step did not "
        "converge; false: use the last iteration's rendering (one Gauss-Newton step before the "
        "result), about 15% faster",
    )
    surface_error: bool = field_doc(
        True, "compute the 97% surface-error quantile (Helten IV) of each frame's result"
    )
    max_surface_points: int = field_doc(
        600, "observed points used for the surface-error quantile at most"
    )
    observed_joint_area_cm2: float = field_doc(
        5.0,
        "a named joint is reported observed (not inferred) when at least this much of the "
        "model's surface within its radius is seen and confirmed by the depth image "
        "(runtime.tracker.joint_support; about 5 pixels at 3 m in a 320x240 stream)",
    )
