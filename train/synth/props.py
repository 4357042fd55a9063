"""Furniture against the person, for the person/clutter forest.

Real rooms have chairs, tables and cupboards, and people sit on them and lean against them.
Where such an object touches the person at about the same depth, the segmentation
(:mod:`runtime.segmentation`) cannot cut it off: on real Kinect depth (UTD-MHAD, sit to stand)
the chair's seat stays in the person's mask, and the tracker bends the hips and legs to
explain it (``docs/real_data.md``). Depth alone says "connected"; what says "not a person" is
shape: flat faces, straight edges, right angles. The body-part forest never learns that (it
is trained on the exact body silhouette), so a second, small forest is trained to tell the
person's pixels from furniture's inside the segmented mask.

:func:`attached_prop` draws one piece standing on the floor against the body, in the camera's
level frame (boxes as :class:`~shared.sensor_noise.background.BackgroundBox`, round parts as
:class:`~shared.sensor_noise.background.BackgroundCylinder`):

- a *chair* behind or under the hips: a round or square seat at a chair's height (a quarter to
  a third of the person's), wider than the hips, on a stem or four legs, half the time with a
  backrest (a chair seen from the front shows its seat beside the hips and between the legs);
- a *bench*: a block behind the hips, wider than them, up to half the person's height;
- a *table* beside the body, its near face at the depth of a body point at its height.

:func:`person_clutter_labels` then labels what the runtime's segmentation keeps of the noisy
frame: 1 on the body, 2 on the prop, 0 elsewhere: the classes
:data:`shared.labels.CLUTTER_CLASSES`. The forest is trained as the body-part forest is, on
the labelled pixels with everything else at the background depth: the person with the
furniture the segmentation would leave attached.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import field_doc
from depthmocap.shared.sensor_noise.background import BackgroundBox, BackgroundCylinder

__all__ = [
    "PROP_KINDS",
    "Furniture",
    "PropConfig",
    "attached_prop",
    "chair_under",
    "person_clutter_labels",
    "pixel_heights",
    "sitting_pose",
]

# The kinds of furniture drawn, and the band of the body (fractions of its height above the
# floor) each one reaches up to.
PROP_KINDS: dict[str, tuple[float, float]] = {
    "chair": (0.22, 0.32),
    "bench": (0.22, 0.55),
    "table": (0.25, 0.75),
}


class Furniture(NamedTuple):
    """One piece of furniture as the scene's shapes (level floor frame)."""

    boxes: tuple[BackgroundBox, ...]
    cylinders: tuple[BackgroundCylinder, ...]


@dataclass
class PropConfig:
    """Furniture against the person (off by default: the body-part training set and the
    evaluation recordings have none)."""

    probability: float = field_doc(0.0, "share of frames with a prop against the person")
    person_clutter_labels: bool = field_doc(
        False,
        "label the segmented mask person (1) or clutter (2), 0 outside it "
        "(shared.labels.CLUTTER_CLASSES): the person/clutter forest's training set",
    )
    depth_m: tuple[float, float] = field_doc(
        (0.3, 0.6), "range of a prop's extent away from the camera (m)"
    )
    table_width_m: tuple[float, float] = field_doc(
        (0.3, 1.0), "range of a table's width beside the body (m)"
    )
    sitting: float = field_doc(
        0.0,
        "share of all frames whose person is seated (hips and knees bent by sitting_pose; "
        "the training motions have no sitting); the furniture drawn for them (probability) "
        "is a chair under them, the others crouch without one",
    )

    def validate(self) -> None:
        """Raise ``ValueError`` on values that make no sense."""
        for name in ("probability", "sitting"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"props.{name} must be in [0, 1], not {getattr(self, name)}")
        for name in ("depth_m", "table_width_m"):
            lo, hi = getattr(self, name)
            if not 0.0 < lo <= hi:
                raise ValueError(f"props.{name} must be a range 0 < lo <= hi, not {lo, hi}")


