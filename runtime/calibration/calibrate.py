"""Automatic skeleton calibration (Wei section 6): bone lengths and radii from a reference pose.

The person holds the reference pose, a T-pose facing the camera (arms raised sideways to the
horizontal, elbows straight, legs a little apart): every limb is seen from the side over its
whole length and no limb covers another. Per labelled frame, every bone's cylinder is fitted
by RANSAC with Wei's score Q = N_in - N_out (:mod:`.cylinder_ransac`).

What a cylinder fit measures is the bone's *visible* extent and radius, which differ from the
joint-to-joint length in ways fixed by the body's geometry (a forearm's pixels include the hand,
the top of a thigh hides behind the pelvis, a clavicle shows only above the chest). These
biases scale with the body, so the same measurement is run on the template body ray-cast in
the same pose (:func:`runtime.raycast.render_body`, exact labels) and the body is scaled per
bone by the ratio of the two: ``length = template_length * measured / measured_on_template``,
likewise the radii. Left and right bones are averaged (Wei: symmetric skeletons). The torso's
elliptic sections keep the template's aspect ratio (its depth is not seen from the front): the
lateral semi-axis is measured, the other scaled with it, and so do the sections' offsets from
the joint axis. Extents (hands, feet, the pelvis below the hips) scale with their segment;
the pelvis's radius and the hip width with the abdomen's and chest's radii (the thighs cover
the sides of the pelvis; the distance between the thigh axes' upper ends is the fallback);
the clavicles, mostly hidden inside the chest, with the distance between the upper arm
axes' inner ends (the shoulders). Bones too hidden to measure take the median scale of the
others. With several frames, each measurement is the median over the frames.

On real (mesh) bodies the per-bone ratios carry errors of their own: a labelled part's
boundaries are not at the skeleton's joint centres (on anny bodies the abdomen came out 12 cm
off, the forearms 9 cm), and Wei's per-bone lengths were 4.9 cm off on average against 3.4 cm
for the unscaled template. ``length_scale="consensus"`` (the default) scales every length by
the median of the per-bone ratios instead (2.9 cm); ``"per_bone"`` is Wei's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import FOOT_SEGMENTS, BodyShape
from depthmocap.shared.camera import Intrinsics, depth_to_points
from depthmocap.shared.config import field_doc
from depthmocap.shared.kinematics import rest_pose
from depthmocap.shared.labels import PART_SEGMENT

from .cylinder_ransac import fit_cylinder

__all__ = [
    "CalibrationConfig",
    "CalibrationError",
    "reference_pose",
    "measure_bones",
    "calibrate_body",
    "SYMMETRIC_PAIRS",
]

SYMMETRIC_PAIRS = ((5, 6), (7, 8), (9, 10), (11, 12), (13, 14))
_TORSO = (0, 1, 2)
_D = {n: i for i, n in enumerate(sk.DOF_NAMES)}


class CalibrationError(ValueError):
    """Calibration impossible with the given frames (no person, pose not held, ...)."""


@dataclass
class CalibrationConfig:
    """Skeleton calibration settings."""

    samples: int = field_doc(1024, help="RANSAC samples (radius + pixel pair) per bone")
    max_pixels: int = field_doc(4000, help="image pixels scored per bone at most (strided)")
    min_pixels: int = field_doc(25, help="a bone with fewer labelled pixels is not measured")
    radius_range: tuple[float, float] = field_doc(
        (0.5, 1.8), help="radii sampled, as factors of the template's radius (low, high)"
    )
    arm_abduction_deg: float = field_doc(90.0, help="reference pose: arms raised sideways")
    leg_abduction_deg: float = field_doc(12.0, help="reference pose: legs apart")
    pose_tolerance_deg: float = field_doc(
        25.0, help="a pose is the reference pose when every arm / leg angle is this close"
    )
    facing_tolerance_deg: float = field_doc(
        35.0, help="... and the body faces the camera within this angle"
    )
    hold_frames: int = field_doc(
        10, help="automatic mode: frames the reference pose must be held (consecutively)"
    )
    check_refine_iterations: int = field_doc(
        8,
        help="automatic mode: tracker iterations refining each detection of the pose check "
        "(Wei refines tracking detections with 3; a small, far person's limb directions need "
        "more to fall within pose_tolerance_deg)",
    )
    hold_misses: int = field_doc(
        2,
        help="automatic mode: a hold survives this many frames in a row whose detection "
        "misses the pose (a glitch of the detector, not the person moving); they are not used",
    )
    seed: int = field_doc(0, help="seed of the RANSAC sampling")
    length_scale: str = field_doc(
        "consensus",
        help="'per_bone': each length by its own measured ratio (Wei); 'consensus': every "
        "length by the median ratio (the per-bone ratios' own errors exceed the "
        "proportions they would capture on mesh bodies, see the module docstring)",
    )

    def __post_init__(self) -> None:
        if self.length_scale not in ("per_bone", "consensus"):
            raise ValueError(
                f"length_scale must be 'per_bone' or 'consensus', got {self.length_scale!r}"
            )


def reference_pose(
    cfg: CalibrationConfig | None = None,
    root_position=(0.0, 0.0, 2.5),
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """The reference pose (T-pose facing the camera) at ``root_position``: (34,)."""
    cfg = cfg or CalibrationConfig()
    q = rest_pose(1, root_position, dtype=dtype)[0]
    for s in ("l", "r"):
        q[_D[f"{s}_humerus_abd"]] = math.radians(cfg.arm_abduction_deg)
        q[_D[f"{s}_femur_abd"]] = math.radians(cfg.leg_abduction_deg)
    return q


def _bone_masks(labels: torch.Tensor) -> torch.Tensor:
    """(H, W) part labels -> (15, H, W) bool pixels of each bone (segment)."""
    seg = torch.as_tensor(PART_SEGMENT, device=labels.device)[labels.long().clamp(0, 19)]
    return seg[None] == torch.arange(sk.NUM_SEGMENTS, device=labels.device)[:, None, None]


def measure_bones(
    depth_m: torch.Tensor,
    labels: torch.Tensor,
    intr: Intrinsics,
    template: BodyShape,
    cfg: CalibrationConfig | None = None,
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Visible length and radius of every bone in one labelled frame.

    Returns:
        lengths (15,), radii (15,) metres (NaN where not measured), and gaps (2,): half the
        distance between the inner ends of the two thigh axes (hip width) and of the two upper
        arm axes (shoulder width); NaN where a limb is missing.
    """
    cfg = cfg or CalibrationConfig()
    gen = generator or torch.Generator().manual_seed(cfg.seed)
    depth = depth_m.to(torch.float64)
    masks = _bone_masks(labels.to(depth.device))
    r_t = template.radii.double().amax(-1)
    lengths = torch.full((sk.NUM_SEGMENTS,), math.nan, dtype=torch.float64)
    radii = lengths.clone()
    # Torso axis: from the pelvis pixels' centroid to the chest pixels' centroid.
    pts = depth_to_points(depth[None], intr)[0]
    ok = depth > 0

    def centroid(m):
        m = m & ok
        return pts[m].mean(0) if int(m.sum()) > 0 else None

    lo, hi = centroid(masks[0] | masks[1]), centroid(masks[2])
    torso_axis = None if lo is None or hi is None else hi - lo
    ends = {}
    for k in range(sk.NUM_SEGMENTS):  # one vectorized RANSAC per bone
        axis = torso_axis if k in _TORSO else None
        if k in _TORSO and axis is None:
            continue
        rr = (cfg.radius_range[0] * float(r_t[k]), cfg.radius_range[1] * float(r_t[k]))
        mask = masks[k]
        if k in FOOT_SEGMENTS and int((mask & ok).sum()) > 0:
            # The foot points at the camera in the reference pose: its pixels lie well in
            # front of the shank's and would tilt the shank's cylinder towards the toes.
            front = depth[mask & ok].median() - 1.5 * r_t[k]
            mask = mask & ~(ok & (depth < front))
        fit = fit_cylinder(
            depth, mask, intr, rr, cfg.samples, cfg.max_pixels, cfg.min_pixels, gen, axis
        )
        if fit.found:
            lengths[k], radii[k] = fit.length, fit.radius
            ends[k] = (fit.start, fit.end)
    gaps = torch.full((2,), math.nan, dtype=torch.float64)
    centre = hi if hi is not None else lo
    for i, (a, b) in enumerate(((11, 12), (7, 8))):
        if a in ends and b in ends and centre is not None:
            # Inner end of each axis: the one nearer the chest centroid (hips, shoulders).
            inner = [min(ends[k], key=lambda p: float((p - centre).norm())) for k in (a, b)]
            gaps[i] = 0.5 * float((inner[0] - inner[1]).norm())
    return lengths, radii, gaps


