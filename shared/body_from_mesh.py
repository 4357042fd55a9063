"""The tracker's cylinder body (:class:`shared.body.BodyShape`) measured on a rest mesh.

One measurement for every place that turns a body mesh into the tracker's body: the ground
truth body of synthetic recordings (the anny body that was rendered) and personalization's
fitted mesh (Helten section III), so the two are comparable.

* **Lengths** are joint to joint between the named joints of ``shared.skeleton.JOINT_NAMES``,
  with the pelvis/abdomen and neck/head splits in the default proportions (the skeleton has
  no joint between them), and the hip half width from the two hip joints.
* **Sections**: each segment's vertices between its two joints, projected onto the segment's
  two cross-section directions (``shared.body.cross_section_axes``, made orthogonal to the
  segment axis measured on the mesh). For points spread around an ellipse the 10%-90%
  quantile range of a projection is 1.90 times the semi-axis, and its middle is the centre:
  the centre's distance from the joint axis is the segment's offset (the spine lies some
  5 cm behind the middle of the trunk; a tracker whose torso is centred on the spine leans
  the whole skeleton back to fit the belly).
  Quantiles are weighted by the surface area around each vertex: meshes are far denser on
  the face (and anny's has eyes and a tongue inside the head), which would otherwise pull the
  head's centre 6 cm forward.
* **Extents** (geometry beyond the joints) where the default body has them: pelvis below the
  hip joints, head above its bone, hand beyond the wrist, sole below the ankle.
* **Feet**: the toe tip's distance forward of the shank axis, and as radius half the height
  of the foot's middle third (the instep the camera sees).
* **Chest tilt**: the angle, seen from the side, between the lower trunk (pelvis to spine)
  and the chest (spine to the base of the neck). Without it the chest went straight up and
  the neck joint sat 4 cm behind anny's, pulling the shoulders with it.
* **Clavicles**: length and rest (elevation, protraction) of the base of the neck -> shoulder
  line in the tilted chest's frame, both sides averaged (mirrored), from the shoulders where
  the poser puts them at q = 0 when given: anny's arm chain is turned from its A-pose onto the
  skeleton's axes by rotating each clavicle bone, which moves the shoulder by 2-3 cm.
"""

from __future__ import annotations

import numpy as np
import torch

from . import skeleton as sk
from .body import DEFAULT_LENGTHS, FOOT_SEGMENTS, BodyShape, cross_section_axes

__all__ = [
    "segment_lengths_from_joints",
    "chest_tilt_from_joints",
    "clavicle_rest_from_joints",
    "vertex_areas",
    "body_from_mesh",
]

# Fraction of a 10%-90% quantile range of cos(theta), theta uniform: 2 cos(pi / 10).
_QUANTILE_RANGE = 2.0 * np.cos(np.pi / 10)
# Extents measured on the mesh: (segment, 0 = before the origin / 1 = beyond the end).
_MEASURED_EXTENTS = (("pelvis", 0), ("head", 1), ("l_forearm", 1), ("r_forearm", 1),
                     ("l_shank", 1), ("r_shank", 1))  # fmt: skip
_MIN_SECTION_POINTS = 20


def segment_lengths_from_joints(joints: np.ndarray) -> tuple[np.ndarray, float]:
    """Segment lengths (15,) and hip half width from named joints (16, 3) or (F, 16, 3).

    Over frames, each distance is the median (posed clips stretch nothing, but mocap noise
    does).
    """
    j = np.asarray(joints, dtype=np.float64).reshape(-1, len(sk.JOINT_NAMES), 3)
    J = {n: j[:, i] for i, n in enumerate(sk.JOINT_NAMES)}

    def dist(a: str, b: str) -> float:
        return float(np.median(np.linalg.norm(J[a] - J[b], axis=-1)))

    names = sk.SEGMENT_NAMES
    L = DEFAULT_LENGTHS.copy()
    limbs = {"upper_arm": ("shoulder", "elbow"), "forearm": ("elbow", "wrist"),
             "thigh": ("hip", "knee"), "shank": ("knee", "ankle")}  # fmt: skip
    for s in "lr":
        for seg, (a, b) in limbs.items():
            L[names.index(f"{s}_{seg}")] = dist(f"{s}_{a}", f"{s}_{b}")
        L[names.index(f"{s}_clavicle")] = dist(f"{s}_shoulder", "neck")
    share = DEFAULT_LENGTHS[0] / (DEFAULT_LENGTHS[0] + DEFAULT_LENGTHS[1])
    lower_trunk = dist("pelvis", "spine")
    L[0], L[1] = share * lower_trunk, (1 - share) * lower_trunk
    L[2] = dist("spine", "neck")
    # neck -> head joint = neck length + JOINT_FRACTION(head) * head length (default ratio).
    frac = sk.JOINT_FRACTION[sk.JOINT_NAMES.index("head")]
    ratio = DEFAULT_LENGTHS[4] / DEFAULT_LENGTHS[3]
    L[3] = dist("neck", "head") / (1 + frac * ratio)
    L[4] = L[3] * ratio
    return L, 0.5 * dist("l_hip", "r_hip")