def attached_prop(
    rng: np.random.Generator,
    body_level: np.ndarray,
    camera_height: float,
    cfg: PropConfig,
    kind: str | None = None,
) -> Furniture:
    """One piece of furniture standing on the floor against the body (module docstring).

    Args:
        body_level: (V, 3) the body's vertices in the camera's level frame (x right, y down,
            z horizontal forward; the floor at ``y = camera_height``).
        camera_height: the camera centre's height above the floor (m).
        kind: one of :data:`PROP_KINDS`, or None to draw one.
    Returns:
        Its boxes and cylinders, in the level frame.
    """
    kind = str(rng.choice(list(PROP_KINDS))) if kind is None else kind
    lo, hi = PROP_KINDS[kind]
    above = camera_height - body_level[:, 1]
    stature = float(above.max())
    hips = body_level[(above > 0.4 * stature) & (above < 0.6 * stature)]
    if len(hips) == 0:  # a body lying down: all of it
        hips = body_level
    top = float(rng.uniform(lo, hi)) * stature
    if kind == "chair":
        return _chair(rng, hips, top, stature)
    x, z = hips[:, 0], hips[:, 2]
    extent = float(rng.uniform(*cfg.depth_m))
    if kind == "bench":
        x0 = np.percentile(x, 5) - rng.uniform(0.05, 0.3)
        x1 = np.percentile(x, 95) + rng.uniform(0.05, 0.3)
        z0 = float(np.median(z)) + rng.uniform(-0.05, 0.15)
    else:
        band = body_level[(above > lo * stature) & (above < hi * stature)]
        band = hips if len(band) == 0 else band
        right = bool(rng.random() < 0.5)
        edge = float(np.percentile(band[:, 0], 97 if right else 3))
        width = float(rng.uniform(*cfg.table_width_m))
        reach = float(rng.uniform(0.0, 0.1))  # how far it reaches under the body's edge
        x0, x1 = (edge - reach, edge + width) if right else (edge - width, edge + reach)
        z0 = float(band[rng.integers(len(band)), 2]) + rng.uniform(-0.1, 0.1)
    box = BackgroundBox(float(x0), float(x1), float(z0), float(z0 + extent), top)
    return Furniture((box,), ())


def _chair(
    rng: np.random.Generator,
    hips: np.ndarray,
    seat: float,
    stature: float,
    centre: np.ndarray | None = None,
) -> Furniture:
    """A chair behind or under the hips (or at ``centre``, level frame): a round or square
    seat wider than them at ``seat`` height, on a stem or four legs, with a backrest half the
    time."""
    if centre is None:
        cx = float(np.median(hips[:, 0])) + rng.uniform(-0.05, 0.05)
        cz = float(np.median(hips[:, 2])) + rng.uniform(0.0, 0.25)
    else:
        cx, cz = float(centre[0]), float(centre[2])
    r = float(rng.uniform(0.2, 0.3))
    under = seat - float(rng.uniform(0.03, 0.1))
    boxes, cylinders = [], []
    if rng.random() < 0.5:
        cylinders.append(BackgroundCylinder(cx, cz, r, under, seat))
    else:
        boxes.append(BackgroundBox(cx - r, cx + r, cz - r, cz + r, seat))  # a solid stool
    if rng.random() < 0.5:
        cylinders.append(BackgroundCylinder(cx, cz, 0.03, 0.0, under))
    else:
        leg = 0.8 * r
        cylinders += [
            BackgroundCylinder(cx + sx * leg, cz + sz * leg, 0.02, 0.0, under)
            for sx in (-1, 1)
            for sz in (-1, 1)
        ]
    if rng.random() < 0.5:
        half = float(rng.uniform(0.15, 0.25))
        z0 = cz + 0.8 * r
        back = float(rng.uniform(0.5, 0.75)) * stature
        boxes.append(BackgroundBox(cx - half, cx + half, z0, z0 + rng.uniform(0.03, 0.08), back))
    return Furniture(tuple(boxes), tuple(cylinders))


