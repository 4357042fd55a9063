"""The broad dev protocol (issue 37), version 1: the frozen set of dev recordings that accuracy
is judged on, with performers, bodies and cameras the system was not tuned on.

The ten-recording dev set (:mod:`train.evaluation.dev_recordings`' default) has one body per
clip and a frontal camera; the system was tuned on it. This protocol renders **every dev take
of the tracked motion classes** (``all_dev_clips``: 40 HDM05 takes of the dev actor, ten
classes) **three times**, each time with another body and another camera:

- **Bodies** (:func:`variant_phenotype`), stratified so that the three of a take differ: one
  short, one medium, one tall (thirds of each sex's height range); both sexes in every take
  (female, male, female or male, female, male in alternate takes); one slim, one average, one
  heavy (rotating with the take). Over six takes every (sex, height, weight) cell occurs once.
  Within a cell the values are uniform draws: anny height in ``female_height`` /
  ``male_height`` (statures about 1.47-1.75 m and 1.62-1.94 m), weight in ``slim_weight`` /
  ``average_weight`` / ``heavy_weight`` with muscle in ``muscle`` (a high muscle value hides
  the weight), adult age, near-pure sex, any proportions.
- **Cameras** (:func:`place_camera`): each take gets a frontal view (person yaw within
  ``frontal_yaw_max_deg``), a side view (yaw ``side_yaw_deg``, either side) and a third view
  that cycles (by the take's position in its class) through feet cut, arm cut, frontal and
  side. Camera heights and nominal distances are stratified draws over the whole protocol
  (Latin hypercube: one per equal stratum, shuffled). Uncut views see the whole motion: the
  camera moves, from its nominal distance, to the nearest distance (5 cm steps, within
  ``distance``, 1.5-4.5 m) at which every vertex (every 20th, as for training frames) stays
  in the image, ``margin_px`` from its border, and within the Kinect v1's 4.5 m range; a
  variant with no such distance tries the other camera heights (0.1 m steps, nearest first),
  then other yaws of its sector (5 degree steps, nearest first), and is skipped (listed in the
  manifest) when none works. Cut views leave part of the person out of the image: *feet*: a
  near camera (1.5-2 m) whose image top passes just over the head and whose bottom edge
  crosses the person's axis at ``feet_cut_height`` above the floor (moved back only as far as
  the person's width needs; a motion wider than any such view, a jog in a circle, is cut at
  the sides too); *arm*: the uncut camera panned so that one image border (left or right)
  lies ``arm_cut_border`` beyond the trunk's (head, neck, shoulders, torso) outermost point
  on that side in the median frame: the arm on that side is cut whenever it reaches out, and
  more of the person when they move towards that border.
- **Frames**: the first ``max_frames`` (90) frames of each take at 30 fps (the takes are
  16-161 frames long): 6,816 frames for 120 variants before skips; the calibration T-pose
  recordings add ``calibration_frames`` (30) per body.

Everything is a pure function of :class:`BroadProtocolConfig` (and its ``seed``) and the clip
names: :func:`protocol_variants` gives the same variants on every machine. What was rendered
(the camera's actual distance, height and yaw read back from the recording, the body's
stature, how much of the person the image cut: the share of frames with a ground-truth joint
outside the image and, per joint, the share of frames it is outside) goes into each
recording's ``protocol.json`` and the output folder's ``manifest.json``. Changing anything
here makes a new protocol version: bump :data:`PROTOCOL_VERSION` and say so in
``docs/protocol.md``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from depthmocap.shared.camera import Intrinsics, points_to_pixels
from depthmocap.shared.config import ConfigError, config_to_dict, field_doc, save_config
from depthmocap.shared.labels import PART_NAMES

if TYPE_CHECKING:
    from depthmocap.train.bodies.anny_body import AnnyBody
    from depthmocap.train.synth.frame import PlacedBody
    from depthmocap.train.synth.viewpoints import Viewpoints

__all__ = [
    "PROTOCOL_VERSION",
    "VIEWS",
    "CUTS",
    "BroadProtocolConfig",
    "Variant",
    "motion_class",
    "protocol_variants",
    "variant_phenotype",
    "body_stature",
    "camera_at",
    "place_camera",
    "recorded_camera",
    "render_protocol",
    "variant_record",
    "write_manifest",
    "joints_outside",
    "load_manifest",
    "manifest_groups",
]

PROTOCOL_VERSION = 1
VIEWS = ("frontal", "side")
CUTS = ("none", "feet", "arm")
# The third camera of a take, cycled by the take's position in its class (shifted by class).
THIRD_CAMERAS = (("frontal", "feet"), ("frontal", "arm"), ("frontal", "none"), ("side", "none"))
HEIGHT_CLASSES = ("short", "medium", "tall")
_TRUNK_PARTS = [PART_NAMES.index(p) for p in ("pelvis", "abdomen", "chest", "neck", "head",
                                              "l_clavicle", "r_clavicle")]  # fmt: skip
WEIGHT_CLASSES = ("slim", "average", "heavy")


@dataclass
class BroadProtocolConfig:
    """The broad dev protocol's spec (module docstring). Its defaults are version 1: the
    preset ``configs/dev_broad.yaml`` repeats them and a test keeps the two equal."""

    version: int = field_doc(PROTOCOL_VERSION, "protocol version these settings define")
    seed: int = field_doc(37, "seed of every draw (bodies, cameras, scenes, sensor noise)")
    bodies_per_take: int = field_doc(3, "recordings (bodies and cameras) per dev take")
    max_frames: int = field_doc(90, "frames per recording: the take's first ones at 30 fps")
    calibration_frames: int = field_doc(30, "frames of each body's calibration T-pose recording")
    width: int = field_doc(320, "depth image width (Kinect v1 intrinsics, 4:3)")
    female_height: tuple[float, float] = field_doc(
        (0.23, 0.50), "anny height range of the female bodies (statures about 1.47-1.75 m)"
    )
    male_height: tuple[float, float] = field_doc(
        (0.26, 0.56), "anny height range of the male bodies (statures about 1.62-1.94 m)"
    )
    slim_weight: tuple[float, float] = field_doc((0.05, 0.25), "anny weight of slim bodies")
    average_weight: tuple[float, float] = field_doc((0.4, 0.6), "anny weight of average bodies")
    heavy_weight: tuple[float, float] = field_doc((0.75, 0.95), "anny weight of heavy bodies")
    muscle: tuple[float, float] = field_doc(
        (0.2, 0.6), "anny muscle range (above about 0.7 the weight hardly shows)"
    )
    age: tuple[float, float] = field_doc((0.70, 0.92), "anny age range (adults, about 17-80)")
    sex_purity: float = field_doc(
        0.1, "largest distance of anny gender from pure female (1) or male (0)"
    )
    distance: tuple[float, float] = field_doc(
        (1.5, 4.5), "camera distance range from the person's axis, m (Kinect v1: up to 4.5)"
    )
    uncut_nominal_distance: tuple[float, float] = field_doc(
        (2.0, 4.5), "range of the uncut views' nominal distances (moved until all is seen)"
    )
    arm_cut_nominal_distance: tuple[float, float] = field_doc(
        (2.0, 3.5), "range of the arm-cut views' nominal distances"
    )
    camera_height: tuple[float, float] = field_doc(
        (0.6, 2.0), "camera height above the floor, m (a shelf to above a TV)"
    )
    frontal_yaw_max_deg: float = field_doc(
        30.0, "frontal and cut views: person yaw within +- this (0 = facing the camera)"
    )
    side_yaw_deg: tuple[float, float] = field_doc(
        (45.0, 90.0), "side views: |person yaw| in this range, either side"
    )
    roll_max_deg: float = field_doc(3.0, "camera roll about its optical axis, +- degrees")
    feet_cut_height: tuple[float, float] = field_doc(
        (0.1, 0.35), "feet cuts: height above the floor where the image's bottom edge crosses "
        "the person's axis, m"
    )  # fmt: skip
    arm_cut_border: tuple[float, float] = field_doc(
        (-0.04, 0.1), "arm cuts: distance of the image's side border beyond the trunk's "
        "(head, neck, shoulders, torso) outermost point on that side in the median frame, m"
    )  # fmt: skip
    margin_px: float = field_doc(2.0, "uncut views: every vertex this far inside the image")

    def validate(self) -> None:
        """Raise :class:`ConfigError` on a version this code does not render or bad ranges."""
        if self.version != PROTOCOL_VERSION:
            raise ConfigError(
                f"protocol version {self.version}: this code renders version {PROTOCOL_VERSION}"
            )
        if self.bodies_per_take < 3 or self.max_frames < 1 or self.calibration_frames < 1:
            raise ConfigError("need bodies_per_take >= 3, max_frames >= 1, calibration_frames >= 1")
        for name in ("female_height", "male_height", "slim_weight", "average_weight",
                     "heavy_weight", "muscle", "age", "distance", "uncut_nominal_distance",
                     "arm_cut_nominal_distance", "camera_height", "side_yaw_deg",
                     "feet_cut_height", "arm_cut_border"):  # fmt: skip
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ConfigError(f"{name}: need low <= high, got {lo}, {hi}")
        lo, hi = self.distance
        if not (0.5 < lo and hi <= 4.5):
            raise ConfigError(f"distance {self.distance}: the Kinect v1 sees 0.5-4.5 m")


@dataclass(frozen=True)
class Variant:
    """One recording of the protocol: a take, a body and a camera (all fixed before render)."""

    name: str  # recording folder: the take's stem and "_b<slot>"
    clip: str  # the .amc file name
    motion_class: str
    take_index: int  # position of the take in the sorted list of takes
    slot: int  # 0 .. bodies_per_take - 1
    seed: int  # render_sequence's seed (scene, sensor noise)
    sex: str  # "female" or "male"
    height_class: str
    weight_class: str
    phenotype: dict
    view: str  # "frontal" or "side"
    cut: str  # "none", "feet" or "arm"
    yaw_deg: float  # person yaw relative to the camera (0: facing it; +: camera at their left)
    camera_height_m: float
    nominal_distance_m: float  # uncut and arm cuts: where the search starts; feet: unused
    roll_deg: float
    cut_amount_m: float  # feet: cut height above the floor; arm: border offset; none: 0
    cut_side: str  # arm cuts: "left" or "right" image border; else ""


def motion_class(clip: str) -> str:
    """HDM05 motion class of a take's name: ``HDM_mm_squat1Reps_037_120.amc`` -> squat1Reps."""
    parts = Path(clip).stem.split("_")
    if len(parts) < 5 or parts[0] != "HDM":
        raise ValueError(f"{clip}: not an HDM05 take name (HDM_<actor>_<class>_<take>_<fps>)")
    return "_".join(parts[2:-2])


