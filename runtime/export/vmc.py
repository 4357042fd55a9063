"""The tracked skeleton as VMC protocol messages (Virtual Motion Capture, OSC over UDP).

Message layouts (VMC protocol, Marionette side, as specified at https://protocol.vmc.info/
(source: github.com/sh-akira/VirtualMotionCaptureProtocol, ``docs/marionette-spec.markdown``;
the same layouts are sent by its ``sample/*/SampleBonesSendBundle.cs``)); one OSC bundle per
frame, in this order::

    /VMC/Ext/Root/Pos  (s)"root" (f)p.x (f)p.y (f)p.z (f)q.x (f)q.y (f)q.z (f)q.w
    /VMC/Ext/Bone/Pos  (s)name   (f)p.x (f)p.y (f)p.z (f)q.x (f)q.y (f)q.z (f)q.w   per bone
    /VMC/Ext/OK        (i)loaded                 1 for a tracked/detected pose, 0 when lost
    /VMC/Ext/T         (f)time                   the stream timestamp, seconds (to 1 us)

A frame without a pose (lost) carries only ``OK 0`` and ``T``: receivers keep the last pose.

Coordinates: Unity's, as the protocol's receivers (EVMC4U, VSeeFace, the Blender VMC add-on via
its Unity bone mapping) expect: left-handed, metres, y up, and an avatar at rest faces +z with
its left hand towards -x. A bone's ``p``/``q`` are its local position and rotation in its
parent bone's frame (``Transform.localPosition``/``localRotation``), with the rotation relative
to the humanoid T-pose: all identity is a T-pose (arms out sideways, palms down), as in a
normalized VRM 0.x model, whose bones a receiver turns by these rotations directly.

From this project's frames: the BVH world of :mod:`runtime.export.bvh` (``CAMERA_TO_WORLD``,
right-handed, y up, z towards the camera) with x negated, ``N = diag(-1, 1, 1)``:

* positions: ``p_unity = N @ CAMERA_TO_WORLD @ p_camera = (-x, -y, -z)`` of camera metres;
* rotations: ``R_unity = N @ R @ N``; as a quaternion ``(x, y, z, w) -> (x, -y, -z, w)``.

So a person facing the camera gives an avatar facing +z (towards a viewer in front of it, as
the VMC receivers place their camera), and moves like a mirror image of the person.

Root and hips: ``Root/Pos`` is the hip centre (the root of q, converted as above) with the
identity rotation; the whole body orientation is on ``Hips``, whose local position is zero.
A receiver that ignores the root (most VTuber apps) still turns and bends the avatar.

Bone mapping (segment of :mod:`shared.skeleton` -> Unity ``HumanBodyBones``), see
:data:`VMC_BONES`: pelvis -> Hips, abdomen -> Spine, chest -> Chest, neck -> Neck, head -> Head,
l/r_clavicle -> Left/RightShoulder, l/r_upper_arm -> Left/RightUpperArm, l/r_forearm ->
Left/RightLowerArm, l/r_thigh -> Left/RightUpperLeg, l/r_shank -> Left/RightLowerLeg; the
skeleton has no hands or feet, so Left/RightHand (at the wrist) and Left/RightFoot (at the
ankle) are sent with the identity local rotation: they continue the forearm and the shank.
UpperChest, toes, eyes, jaw and fingers are not sent (a receiver keeps them at rest).

Rotations: each bone has a fixed T-pose frame ``T_k`` in the body frame of
:mod:`shared.skeleton` (identity for the torso, head, clavicles and legs; the arms turned from
hanging down to pointing sideways: ``R_z(+90 deg)`` left, ``R_z(-90 deg)`` right). With ``W_k``
the segment's frame from forward kinematics, the bone's frame is ``W_k T_k^T`` and its local
rotation ``T_parent @ R_local @ T_k^T`` (``R_local`` = :func:`runtime.export.bvh.joint_rotations`,
the rest-pose-relative rotations the BVH export writes), so every bone points where the
tracked segment points (the body's chest lean and clavicle rest included). Positions are the
tracked body's joint offsets (``body.json``), in the same frames.
"""

from __future__ import annotations

import numpy as np
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape

from .bvh import CAMERA_TO_WORLD, _segment_offsets, joint_rotations
from .rotations import matrix_to_quat

__all__ = [
    "VMC_BONES",
    "UNITY_FROM_BVH",
    "camera_to_unity_position",
    "vmc_bone_transforms",
    "vmc_root_transform",
    "vmc_bundle",
]

# (HumanBodyBones name, segment index, what it is): a segment's own joint, or the far end of a
# leaf segment (the wrist and ankle bones, which have no DoFs of their own).
_S = sk.SEGMENT_NAMES.index
VMC_BONES: tuple[tuple[str, int, str], ...] = (
    ("Hips", _S("pelvis"), "segment"),
    ("Spine", _S("abdomen"), "segment"),
    ("Chest", _S("chest"), "segment"),
    ("Neck", _S("neck"), "segment"),
    ("Head", _S("head"), "segment"),
    ("LeftShoulder", _S("l_clavicle"), "segment"),
    ("LeftUpperArm", _S("l_upper_arm"), "segment"),
    ("LeftLowerArm", _S("l_forearm"), "segment"),
    ("LeftHand", _S("l_forearm"), "end"),
    ("RightShoulder", _S("r_clavicle"), "segment"),
    ("RightUpperArm", _S("r_upper_arm"), "segment"),
    ("RightLowerArm", _S("r_forearm"), "segment"),
    ("RightHand", _S("r_forearm"), "end"),
    ("LeftUpperLeg", _S("l_thigh"), "segment"),
    ("LeftLowerLeg", _S("l_shank"), "segment"),
    ("LeftFoot", _S("l_shank"), "end"),
    ("RightUpperLeg", _S("r_thigh"), "segment"),
    ("RightLowerLeg", _S("r_shank"), "segment"),
    ("RightFoot", _S("r_shank"), "end"),
)
VMC_BONE_NAMES: tuple[str, ...] = tuple(b[0] for b in VMC_BONES)