def sitting_pose(q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(34,) ``q`` seated: both hips flexed 70-100 degrees, the knees 70-110, the thighs a
    little apart; the rest of the pose (trunk, arms, head) as it was."""
    out = np.array(q, dtype=np.float64, copy=True)
    for side in "lr":
        out[sk.DOF_NAMES.index(f"{side}_femur_flex")] = rng.uniform(1.2, 1.75)
        out[sk.DOF_NAMES.index(f"{side}_femur_abd")] = rng.uniform(-0.05, 0.3)
        out[sk.DOF_NAMES.index(f"{side}_femur_twist")] = rng.uniform(-0.2, 0.2)
        out[sk.DOF_NAMES.index(f"{side}_tibia_flex")] = rng.uniform(1.2, 1.9)
    return out


def chair_under(
    rng: np.random.Generator, body_level: np.ndarray, pelvis_level: np.ndarray
) -> Furniture:
    """A chair whose seat carries a seated body: centred under the pelvis (level frame, (3,)),
    its top at the lowest body point within 12 cm of it horizontally (the buttocks)."""
    near = np.hypot(body_level[:, 0] - pelvis_level[0], body_level[:, 2] - pelvis_level[2]) < 0.12
    lowest = float(body_level[near, 1].max()) if near.any() else float(pelvis_level[1]) + 0.1
    floor = float(body_level[:, 1].max())  # the feet stand on the floor
    seat = max(floor - lowest - float(rng.uniform(0.0, 0.015)), 0.1)
    hips = body_level[near] if near.any() else body_level
    centre = np.array([pelvis_level[0], 0.0, pelvis_level[2] + rng.uniform(0.0, 0.08)])
    return _chair(rng, hips, seat, floor - float(body_level[:, 1].min()), centre)


def person_clutter_labels(
    depth_mm: np.ndarray, labels: np.ndarray, prop: np.ndarray, height_m: np.ndarray,
    floor_band_m: float = 0.05,
) -> np.ndarray:  # fmt: skip
    """(H, W) uint8 :data:`~shared.labels.CLUTTER_CLASSES` labels of a noisy frame: 1 on the
    body (``labels > 0``), 2 on the prop's pixels with a reading, 0 elsewhere.

    The prop is drawn flush with the body, so the segmentation keeps it with the person
    (checked against :mod:`runtime.segmentation` in the tests); only its foot on the floor,
    which the segmentation takes away with the floor, is left out.

    Args:
        depth_mm: (H, W) the frame after the sensor model; 0 = no reading.
        labels: (H, W) its part labels (0 off the body).
        prop: (H, W) bool where the prop is the nearest surface (before the sensor model).
        height_m: (H, W) each pixel's height above the floor (m).
        floor_band_m: the segmentation's floor band: pixels lower than this are floor.
    """
    body = np.asarray(labels) > 0
    clutter = np.asarray(prop, bool) & ~body & (np.asarray(depth_mm) > 0)
    clutter &= np.asarray(height_m) > floor_band_m
    return np.where(body, 1, np.where(clutter, 2, 0)).astype(np.uint8)


def pixel_heights(
    depth_m: np.ndarray, intr: Intrinsics, level_from_camera: np.ndarray, camera_height: float
) -> np.ndarray:
    """(H, W) each pixel's height above the floor (m) from its depth (metres, 0 = none: NaN
    there), the camera's level rotation (``shared.sensor_noise.background.level_from_camera``)
    and height."""
    z = np.where(np.asarray(depth_m) > 0, depth_m, np.nan).astype(np.float64)
    h, w = z.shape
    u = (np.arange(w) - intr.cx) / intr.fx
    v = (np.arange(h) - intr.cy) / intr.fy
    rot = np.asarray(level_from_camera, dtype=np.float64)
    y_level = (rot[1, 0] * u[None, :] + rot[1, 1] * v[:, None] + rot[1, 2]) * z
    return camera_height - y_level