def _template_measurement(template, intr, cfg, root_z, gen):
    from depthmocap.runtime.raycast import part_labels, render_body

    q = reference_pose(cfg, (0.0, 0.0, root_z), torch.float64)
    body = template.to(dtype=torch.float64)
    r = render_body(q[None], body, intr)
    return measure_bones(r.depth[0], part_labels(r, body)[0], intr, template, cfg, gen)


def _first_finite(*candidates: torch.Tensor) -> torch.Tensor:
    """The first finite one of scalar ``candidates`` (the last if none is)."""
    out = candidates[-1]
    for c in reversed(candidates[:-1]):
        out = torch.where(torch.isfinite(c), c, out)
    return out


def calibrate_body(
    frames: list[torch.Tensor],
    labels: list[torch.Tensor],
    intr: Intrinsics,
    template: BodyShape | None = None,
    cfg: CalibrationConfig | None = None,
) -> BodyShape:
    """Body of the person holding the reference pose in ``frames`` (module docstring).

    Args:
        frames: depth images (H, W) in metres (0 = no reading), the person in the reference pose.
        labels: their (H, W) part labels (forest or ground truth; 0 = background).
        intr: intrinsics; template: body whose proportions fill in (default: average adult).
        cfg: settings.
    Raises:
        CalibrationError: no frame, or no bone measurable.
    """
    cfg = cfg or CalibrationConfig()
    template = (template or BodyShape.default()).to(dtype=torch.float64, device="cpu")
    if not frames or len(frames) != len(labels):
        raise CalibrationError("calibration needs at least one depth frame with its labels")
    gen = torch.Generator().manual_seed(cfg.seed)
    meas = [
        measure_bones(d.cpu(), lab.cpu(), intr, template, cfg, gen)
        for d, lab in zip(frames, labels)
    ]
    lengths = torch.stack([m[0] for m in meas]).nanmedian(0).values
    radii = torch.stack([m[1] for m in meas]).nanmedian(0).values
    gap = torch.stack([m[2] for m in meas]).nanmedian(0).values
    if bool(torch.isnan(lengths).all()):
        raise CalibrationError("no bone could be measured (is a person in the reference pose?)")
    depths = torch.cat([d.cpu()[(d.cpu() > 0) & (lab.cpu() > 0)] for d, lab in zip(frames, labels)])
    root_z = float(depths.double().median()) if depths.numel() else 2.5
    t_len, t_rad, t_gap = _template_measurement(template, intr, cfg, root_z, gen)

    len_scale = lengths / t_len
    rad_scale = radii / t_rad
    # The clavicles hide inside the chest: their length follows the shoulder width instead.
    clavicle = gap[1] / t_gap[1]
    if bool(torch.isfinite(clavicle)):
        len_scale[5] = len_scale[6] = clavicle
    for a, b in SYMMETRIC_PAIRS:  # symmetric skeleton: average left and right
        for s in (len_scale, rad_scale):
            s[a] = s[b] = torch.stack([s[a], s[b]]).nanmean()
    overall = len_scale[torch.isfinite(len_scale)].median()
    len_scale = torch.where(torch.isfinite(len_scale), len_scale, overall)
    if cfg.length_scale == "consensus":
        len_scale = overall.expand_as(len_scale)
    # The hips follow the abdomen's and chest's width: the pelvis's own pixels (a short, wide
    # section whose sides the thighs' tops cover) and the gap between the thigh axes measure
    # them badly on mesh bodies (ten dev bodies: pelvis radius 6.9 cm, hip half-width 1.9 cm
    # too small on average; from the torso's width 1.1 and 0.6 cm off).
    torso = rad_scale[1:3].nanmean()
    hip_scale = _first_finite(torso, gap[0] / t_gap[0], rad_scale[0], overall)
    rad_scale[0] = _first_finite(torso, rad_scale[0], overall)
    rad_scale = torch.where(torch.isfinite(rad_scale), rad_scale, overall)
    shank = FOOT_SEGMENTS[0]
    return BodyShape(
        template.lengths * len_scale,
        template.radii * rad_scale[:, None],
        template.extents * len_scale[:, None],
        template.hip_half_width * hip_scale,
        # Section centres sit off the joint axis (the belly in front of the spine) by amounts
        # a front view cannot measure: the template's, scaled with the section.
        template.offsets * rad_scale[:, None],
        template.feet * torch.stack([len_scale[shank], rad_scale[shank]]),
        chest_tilt=template.chest_tilt,
        clavicle_rest=template.clavicle_rest,  # the T-pose lifts the shoulders: cannot show it
    ).to(dtype=torch.float32)