def _stratified(rng: np.random.Generator, n: int, lo: float, hi: float) -> np.ndarray:
    """``n`` values in [lo, hi], one uniform draw in each of ``n`` equal strata, shuffled."""
    return lo + (hi - lo) * (rng.permutation(n) + rng.random(n)) / max(n, 1)


def variant_phenotype(
    cfg: BroadProtocolConfig, sex: str, height_class: str, weight_class: str, u: np.ndarray
) -> dict[str, float]:
    """The anny phenotype of one body: ``u`` holds six uniform [0, 1) numbers."""
    purity = cfg.sex_purity * u[0]
    lo, hi = cfg.female_height if sex == "female" else cfg.male_height
    third = (hi - lo) / 3.0
    k = HEIGHT_CLASSES.index(height_class)
    weight = getattr(cfg, f"{weight_class}_weight")
    return {
        "gender": float(1.0 - purity if sex == "female" else purity),
        "age": float(cfg.age[0] + (cfg.age[1] - cfg.age[0]) * u[1]),
        "muscle": float(cfg.muscle[0] + (cfg.muscle[1] - cfg.muscle[0]) * u[2]),
        "weight": float(weight[0] + (weight[1] - weight[0]) * u[3]),
        "height": float(lo + third * (k + u[4])),
        "proportions": float(u[5]),
    }