def _segment_axes(joints: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start point (15, 3) and unit axis (15, 3) of every segment on the rest mesh."""
    J = dict(zip(sk.JOINT_NAMES, joints))
    up = J["head"] - J["neck"]
    up = up / np.linalg.norm(up)
    start, end = np.zeros((sk.NUM_SEGMENTS, 3)), np.zeros((sk.NUM_SEGMENTS, 3))
    trunk = J["spine"] - J["pelvis"]
    start[0], end[0] = J["pelvis"], J["spine"]
    start[1], end[1] = J["pelvis"] + trunk * lengths[0] / (lengths[0] + lengths[1]), J["spine"]
    start[2], end[2] = J["spine"], J["neck"]
    start[3], end[3] = J["neck"], J["neck"] + lengths[3] * up
    start[4], end[4] = end[3], end[3] + lengths[4] * up
    for s in "lr":
        for seg, (a, b) in {"clavicle": ("neck", f"{s}_shoulder"),
                            "upper_arm": (f"{s}_shoulder", f"{s}_elbow"),
                            "forearm": (f"{s}_elbow", f"{s}_wrist"),
                            "thigh": (f"{s}_hip", f"{s}_knee"),
                            "shank": (f"{s}_knee", f"{s}_ankle")}.items():  # fmt: skip
            k = sk.SEGMENT_NAMES.index(f"{s}_{seg}")
            start[k], end[k] = J[a], J[b]
    axis = end - start
    return start, axis / np.linalg.norm(axis, axis=1, keepdims=True)


def chest_tilt_from_joints(joints: np.ndarray) -> float:
    """Forward lean (rad) of spine -> neck against pelvis -> spine, in the body's y-z plane;
    ``joints`` (16, 3) in the body frame (y up, z forward)."""
    J = dict(zip(sk.JOINT_NAMES, np.asarray(joints, dtype=np.float64)))
    lower, upper = J["spine"] - J["pelvis"], J["neck"] - J["spine"]
    return float(np.arctan2(upper[2], upper[1]) - np.arctan2(lower[2], lower[1]))


def clavicle_rest_from_joints(joints: np.ndarray, chest_tilt: float) -> np.ndarray:
    """Rest (elevation, protraction) of the clavicles (2,) in radians, both sides averaged.

    ``joints`` (16, 3) in the body frame; the angles are those of
    ``shared.skeleton``'s clavicle DoFs that turn the segment axis (+-x of the chest frame,
    which leans ``chest_tilt`` forward) onto neck -> shoulder.
    """
    J = dict(zip(sk.JOINT_NAMES, np.asarray(joints, dtype=np.float64)))
    c, s = np.cos(chest_tilt), np.sin(chest_tilt)
    to_chest = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])  # R_x(tilt)^T
    angles = []
    for side, sign in (("l", 1.0), ("r", -1.0)):
        x, y, z = to_chest @ (J[f"{side}_shoulder"] - J["neck"])
        angles.append((np.arctan2(y, sign * x), np.arctan2(z, np.hypot(x, y))))
    return np.mean(angles, 0)


def vertex_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V,) a third of the area of the triangles around each vertex, square metres."""
    tri = vertices[faces]  # (F, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=-1)
    out = np.zeros(len(vertices))
    np.add.at(out, faces.reshape(-1), np.repeat(area / 3.0, 3))
    return out


def _weighted_quantiles(x: np.ndarray, w: np.ndarray, q: tuple[float, ...]) -> np.ndarray:
    """Quantiles of samples ``x`` (N,) with weights ``w`` (N,), by the weighted CDF midpoints."""
    order = np.argsort(x)
    xs, ws = x[order], w[order]
    if not ws.sum() > 0:  # no area at all (points without faces): equal weights
        ws = np.ones_like(ws)
    cdf = (np.cumsum(ws) - 0.5 * ws) / ws.sum()
    return np.interp(q, cdf, xs)