# Our right-handed BVH world (and body frame) -> Unity's left-handed axes.
UNITY_FROM_BVH = np.diag([-1.0, 1.0, 1.0])
_CAMERA_TO_UNITY = UNITY_FROM_BVH @ CAMERA_TO_WORLD


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# T-pose frame of each segment in the body frame (x left, y up, z forward).
_TPOSE = np.broadcast_to(np.eye(3), (sk.NUM_SEGMENTS, 3, 3)).copy()
for _side, _deg in (("l", 90.0), ("r", -90.0)):
    _TPOSE[_S(f"{_side}_upper_arm")] = _TPOSE[_S(f"{_side}_forearm")] = _rot_z(_deg)


def camera_to_unity_position(p: np.ndarray) -> np.ndarray:
    """Camera-frame metres (..., 3) -> Unity world metres: ``(-x, -y, -z)``."""
    return np.asarray(p, dtype=np.float64) @ _CAMERA_TO_UNITY.T


def _bone_offsets(body: BodyShape) -> np.ndarray:
    """(len(VMC_BONES), 3) each bone's origin in its parent bone's T-pose frame, Unity axes."""
    offsets = _segment_offsets(body)
    lengths = body.lengths.detach().cpu().double().numpy()
    out = np.zeros((len(VMC_BONES), 3))
    for i, (_, k, kind) in enumerate(VMC_BONES):
        if kind == "end":  # the far end of segment k, in k's frame
            out[i] = _TPOSE[k] @ (lengths[k] * sk.SEGMENT_AXIS[k])
        elif k != 0:
            out[i] = _TPOSE[sk.SEGMENT_PARENT[k]] @ offsets[k]
    return out @ UNITY_FROM_BVH.T


def vmc_bone_transforms(
    q: np.ndarray, body: BodyShape
) -> tuple[tuple[str, np.ndarray, np.ndarray], ...]:
    """The ``Bone/Pos`` values of pose ``q`` (34,): ``(name, local position (3,), local
    rotation (4,) x y z w)`` per bone of :data:`VMC_BONES`, Unity axes (module docstring)."""
    q = np.asarray(q, dtype=np.float64)
    rest = tuple(float(a) for a in body.clavicle_rest)
    local = joint_rotations(q[None], float(body.chest_tilt), rest)[0]  # (15, 3, 3)
    rel = np.empty_like(local)
    # Hips: the whole body orientation, in the BVH world (the root carries no rotation).
    rel[0] = CAMERA_TO_WORLD @ local[0] @ _TPOSE[0].T
    par = sk.SEGMENT_PARENT[1:]
    rel[1:] = _TPOSE[par] @ local[1:] @ np.swapaxes(_TPOSE[1:], -1, -2)
    rot = np.empty((len(VMC_BONES), 3, 3))
    for i, (_, k, kind) in enumerate(VMC_BONES):
        rot[i] = np.eye(3) if kind == "end" else rel[k]
    quats = matrix_to_quat(UNITY_FROM_BVH @ rot @ UNITY_FROM_BVH)
    pos = _bone_offsets(body)
    return tuple((name, pos[i], quats[i]) for i, name in enumerate(VMC_BONE_NAMES))


def vmc_root_transform(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``Root/Pos`` values of pose ``q``: (hip centre in Unity metres, identity (x y z w))."""
    q = np.asarray(q, dtype=np.float64)
    return camera_to_unity_position(q[0:3]), np.array([0.0, 0.0, 0.0, 1.0])


def vmc_bundle(time: float, q: np.ndarray | None, body: BodyShape):
    """The OSC bundle of one frame (a ``pythonosc`` ``OscBundle``); ``q`` None: lost."""
    from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
    from pythonosc.osc_message_builder import OscMessageBuilder

    def message(address: str, *args: tuple[object, str]):
        m = OscMessageBuilder(address)
        for value, kind in args:
            m.add_arg(value, kind)
        return m.build()

    def transform(address: str, name: str, p: np.ndarray, r: np.ndarray):
        floats = [(float(v), "f") for v in (*p, *r)]
        return message(address, (name, "s"), *floats)

    bundle = OscBundleBuilder(IMMEDIATELY)
    if q is not None:
        p, r = vmc_root_transform(q)
        bundle.add_content(transform("/VMC/Ext/Root/Pos", "root", p, r))
        for name, p, r in vmc_bone_transforms(q, body):
            bundle.add_content(transform("/VMC/Ext/Bone/Pos", name, p, r))
    bundle.add_content(message("/VMC/Ext/OK", (1 if q is not None else 0, "i")))
    bundle.add_content(message("/VMC/Ext/T", (round(float(time), 6), "f")))
    return bundle.build()