def protocol_variants(cfg: BroadProtocolConfig, clips: list[str]) -> list[Variant]:
    """Every recording of the protocol for the sorted take names ``clips`` (module docstring).

    A pure function of ``cfg`` and ``clips``.
    """
    cfg.validate()
    clips = sorted(clips)
    rng = np.random.default_rng([cfg.seed, cfg.version, 37])
    classes = sorted({motion_class(c) for c in clips})
    n_slots = cfg.bodies_per_take
    # Cameras: frontal, side, then the cycled third; more slots continue the cycle.
    cameras = []
    seen_in_class: dict[str, int] = {}
    for clip in clips:
        cls = motion_class(clip)
        i = seen_in_class.get(cls, 0)
        seen_in_class[cls] = i + 1
        extra = [THIRD_CAMERAS[(classes.index(cls) + i + j) % len(THIRD_CAMERAS)]
                 for j in range(n_slots - 2)]  # fmt: skip
        take = [("frontal", "none"), ("side", "none"), *extra]
        cameras.append([take[j] for j in rng.permutation(n_slots)])
    flat = [cam for take in cameras for cam in take]
    n = len(flat)
    heights = _stratified(rng, n, *cfg.camera_height)
    rolls = rng.uniform(-cfg.roll_max_deg, cfg.roll_max_deg, n)
    signs = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    right = rng.random(n) < 0.5
    body_u = rng.random((n, 6))
    # Distances and yaws: stratified within each kind of camera.
    nominal = np.zeros(n)
    yaw = np.zeros(n)
    amount = np.zeros(n)
    for kind in sorted(set(flat)):
        idx = np.array([i for i, c in enumerate(flat) if c == kind])
        view, cut = kind
        span = cfg.arm_cut_nominal_distance if cut == "arm" else cfg.uncut_nominal_distance
        nominal[idx] = _stratified(rng, len(idx), *span) if cut != "feet" else 0.0
        yaw[idx] = (
            _stratified(rng, len(idx), *cfg.side_yaw_deg)
            if view == "side"
            else _stratified(rng, len(idx), 0.0, cfg.frontal_yaw_max_deg)
        )
        if cut != "none":
            span = cfg.feet_cut_height if cut == "feet" else cfg.arm_cut_border
            amount[idx] = _stratified(rng, len(idx), *span)
    out = []
    for t, clip in enumerate(clips):
        # Both sexes in every take; heights short/medium/tall; weights rotate with the take.
        sexes = ("female", "male") if t % 2 == 0 else ("male", "female")
        for s in range(n_slots):
            i = t * n_slots + s
            sex = sexes[s % 2]
            height_class = HEIGHT_CLASSES[s % 3]
            weight_class = WEIGHT_CLASSES[(s + t) % 3]
            view, cut = flat[i]
            out.append(
                Variant(
                    name=f"{Path(clip).stem}_b{s}",
                    clip=clip,
                    motion_class=motion_class(clip),
                    take_index=t,
                    slot=s,
                    seed=cfg.seed * 100_000 + t * 100 + s,
                    sex=sex,
                    height_class=height_class,
                    weight_class=weight_class,
                    phenotype=variant_phenotype(cfg, sex, height_class, weight_class, body_u[i]),
                    view=view,
                    cut=cut,
                    yaw_deg=round(float(signs[i] * yaw[i]), 3),
                    camera_height_m=round(float(heights[i]), 4),
                    nominal_distance_m=round(float(nominal[i]), 4),
                    roll_deg=round(float(rolls[i]), 3),
                    cut_amount_m=round(float(amount[i]), 4),
                    cut_side=("right" if right[i] else "left") if cut == "arm" else "",
                )
            )
    return out


