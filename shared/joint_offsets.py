"""Where the output joints sit relative to the model's: a learned offset per joint and pose.

The cylinder model's joints are its segments' pivots (``kinematics.named_joint_positions``);
the joints a user expects are a motion-capture skeleton's (HDM05's: the spine joint higher on
the back, the hips wider and further forward, ...). Tracking puts the model where the depth
is, so the difference is a systematic offset in each joint's own segment frame: 20 mm to
9 cm on the dev recordings, most of the gap between raw and offset-normalized error.

:func:`offset_joints` moves each joint by its offset, turned with its segment and scaled with
the body's stature. The offset depends on the pose, because a capsule's pivot and a mocap joint
move apart as the limb bends and the tracker's own bias changes with the pose (fitted, it
removes 7-10 mm more than a constant offset on held-out tuning recordings): it is linear in the
pose's joint angles and their squares (:func:`pose_features`),
``offset_j(q) = offsets_m[j] + features(q) @ pose_coefficients_m[j]``. The offsets are fitted
from tracked synthetic recordings with ground truth (``python -m
depthmocap.train.evaluation.joint_offsets_fit``) and shipped as ``models/joint_offsets.json``:

    {"format": "depthmocap-joint-offsets", "version": 2, "joint_names": [16 names],
     "reference_stature_m": 1.7, "offsets_m": [[x, y, z] x 16],
     "pose_features": "angles_and_squares", "pose_coefficients_m": [[[x, y, z] x 56] x 16],
     "fitted_on": "...", "frames": 2847}

``offsets_m`` are in metres, in the frame of each joint's segment (``skeleton.JOINT_SEGMENT``),
for a body of ``reference_stature_m``; a body of another stature gets them scaled by the ratio.
Version 1 files (constant offsets: no ``pose_*`` keys) are still read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import skeleton as sk
from .json_file import read_json_file, write_json_file

__all__ = [
    "FORMAT",
    "NUM_POSE_FEATURES",
    "POSE_FEATURES",
    "VERSION",
    "JointOffsets",
    "JointOffsetsError",
    "apply_offsets",
    "load_joint_offsets",
    "offset_joints",
    "offsets_at",
    "pose_features",
    "save_joint_offsets",
]

FORMAT = "depthmocap-joint-offsets"
VERSION = 2
_READABLE = (1, 2)
POSE_FEATURES = "angles_and_squares"
NUM_POSE_FEATURES = 2 * (sk.NUM_DOFS - sk.ANGLE_DOFS.start)


def pose_features(q: torch.Tensor) -> torch.Tensor:
    """(B, 34) poses -> (B, P) features the offsets are linear in: the 28 joint angles, then
    their squares (P = :data:`NUM_POSE_FEATURES`). The root is left out: where the person
    stands and faces says nothing about where a joint sits on its segment."""
    angles = q[..., sk.ANGLE_DOFS]
    return torch.cat([angles, angles * angles], dim=-1)


class JointOffsetsError(ValueError):
    """A joint-offsets file that is missing, unreadable, of another format or version, or
    inconsistent."""


@dataclass
class JointOffsets:
    """Per-joint offsets (module docstring).

    Attributes:
        offsets_m: (J, 3) metres in each joint's segment frame, J = ``len(JOINT_NAMES)``:
            the offsets at the zero pose.
        reference_stature_m: the stature the offsets are for.
        pose_coefficients_m: (J, P, 3) how each offset changes with the pose's features
            (:func:`pose_features`), or None: constant offsets.
        fitted_on: what they were fitted on (free text, for the record).
        frames: how many frames they were fitted on.
    """

    offsets_m: np.ndarray
    reference_stature_m: float
    fitted_on: str = ""
    frames: int = 0
    pose_coefficients_m: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.offsets_m = np.asarray(self.offsets_m, dtype=np.float64)
        J = len(sk.JOINT_NAMES)
        if self.offsets_m.shape != (J, 3) or not np.isfinite(self.offsets_m).all():
            raise JointOffsetsError(
                f"joint offsets must be {J} finite (x, y, z) rows, got {self.offsets_m.shape}"
            )
        if self.pose_coefficients_m is not None:
            c = np.asarray(self.pose_coefficients_m, dtype=np.float64)
            if c.shape != (J, NUM_POSE_FEATURES, 3) or not np.isfinite(c).all():
                raise JointOffsetsError(
                    f"pose coefficients must be finite, ({J}, {NUM_POSE_FEATURES}, 3), got "
                    f"{c.shape}"
                )
            self.pose_coefficients_m = c
        ok = math.isfinite(self.reference_stature_m) and self.reference_stature_m > 0
        if not ok:
            raise JointOffsetsError(
                f"reference_stature_m must be positive, got {self.reference_stature_m}"
            )

    def to_json_dict(self) -> dict:
        data = {
            "format": FORMAT,
            "version": VERSION,
            "joint_names": list(sk.JOINT_NAMES),
            "reference_stature_m": float(self.reference_stature_m),
            "offsets_m": np.round(self.offsets_m, 6).tolist(),
        }
        if self.pose_coefficients_m is not None:
            data["pose_features"] = POSE_FEATURES
            data["pose_coefficients_m"] = np.round(self.pose_coefficients_m, 7).tolist()
        return {**data, "fitted_on": self.fitted_on, "frames": int(self.frames)}


def save_joint_offsets(path: str | Path, offsets: JointOffsets) -> None:
    """Write ``offsets`` as JSON (atomically: a reader never sees half a file)."""
    write_json_file(path, offsets.to_json_dict())


def load_joint_offsets(path: str | Path) -> JointOffsets:
    """Read a joint-offsets file.

    Raises:
        JointOffsetsError: missing or unreadable file, another format or version, joint names
            other than this build's, or bad values.
    """
    path = Path(path)
    data = read_json_file(path, "joint-offsets", JointOffsetsError)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise JointOffsetsError(f"{path}: not a {FORMAT} file")
    if data.get("version") not in _READABLE:
        raise JointOffsetsError(
            f"{path}: joint-offsets version {data.get('version')!r}, this build reads "
            f"{', '.join(map(str, _READABLE))}"
        )
    if data.get("joint_names") != list(sk.JOINT_NAMES):
        raise JointOffsetsError(f"{path}: its joints are not this build's {list(sk.JOINT_NAMES)}")
    coefficients = data.get("pose_coefficients_m")
    if coefficients is not None and data.get("pose_features") != POSE_FEATURES:
        raise JointOffsetsError(
            f"{path}: pose features {data.get('pose_features')!r}, this build has {POSE_FEATURES!r}"
        )
    try:
        return JointOffsets(
            np.asarray(data.get("offsets_m"), dtype=np.float64),
            float(data.get("reference_stature_m")),
            str(data.get("fitted_on", "")),
            int(data.get("frames", 0)),
            None if coefficients is None else np.asarray(coefficients, dtype=np.float64),
        )
    except (TypeError, ValueError) as err:
        raise JointOffsetsError(f"{path}: {err}") from None


def offsets_at(
    q: torch.Tensor, offsets: torch.Tensor, coefficients: torch.Tensor | None
) -> torch.Tensor:
    """(B, J, 3) each joint's offset at poses ``q`` (B, 34), from the zero-pose ``offsets``
    (J, 3) and the ``coefficients`` (J, P, 3) of :func:`pose_features` (None: constant)."""
    offsets = offsets.to(q)
    if coefficients is None:
        return offsets.expand(q.shape[0], -1, -1)
    return offsets + torch.einsum("bp,jpc->bjc", pose_features(q), coefficients.to(q))


def offset_joints(
    joints: torch.Tensor, rotations: torch.Tensor, offsets: torch.Tensor, scale: torch.Tensor
) -> torch.Tensor:
    """The model's joints moved by their offsets.

    Args:
        joints: (B, J, 3) the model's named joints (``named_joint_positions``).
        rotations: (B, S, 3, 3) segment rotations of the same poses (``Kinematics.rotations``).
        offsets: (J, 3), or (B, J, 3) per pose (:func:`offsets_at`), metres in each joint's
            segment frame, for the reference stature.
        scale: (B,) or () the body's stature over the reference stature.
    Returns:
        (B, J, 3) ``joints + scale R_seg(j) offsets_j``.
    """
    seg = torch.as_tensor(sk.JOINT_SEGMENT, dtype=torch.long, device=joints.device)
    rot = rotations[:, seg]  # (B, J, 3, 3)
    offsets = offsets.to(joints)
    offsets = offsets[None] if offsets.dim() == 2 else offsets
    moved = (rot @ offsets[..., None])[..., 0]
    return joints + torch.as_tensor(scale).to(joints).reshape(-1, 1, 1) * moved


def apply_offsets(
    joints: torch.Tensor,
    rotations: torch.Tensor,
    q: torch.Tensor,
    offsets: JointOffsets,
    stature: torch.Tensor | float,
) -> torch.Tensor:
    """The model's joints of poses ``q`` (B, 34) moved by ``offsets`` at those poses, for a
    body of ``stature`` ((B,) or (), metres): :func:`offsets_at`, then :func:`offset_joints`.
    Computed in ``joints``' dtype and device.

    Args:
        joints: (B, J, 3) the model's named joints; rotations: (B, S, 3, 3) segment rotations.
    Returns:
        (B, J, 3).
    """
    coef = offsets.pose_coefficients_m
    per_pose = offsets_at(
        q.to(joints),
        torch.as_tensor(offsets.offsets_m).to(joints),
        None if coef is None else torch.as_tensor(coef).to(joints),
    )
    scale = torch.as_tensor(stature).to(joints) / offsets.reference_stature_m
    return offset_joints(joints, rotations, per_pose, scale)
