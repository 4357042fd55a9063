"""Retargeting: mocap clips -> named joints -> the 34-DoF tracking skeleton.

Copying local Euler angles between rigs fails (bone-local axes and rest poses differ), so we
go through positions: each rig's joints are mapped by name onto the named anatomical joints
of :mod:`shared.skeleton`, a :class:`BodyShape` is measured from them, and inverse kinematics
recovers q frame by frame (batched). The same named joints drive the ``anny`` mesh.

World frame of the outputs: y up (both HDM05 ASF/AMC and the CMU BVH files are y-up),
metres; the floor is re-established by :func:`shared.procedural_motion.ground_poses` users.
"""

from __future__ import annotations

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import DEFAULT_LENGTHS, BodyShape
from depthmocap.shared.body_from_mesh import segment_lengths_from_joints
from depthmocap.shared.ik import fit_pose
from depthmocap.shared.so3 import matrix_to_rotvec
from depthmocap.train.mocap import MotionClip

__all__ = [
    "RIG_JOINT_MAPS",
    "detect_rig",
    "clip_named_joints",
    "body_from_named_joints",
    "root_frame_from_joints",
    "retarget_joints",
]

# Named joint -> source joints averaged to get it, per rig. ``head`` is special-cased.
RIG_JOINT_MAPS: dict[str, dict[str, tuple[str, ...]]] = {
    "asf": {
        "head": ("head", "head_end"),
        "neck": ("lowerneck",),
        "spine": ("upperback",),
        "pelvis": ("lfemur", "rfemur"),
        "l_shoulder": ("lhumerus",), "r_shoulder": ("rhumerus",),
        "l_elbow": ("lradius",), "r_elbow": ("rradius",),
        "l_wrist": ("lwrist",), "r_wrist": ("rwrist",),
        "l_hip": ("lfemur",), "r_hip": ("rfemur",),
        "l_knee": ("ltibia",), "r_knee": ("rtibia",),
        "l_ankle": ("lfoot",), "r_ankle": ("rfoot",),
    },
    "cc": {
        "head": ("CC_Base_Head",),
        "neck": ("CC_Base_NeckTwist01",),
        "spine": ("CC_Base_Spine01",),
        "pelvis": ("CC_Base_L_Thigh", "CC_Base_R_Thigh"),
        "l_shoulder": ("CC_Base_L_Upperarm",), "r_shoulder": ("CC_Base_R_Upperarm",),
        "l_elbow": ("CC_Base_L_Forearm",), "r_elbow": ("CC_Base_R_Forearm",),
        "l_wrist": ("CC_Base_L_Hand",), "r_wrist": ("CC_Base_R_Hand",),
        "l_hip": ("CC_Base_L_Thigh",), "r_hip": ("CC_Base_R_Thigh",),
        "l_knee": ("CC_Base_L_Calf",), "r_knee": ("CC_Base_R_Calf",),
        "l_ankle": ("CC_Base_L_Foot",), "r_ankle": ("CC_Base_R_Foot",),
    },
}  # fmt: skip
# Rigs place the spine behind the hip centre (the lumbar spine is posterior); our skeleton
# puts it above. Trust the trunk's interior points less than the limb joints.
RETARGET_WEIGHTS = np.array([1.0 if n not in ("spine", "neck") else 0.1 for n in sk.JOINT_NAMES])
_ARM_STARTS = (0.0, 1.6, 2.6)  # shoulder abduction of the IK starts, radians
# The CC rig's head joint sits at the skull base; the head centre is this far above it.
_CC_HEAD_CENTRE_ABOVE_BASE = 0.10


def detect_rig(clip: MotionClip) -> str:
    """Which entry of :data:`RIG_JOINT_MAPS` fits the clip's joint names."""
    names = set(clip.joint_names)
    for rig, mapping in RIG_JOINT_MAPS.items():
        if all(src in names for srcs in mapping.values() for src in srcs):
            return rig
    raise ValueError(
        f"{clip.source}: unknown rig (joint names fit none of {', '.join(RIG_JOINT_MAPS)})"
    )