# ---------------------------------------------------------------------------------------------
# Cameras


def camera_at(
    distance: float,
    height: float,
    yaw_deg: float,
    target_height: float,
    roll_deg: float = 0.0,
    pan_rad: float = 0.0,
) -> Viewpoints:
    """The camera ``distance`` m from the person's axis (world origin) at ``height``, seeing
    the person at ``yaw_deg`` (:mod:`train.synth.viewpoints`), looking at the axis point
    ``target_height`` above the floor, then panned about its own y axis by ``pan_rad``
    (positive: the person moves towards the image's right) and rolled."""
    from depthmocap.train.mocap.clip import axis_rotation
    from depthmocap.train.synth.viewpoints import Viewpoints, look_at

    psi = math.radians(yaw_deg)
    position = np.array([[distance * math.sin(psi), height, distance * math.cos(psi)]])
    cam = look_at(position, np.array([0.0, target_height, 0.0]))
    # Turning the camera by +pan about its own y axis moves what it sees to the right.
    turn = axis_rotation("z", np.array([math.radians(roll_deg)])) @ axis_rotation(
        "y", np.array([pan_rad])
    )
    cam[:, :3, :] = turn @ cam[:, :3, :]
    return Viewpoints(
        cam, position, np.array([distance]), np.array([height]), np.array([psi]),
        np.array([math.radians(roll_deg)]),
    )  # fmt: skip


def _project(cam: np.ndarray, points: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, ...]:
    """Pixel u, v and depth z of world ``points`` (P, 3) seen by ``cam`` (4, 4)."""
    import torch

    p = points @ cam[:3, :3].T + cam[:3, 3]
    z = p[:, 2]
    uv = points_to_pixels(torch.as_tensor(np.where(z[:, None] > 0.05, p, 1.0)), intr).numpy()
    return uv[:, 0], uv[:, 1], z


