"""The tracker's cylinder body (:class:`shared.body.BodyShape`) measured on a fitted rest mesh.

* **Lengths** are joint to joint, with the named joints defined on anny's bones as the
  ground truth of synthetic recordings defines them (``train.anny_body.anatomical_joints``:
  head = middle of the Head bone, neck = Neck head, spine = Spine head, shoulder/elbow/wrist =
  Arm/ForeArm/Hand heads, hip/knee/ankle = UpLeg/Leg/Foot heads) and the segment lengths
  derived from them as ``train.retarget.body_from_named_joints`` does (pelvis/abdomen and
  neck/head splits in the default proportions), so that the tracker's named joints land on
  the same anatomical points.
* **Radii**: each segment's vertices (by dominant skinning bone) projected onto the segment's
  two cross-section directions (``shared.body.cross_section_axes``, made orthogonal to the
  segment axis measured on the mesh); for points spread around an ellipse the 10%-90%
  quantile range of a projection is 1.90 times the semi-axis.
* **Extents** (geometry beyond the joints) where the default body has them: pelvis below the
  hip joints, head above its bone, hand beyond the wrist, foot below the ankle.
"""

from __future__ import annotations

import numpy as np
import torch

from shared import skeleton as sk
from shared.body import DEFAULT_EXTENTS, DEFAULT_LENGTHS, BodyShape, cross_section_axes

from .shape_model import RestShape, ShapeModel

__all__ = ["named_joints_from_bones", "body_from_rest"]

# Named joint -> (bone, end) pairs averaged; "head" is the middle of the Head bone.
_JOINT_BONES: dict[str, tuple[tuple[str, str], ...]] = {
    "head": (("Head", "head"), ("Head", "tail")),
    "neck": (("Neck", "head"),),
    "spine": (("Spine", "head"),),
    "pelvis": (("LeftUpLeg", "head"), ("RightUpLeg", "head")),
    **{f"{s}_{j}": ((f"{side}{b}", "head"),)
       for s, side in (("l", "Left"), ("r", "Right"))
       for j, b in (("shoulder", "Arm"), ("elbow", "ForeArm"), ("wrist", "Hand"),
                    ("hip", "UpLeg"), ("knee", "Leg"), ("ankle", "Foot"))},
}  # fmt: skip
# Fraction of a 10%-90% quantile range of cos(theta), theta uniform: 2 cos(pi / 10).
_QUANTILE_RANGE = 2.0 * np.cos(np.pi / 10)
# Extents measured on the mesh: (segment, 0 = before the origin / 1 = beyond the end).
_MEASURED_EXTENTS = (("pelvis", 0), ("head", 1), ("l_forearm", 1), ("r_forearm", 1),
                     ("l_shank", 1), ("r_shank", 1))  # fmt: skip


def named_joints_from_bones(model: ShapeModel, rest: RestShape) -> np.ndarray:
    """(16, 3) named joints (``shared.skeleton.JOINT_NAMES`` order) of a batch-1 rest body."""
    heads, tails = rest.heads[0].detach().numpy(), rest.tails[0].detach().numpy()
    out = np.zeros((len(sk.JOINT_NAMES), 3))
    for j, name in enumerate(sk.JOINT_NAMES):
        ends = _JOINT_BONES[name]
        out[j] = np.mean(
            [(heads if end == "head" else tails)[model.bone_names.index(b)] for b, end in ends], 0
        )
    return out


def _lengths(joints: np.ndarray) -> tuple[np.ndarray, float]:
    """Segment lengths (15,) and hip half width from named joints."""
    J = dict(zip(sk.JOINT_NAMES, joints))

    def dist(a: str, b: str) -> float:
        return float(np.linalg.norm(J[a] - J[b]))

    names = sk.SEGMENT_NAMES
    L = DEFAULT_LENGTHS.copy()
    limbs = {"upper_arm": ("shoulder", "elbow"), "forearm": ("elbow", "wrist"),
             "thigh": ("hip", "knee"), "shank": ("knee", "ankle")}  # fmt: skip
    for s in "lr":
        for seg, (a, b) in limbs.items():
            L[names.index(f"{s}_{seg}")] = dist(f"{s}_{a}", f"{s}_{b}")
        L[names.index(f"{s}_clavicle")] = dist(f"{s}_shoulder", "neck")
    share = DEFAULT_LENGTHS[0] / (DEFAULT_LENGTHS[0] + DEFAULT_LENGTHS[1])
    L[0], L[1] = share * dist("pelvis", "spine"), (1 - share) * dist("pelvis", "spine")
    L[2] = dist("spine", "neck")
    # neck -> head joint = neck length + JOINT_FRACTION(head) * head length (default ratio).
    frac = sk.JOINT_FRACTION[sk.JOINT_NAMES.index("head")]
    ratio = DEFAULT_LENGTHS[4] / DEFAULT_LENGTHS[3]
    L[3] = dist("neck", "head") / (1 + frac * ratio)
    L[4] = L[3] * ratio
    return L, 0.5 * dist("l_hip", "r_hip")


def _segment_frames(joints: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start point (15, 3) and axis (15, 3) of every segment on the rest mesh."""
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


def body_from_rest(model: ShapeModel, rest: RestShape) -> BodyShape:
    """The tracker's body measured on a batch-1 rest body of ``model`` (module docstring)."""
    joints = named_joints_from_bones(model, rest)
    lengths, hip_half_width = _lengths(joints)
    start, axis = _segment_frames(joints, lengths)
    verts = rest.vertices[0].detach().numpy()
    segment = model.vertex_segment.numpy()
    section = cross_section_axes()  # (15, 2, 3) in the segment frame = body frame at rest
    radii = np.zeros((sk.NUM_SEGMENTS, 2))
    extents = DEFAULT_EXTENTS * 0.0
    for k in range(sk.NUM_SEGMENTS):
        rel = verts[segment == k] - start[k]
        along = rel @ axis[k]
        inside = (along >= 0) & (along <= lengths[k])
        for i in range(2):
            d = section[k, i] - (section[k, i] @ axis[k]) * axis[k]
            proj = rel[inside if inside.sum() >= 20 else slice(None)] @ (d / np.linalg.norm(d))
            lo, hi = np.quantile(proj, [0.1, 0.9])
            radii[k, i] = max((hi - lo) / _QUANTILE_RANGE, 0.01)
        for name, side in _MEASURED_EXTENTS:
            if sk.SEGMENT_NAMES.index(name) == k:
                beyond = -along.min() if side == 0 else along.max() - lengths[k]
                extents[k, side] = max(float(beyond), 0.0)
    body = BodyShape(
        torch.as_tensor(lengths),
        torch.as_tensor(radii),
        torch.as_tensor(extents),
        torch.tensor(hip_half_width, dtype=torch.float64),
    )
    body.validate()
    return body.to(torch.float32)