def clip_named_joints(clip: MotionClip) -> np.ndarray:
    """Named joints (``skeleton.JOINT_NAMES`` order) of every frame: (F, J, 3) metres."""
    mapping = RIG_JOINT_MAPS[detect_rig(clip)]
    out = np.stack(
        [clip.positions[:, [clip.index(s) for s in mapping[n]]].mean(1) for n in sk.JOINT_NAMES], 1
    )
    if mapping is RIG_JOINT_MAPS["cc"]:
        h, n = sk.JOINT_NAMES.index("head"), sk.JOINT_NAMES.index("neck")
        up = out[:, h] - out[:, n]
        up /= np.linalg.norm(up, axis=-1, keepdims=True).clip(1e-9)
        out[:, h] += _CC_HEAD_CENTRE_ABOVE_BASE * up
    return out


def body_from_named_joints(joints: np.ndarray, template: BodyShape | None = None) -> BodyShape:
    """Segment lengths measured from named joints (median over frames); radii from ``template``.

    Args:
        joints: (F, J, 3) or (J, 3) named joints.
        template: supplies radii and extents (defaults to the average adult), scaled by the
            measured leg length.
    Returns:
        an unbatched float32 :class:`BodyShape`.
    """
    template = BodyShape.default(torch.float64) if template is None else template.to(torch.float64)
    L, hip = segment_lengths_from_joints(joints)
    scale = (L[11] + L[13]) / (DEFAULT_LENGTHS[11] + DEFAULT_LENGTHS[13])
    body = BodyShape(
        torch.as_tensor(L),
        template.radii * scale,
        template.extents * scale,
        torch.tensor(hip, dtype=torch.float64),
    )
    body.validate()
    return body.to(torch.float32)


def root_frame_from_joints(joints: torch.Tensor) -> torch.Tensor:
    """Root orientation estimated from hips and trunk: rotation vectors (B, 3).

    Body x = right-to-left hip direction, y = pelvis-to-neck direction made orthogonal, z =
    x cross y (forward).
    """
    J = {n: joints[:, i] for i, n in enumerate(sk.JOINT_NAMES)}
    x = J["l_hip"] - J["r_hip"] + 0.5 * (J["l_shoulder"] - J["r_shoulder"])
    x = x / x.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    y = J["neck"] - J["pelvis"]
    y = y - (y * x).sum(-1, keepdim=True) * x
    y = y / y.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    z = torch.linalg.cross(x, y, dim=-1)
    return matrix_to_rotvec(torch.stack([x, y, z], -1))


def retarget_joints(
    joints: np.ndarray, body: BodyShape, iterations: int = 40, passes: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Poses q reproducing named joints, batched over frames.

    Every frame starts from the rest pose with the root placed and oriented from the hips
    and trunk; a second pass restarts the frames that stayed poor from their neighbour's
    solution (temporal continuity breaks the arm ambiguities of single frames).

    Args:
        joints: (F, J, 3) named joints in metres.
        body: the skeleton's body (see :func:`body_from_named_joints`).
    Returns:
        q (F, 34) float64 and the per-frame RMS joint error in metres (F,).
    """
    tj = torch.as_tensor(np.asarray(joints), dtype=torch.float64)
    b = body.to(torch.float64)
    q0 = torch.zeros(tj.shape[0], sk.NUM_DOFS, dtype=torch.float64)
    q0[:, 0:3] = tj[:, sk.JOINT_NAMES.index("pelvis")]
    q0[:, 3:6] = root_frame_from_joints(tj)
    weights = torch.as_tensor(RETARGET_WEIGHTS, dtype=torch.float64).expand(tj.shape[0], -1)
    # Several arm starts: from arms-down alone, raised arms fall into the wrong Euler branch.
    q, rms = None, None
    for abduction in _ARM_STARTS:
        init = q0.clone()
        init[:, sk.DOF_NAMES.index("l_humerus_abd")] = abduction
        init[:, sk.DOF_NAMES.index("r_humerus_abd")] = abduction
        res = fit_pose(tj, init, b, weights=weights, q_ref=q0, iterations=iterations)
        if q is None:
            q, rms = res.q, res.rms
        else:
            better = res.rms < rms
            q = torch.where(better[:, None], res.q, q)
            rms = torch.where(better, res.rms, rms)
    for _ in range(passes - 1):
        if q.shape[0] < 2:
            break
        prev = torch.cat([q[:1], q[:-1]])
        nxt = torch.cat([q[1:], q[-1:]])
        for cand in (prev, nxt):
            init = torch.cat([q0[:, :6], cand[:, 6:]], 1)
            alt = fit_pose(tj, init, b, weights=weights, q_ref=q0, iterations=iterations)
            better = alt.rms < rms
            q = torch.where(better[:, None], alt.q, q)
            rms = torch.where(better, alt.rms, rms)
    return q.numpy(), rms.numpy()