def _inside(
    cam: np.ndarray, points: np.ndarray, intr: Intrinsics, margin: float, max_depth: float,
    rows: bool = True, cols: bool = True,
) -> bool:  # fmt: skip
    u, v, z = _project(cam, points, intr)
    ok = (z > 0.5) & (z < max_depth)
    if cols:
        ok &= (u >= margin - 0.5) & (u <= intr.width - 0.5 - margin)
    if rows:
        ok &= (v >= margin - 0.5) & (v <= intr.height - 0.5 - margin)
    return bool(ok.all())


def _half_fov(intr: Intrinsics) -> tuple[float, float]:
    """Half the horizontal and vertical field of view, radians."""
    return math.atan((intr.cx + 0.5) / intr.fx), math.atan((intr.cy + 0.5) / intr.fy)


def _feet_cut_distance(height: float, top: float, cut: float, half_v: float) -> float | None:
    """Horizontal distance at which a camera at ``height`` whose view spans 2 ``half_v``
    vertically sees the person's axis from ``cut`` to ``top`` above the floor; None if none."""

    def spread(d: float) -> float:
        return math.atan2(height - cut, d) - math.atan2(height - top, d)

    lo, hi = 0.05, 20.0
    if height > top:  # a camera above the head: the spread peaks at sqrt(a b)
        lo = math.sqrt((height - cut) * (height - top))
    if spread(lo) < 2 * half_v or spread(hi) > 2 * half_v:
        return None
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if spread(mid) > 2 * half_v else (lo, mid)
    return 0.5 * (lo + hi)


def _yaws(variant: Variant, cfg: BroadProtocolConfig) -> list[float]:
    """The variant's yaw, then 5 degree steps of its view's sector, nearest first."""
    if variant.view == "side":
        lo, hi = cfg.side_yaw_deg
        grid = np.concatenate([np.arange(lo, hi + 1e-9, 5.0), -np.arange(lo, hi + 1e-9, 5.0)])
    else:
        top = cfg.frontal_yaw_max_deg
        grid = np.arange(-top, top + 1e-9, 5.0)
    return [variant.yaw_deg, *grid[np.argsort(np.abs(grid - variant.yaw_deg), kind="stable")]]


def place_camera(
    variant: Variant,
    cfg: BroadProtocolConfig,
    placed: PlacedBody,
    body: AnnyBody,
    intr: Intrinsics,
    max_depth: float,
) -> Viewpoints:
    """The camera of ``variant`` for the posed motion ``placed`` (module docstring).

    Raises:
        OutOfRangeError: no distance within ``cfg.distance`` shows what the variant needs
            within ``max_depth``.
    """
    from depthmocap.train.synth.sequence import OutOfRangeError

    hull = placed.vertices[:, ::20].reshape(-1, 3)
    target = float(np.median(placed.q[:, 1]))
    h, yaw, roll = variant.camera_height_m, variant.yaw_deg, variant.roll_deg
    lo, hi = cfg.distance
    steps = np.round(np.arange(lo, hi + 1e-9, 0.05), 4)
    half_h, half_v = _half_fov(intr)
    if variant.cut == "feet":
        head = placed.vertices[:, body.labels == PART_NAMES.index("head")]
        top = float(head[..., 1].max()) + 0.05
        d = _feet_cut_distance(h, top, variant.cut_amount_m, half_v)
        d = max(lo, d if d is not None else lo)
        # Aim so that the image's top edge passes over the head; move back (less cut) only as
        # far as the person's width needs.
        # A motion wider than any such view (a jog in a circle) is cut at the sides too: the
        # nearest distance that keeps it within the sensor's range.
        for cols in (True, False):
            for dist in steps[steps >= d - 1e-9]:
                pitch = math.atan2(h - top, dist) + half_v  # downwards, radians
                cam = camera_at(dist, h, yaw, h - dist * math.tan(pitch), roll)
                if _inside(cam.cam_from_world[0], hull, intr, 0.0, max_depth, False, cols):
                    return cam
        raise OutOfRangeError(f"{variant.name}: no feet-cut camera keeps it within range")
    order = steps[np.argsort(np.abs(steps - variant.nominal_distance_m), kind="stable")]
    # The variant's camera height and yaw first; when no distance shows the motion from
    # there, the nearest height (0.1 m steps within camera_height), then the nearest yaw
    # (5 degree steps within the view's sector) that does.
    grid = np.round(np.arange(cfg.camera_height[0], cfg.camera_height[1] + 1e-9, 0.1), 4)
    heights = [h, *grid[np.argsort(np.abs(grid - h), kind="stable")]]
    for yaw, h, dist in ((y, a, b) for y in _yaws(variant, cfg) for a in heights for b in order):
        cam = camera_at(float(dist), h, yaw, target, roll)
        if variant.cut == "arm":
            if not _inside(cam.cam_from_world[0], hull, intr, cfg.margin_px, max_depth, cols=False):
                continue
            # Pan so that the side border lies cut_amount_m beyond the trunk's outermost
            # point on that side in the median frame (a pan adds to every horizontal angle).
            trunk = placed.vertices[:, np.isin(body.labels, _TRUNK_PARTS)][:, ::10]
            p = trunk @ cam.cam_from_world[0, :3, :3].T + cam.cam_from_world[0, :3, 3]
            angle = np.arctan2(p[..., 0], p[..., 2])  # (F, P)
            gap = math.atan2(variant.cut_amount_m, float(dist))
            if variant.cut_side == "right":
                pan = half_h - float(np.median(angle.max(1))) - gap
            else:
                pan = -half_h - float(np.median(angle.min(1))) + gap
            return camera_at(float(dist), h, yaw, target, roll, pan)
        if _inside(cam.cam_from_world[0], hull, intr, cfg.margin_px, max_depth):
            return cam
    raise OutOfRangeError(
        f"{variant.name}: no camera at {lo}-{hi} m (any height) keeps the whole motion in "
        f"view within {max_depth} m"
    )