def _foot(rel: np.ndarray, axis: np.ndarray, length: float) -> tuple[float, float]:
    """(toe tip forward of the shank axis, radius) from a shank's vertices relative to its
    start (the knee); body-frame forward is +z."""
    along = rel @ axis
    below = rel[along > length]  # past the ankle: the foot
    if len(below) < _MIN_SECTION_POINTS:
        raise ValueError("the mesh has no foot below the ankle")
    fwd = np.array([0.0, 0.0, 1.0]) - axis[2] * axis
    fwd /= np.linalg.norm(fwd)
    ahead = below @ fwd
    toe = float(ahead.max())
    middle = (ahead > toe / 3) & (ahead < 2 * toe / 3)
    height = np.ptp(below[middle] @ axis) if middle.sum() >= 3 else 0.5 * toe
    return toe, 0.5 * float(height)


def body_from_mesh(
    joints: np.ndarray,
    vertices: np.ndarray,
    vertex_segment: np.ndarray,
    faces: np.ndarray | None = None,
    posed_shoulders: np.ndarray | None = None,
) -> BodyShape:
    """The tracker's body measured on a rest mesh in the body frame (module docstring).

    Args:
        joints: (16, 3) named joints of the rest mesh (``JOINT_NAMES`` order), metres.
        vertices: (V, 3) rest vertices in the body frame (x left, y up, z forward).
        vertex_segment: (V,) segment index of each vertex (``SEGMENT_NAMES`` order).
        faces: (F, 3) triangles, to weight vertices by their surface area (None: equal).
        posed_shoulders: (2, 3) left and right shoulder where the poser puts them at q = 0,
            for the clavicles' lengths and rest angles (None: the rest joints' shoulders).
    Returns:
        an unbatched float32 :class:`BodyShape`.
    """
    joints = np.asarray(joints, dtype=np.float64)
    verts = np.asarray(vertices, dtype=np.float64)
    segment = np.asarray(vertex_segment)
    weight = np.ones(len(verts)) if faces is None else vertex_areas(verts, np.asarray(faces))
    lengths, hip_half_width = segment_lengths_from_joints(joints)
    chest_tilt = chest_tilt_from_joints(joints)
    at_zero = joints.copy()
    if posed_shoulders is not None:
        for side, shoulder in zip("lr", np.asarray(posed_shoulders, dtype=np.float64)):
            at_zero[sk.JOINT_NAMES.index(f"{side}_shoulder")] = shoulder
    neck = at_zero[sk.JOINT_NAMES.index("neck")]
    for side in "lr":
        shoulder = at_zero[sk.JOINT_NAMES.index(f"{side}_shoulder")]
        lengths[sk.SEGMENT_NAMES.index(f"{side}_clavicle")] = np.linalg.norm(shoulder - neck)
    start, axis = _segment_axes(joints, lengths)
    section = cross_section_axes()  # (15, 2, 3) in the segment frame = body frame at rest
    radii = np.zeros((sk.NUM_SEGMENTS, 2))
    offsets = np.zeros((sk.NUM_SEGMENTS, 2))
    extents = np.zeros((sk.NUM_SEGMENTS, 2))
    feet = np.zeros((2, 2))
    for k in range(sk.NUM_SEGMENTS):
        rel = verts[segment == k] - start[k]
        if len(rel) == 0:
            raise ValueError(f"the mesh has no vertices on segment {sk.SEGMENT_NAMES[k]}")
        along = rel @ axis[k]
        inside = (along >= 0) & (along <= lengths[k])
        if inside.sum() < _MIN_SECTION_POINTS:
            inside = np.ones_like(inside)
        used, w = rel[inside], weight[segment == k][inside]
        for i in range(2):
            d = section[k, i] - (section[k, i] @ axis[k]) * axis[k]
            lo, hi = _weighted_quantiles(used @ (d / np.linalg.norm(d)), w, (0.1, 0.9))
            radii[k, i] = max((hi - lo) / _QUANTILE_RANGE, 0.01)
            offsets[k, i] = 0.5 * (lo + hi)
        for name, side in _MEASURED_EXTENTS:
            if sk.SEGMENT_NAMES.index(name) == k:
                beyond = -along.min() if side == 0 else along.max() - lengths[k]
                extents[k, side] = max(float(beyond), 0.0)
        if k in FOOT_SEGMENTS:
            feet[FOOT_SEGMENTS.index(k)] = _foot(rel, axis[k], lengths[k])
    t = torch.as_tensor
    body = BodyShape(
        t(lengths), t(radii), t(extents), torch.tensor(hip_half_width, dtype=torch.float64),
        t(offsets), t(feet), torch.tensor(chest_tilt, dtype=torch.float64),
        t(clavicle_rest_from_joints(at_zero, chest_tilt)),
    )  # fmt: skip
    body.validate()
    return body.to(torch.float32)
