"""Named joints and measurements of anny bodies, defined as the tracker's skeleton defines them.

The named joints (``shared.anny_rig.JOINT_RECIPES``) are the points the tracker must report;
segment lengths follow ``shared.body.DEFAULT_LENGTHS`` so that the measured body and the
cylinder model's defaults can be compared term by term.
"""

from __future__ import annotations

import numpy as np
from depthmocap.shared.anny_rig import JOINT_RECIPES
from depthmocap.shared.skeleton import JOINT_NAMES, SEGMENT_NAMES
from depthmocap.train.bodies.anny_body import AnnyBody
from depthmocap.train.bodies.skinning import PosedBody

__all__ = ["anatomical_joints", "body_measurements", "segment_lengths"]

assert tuple(JOINT_RECIPES) == JOINT_NAMES

# Joint-to-joint definition of each segment's length, matching shared.body.DEFAULT_LENGTHS:
# (start joint, end joint) as named joints or bone ends.
_SEGMENT_ENDS: dict[str, tuple[str, str]] = {
    "pelvis": ("pelvis", "LowerBack.head"),
    "abdomen": ("LowerBack.head", "spine"),
    "chest": ("spine", "neck"),
    "neck": ("neck", "Head.head"),
    "head": ("Head.head", "Head.tail"),
    "l_clavicle": ("neck", "l_shoulder"),
    "r_clavicle": ("neck", "r_shoulder"),
    "l_upper_arm": ("l_shoulder", "l_elbow"),
    "r_upper_arm": ("r_shoulder", "r_elbow"),
    "l_forearm": ("l_elbow", "l_wrist"),
    "r_forearm": ("r_elbow", "r_wrist"),
    "l_thigh": ("l_hip", "l_knee"),
    "r_thigh": ("r_hip", "r_knee"),
    "l_shank": ("l_knee", "l_ankle"),
    "r_shank": ("r_knee", "r_ankle"),
}


def _bone_end(body: AnnyBody, heads: np.ndarray, tails: np.ndarray, spec: str) -> np.ndarray:
    name, end = spec.split(".")
    return (heads if end == "head" else tails)[..., body.bone_index(name), :]


def anatomical_joints(body: AnnyBody, posed: PosedBody | None = None) -> np.ndarray:
    """The named joints of ``shared.skeleton.JOINT_NAMES`` from bone heads/tails.

    head = middle of the Head bone; neck = Neck head (base of the neck); spine = Spine head
    (top of the lumbar spine, where our chest segment starts); pelvis = midpoint of the hips;
    shoulder/elbow/wrist = Arm/ForeArm/Hand heads; hip/knee/ankle = UpLeg/Leg/Foot heads.

    Args:
        body: the body.
        posed: a ``pose_body`` result; None for the rest pose.
    Returns:
        (..., 16, 3) joint positions in JOINT_NAMES order.
    """
    heads = body.bone_heads if posed is None else posed.bone_heads
    tails = body.bone_tails if posed is None else posed.bone_tails
    key = ("joints",)
    if key not in body._cache:
        n = body.num_bones
        mix = np.zeros((len(JOINT_NAMES), 2 * n))
        for j, name in enumerate(JOINT_NAMES):
            for bone, end, w in JOINT_RECIPES[name]:
                mix[j, body.bone_index(bone) + (n if end == "tail" else 0)] += w
        body._cache[key] = mix
    mix = body._cache[key]
    return (mix @ np.concatenate([heads, tails], axis=-2)).astype(heads.dtype, copy=False)


def segment_lengths(body: AnnyBody) -> np.ndarray:
    """(15,) rest joint-to-joint segment lengths in SEGMENT_NAMES order, defined as
    ``shared.body.DEFAULT_LENGTHS`` (e.g. thigh = hip->knee, clavicle = neck base->shoulder,
    head = Head bone length, i.e. top of the neck to about the crown)."""
    joints = dict(zip(JOINT_NAMES, anatomical_joints(body)))

    def point(spec: str) -> np.ndarray:
        return (
            joints[spec]
            if spec in joints
            else _bone_end(body, body.bone_heads, body.bone_tails, spec)
        )

    return np.array(
        [np.linalg.norm(point(b) - point(a)) for a, b in (_SEGMENT_ENDS[s] for s in SEGMENT_NAMES)]
    )


def body_measurements(body: AnnyBody) -> dict[str, float]:
    """Rest measurements for comparing with the cylinder model's defaults (metres).

    Returns:
        dict with every segment length (by segment name), ``stature`` (mesh height),
        ``hip_half_width`` (half the distance between the hip joints), ``shoulder_width``
        (between the shoulder joints), ``ankle_height`` (ankle above the sole), ``hand_length``
        (left wrist to the farthest hand/finger vertex, i.e. the fingertip).
    """
    joints = dict(zip(JOINT_NAMES, anatomical_joints(body)))
    out = {name: float(v) for name, v in zip(SEGMENT_NAMES, segment_lengths(body))}
    y = body.vertices[:, 1]
    # Hand = vertices whose dominant bone is the hand or a finger (not the forearm itself).
    dominant = np.array(body.bone_names)[np.argmax(body.skin_weights, axis=1)]
    hand = body.vertices[
        np.isin(dominant, ["LeftHand", "LThumb", "LeftFingerBase", "LeftHandFinger1"])
    ]
    out.update(
        stature=float(y.max() - y.min()),
        hip_half_width=float(0.5 * np.linalg.norm(joints["l_hip"] - joints["r_hip"])),
        shoulder_width=float(np.linalg.norm(joints["l_shoulder"] - joints["r_shoulder"])),
        ankle_height=float(0.5 * (joints["l_ankle"][1] + joints["r_ankle"][1]) - y.min()),
        hand_length=float(np.linalg.norm(hand - joints["l_wrist"], axis=1).max()),
    )
    return out