def recorded_camera(cam_from_world: np.ndarray) -> dict[str, float]:
    """Distance from the person's axis, height and person yaw of a recording's camera."""
    rot, t = cam_from_world[:3, :3], cam_from_world[:3, 3]
    c = -rot.T @ t
    return {
        "distance_m": round(float(math.hypot(c[0], c[2])), 3),
        "camera_height_m": round(float(c[1]), 3),
        "yaw_deg": round(math.degrees(math.atan2(c[0], c[2])), 2),
    }


def joints_outside(joints_cam: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """(F, J) bool: which ground-truth joints (camera frame) project outside the image."""
    import torch

    f, j, _ = joints_cam.shape
    p = joints_cam.reshape(-1, 3).astype(np.float64)
    z = p[:, 2]
    uv = points_to_pixels(torch.as_tensor(np.where(z[:, None] > 0.05, p, 1.0)), intr).numpy()
    inside = (
        (z > 0.05)
        & (uv[:, 0] >= -0.5)
        & (uv[:, 0] <= intr.width - 0.5)
        & (uv[:, 1] >= -0.5)
        & (uv[:, 1] <= intr.height - 0.5)
    )
    return ~inside.reshape(f, j)


# ---------------------------------------------------------------------------------------------
# Manifest


def variant_record(variant: Variant, recording: Path) -> dict:
    """What ``recording`` (rendered for ``variant``) holds: the variant, the camera read back
    from its ground truth, the body's stature, and how much the image cut."""
    from depthmocap.shared import skeleton as sk
    from depthmocap.shared.recording import Recording

    rec = Recording(recording)
    gt = np.load(recording / "groundtruth.npz")
    out = joints_outside(gt["joints"], rec.intrinsics)
    names = list(sk.JOINT_NAMES)
    record = asdict(variant)
    record["frames"] = int(gt["joints"].shape[0])
    record["stature_m"] = body_stature(variant.phenotype)
    record["camera"] = recorded_camera(gt["cam_from_world"])
    record["frames_cut_pct"] = round(100.0 * float(out.any(1).mean()), 2)
    record["joints_cut_pct"] = round(100.0 * float(out.mean()), 2)
    record["joints_cut"] = {
        n: round(100.0 * float(out[:, i].mean()), 1) for i, n in enumerate(names) if out[:, i].any()
    }
    return record


def body_stature(phenotype: dict[str, float]) -> float:
    """Standing height of the anny body of ``phenotype`` (its rest pose's vertical extent), m."""
    from depthmocap.train.bodies.anny_body import make_body

    return round(float(np.ptp(make_body(phenotype).vertices[:, 1])), 3)


def load_manifest(folder: str | Path) -> dict:
    """``manifest.json`` of a protocol folder, checked for this code's protocol version."""
    path = Path(folder) / "manifest.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no protocol manifest (run make dev-protocol)")
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not valid JSON ({err})") from None
    version = manifest.get("version") if isinstance(manifest, dict) else None
    if version != PROTOCOL_VERSION or not isinstance(manifest.get("recordings"), list):
        raise ValueError(
            f"{path}: protocol version {version!r}; this code reads version {PROTOCOL_VERSION}"
        )
    return manifest


def manifest_groups(manifest: dict) -> dict[str, dict[str, str]]:
    """Groupings of the recordings for the per-group tables: name -> {recording: group}."""
    recs = manifest["recordings"]
    return {
        "motion class": {r["name"]: r["motion_class"] for r in recs},
        "camera": {r["name"]: r["view"] for r in recs},
        "cut": {r["name"]: "uncut" if r["cut"] == "none" else f"cut ({r['cut']})" for r in recs},
        "body": {r["name"]: f"{r['sex']}, {r['height_class']}" for r in recs},
    }


def write_manifest(
    folder: Path, cfg: BroadProtocolConfig, records: list[dict], skipped: list[dict]
) -> Path:
    """Write ``manifest.json``: the spec, every recording's record and the skipped variants."""
    manifest = {
        "protocol": "broad",
        "version": PROTOCOL_VERSION,
        "config": config_to_dict(cfg),
        "frames": sum(r["frames"] for r in records),
        "recordings": records,
        "skipped": skipped,
    }
    path = folder / "manifest.json"
    path.write_text(json.dumps(manifest, indent=1))
    return path


def render_protocol(
    cfg: BroadProtocolConfig,
    clips_folder: Path,
    out: Path,
    calibration_out: Path | None,
    count: int | None = None,
) -> Path:
    """Render the protocol's recordings into ``out`` (and each body's calibration T-pose into
    ``calibration_out``), skipping recordings already there; writes ``manifest.json``.

    ``count``: only the first ``count`` variants (a partial protocol, for trying it out).
    """
    from depthmocap.train.evaluation.dev_recordings import all_dev_clips
    from depthmocap.train.synth.sequence import OutOfRangeError, render_sequence

    variants = protocol_variants(cfg, all_dev_clips(clips_folder))[:count]
    out.mkdir(parents=True, exist_ok=True)
    save_config(cfg, out / "protocol.yaml")
    records, skipped = [], []
    for i, v in enumerate(variants):
        rec = out / v.name
        done = rec / "protocol.json"
        if not (done.is_file() and (rec / "groundtruth.npz").is_file()):
            try:
                render_sequence(
                    str(clips_folder / v.clip), rec, frames=cfg.max_frames, seed=v.seed,
                    width=cfg.width, overwrite=True, require_in_range=True,
                    phenotype=v.phenotype,
                    camera=lambda placed, body, intr, far, v=v: place_camera(
                        v, cfg, placed, body, intr, far
                    ),
                )  # fmt: skip
            except OutOfRangeError as err:
                skipped.append({**asdict(v), "reason": str(err)})
                print(f"[{i + 1}/{len(variants)}] skipped: {err}", flush=True)
                continue
            done.write_text(json.dumps(variant_record(v, rec), indent=1))
            print(f"[{i + 1}/{len(variants)}] wrote {rec}", flush=True)
        record = json.loads(done.read_text())
        if "stature_m" not in record:  # (recordings rendered before it was recorded)
            record["stature_m"] = body_stature(v.phenotype)
            done.write_text(json.dumps(record, indent=1))
        records.append(record)
    path = write_manifest(out, cfg, records, skipped)
    print(f"{len(records)} recordings, {sum(r['frames'] for r in records)} frames, "
          f"{len(skipped)} skipped: {path}", flush=True)  # fmt: skip
    if calibration_out is None:
        return path
    for i, r in enumerate(records):
        # The same body holding the calibration T-pose (a random frontal camera, as in
        # dev_recordings), for "hybrid, calibrated body".
        rec = calibration_out / r["name"]
        if not (rec / "groundtruth.npz").is_file():
            render_sequence(
                "t_pose", rec, frames=cfg.calibration_frames, seed=r["seed"], width=cfg.width,
                overwrite=True, phenotype=r["phenotype"],
            )  # fmt: skip
            print(f"[{i + 1}/{len(records)}] wrote {rec}", flush=True)
    return path
