"""Which ground-truth joints the camera sees, from a synthetic recording's part labels.

One depth camera cannot place a limb it does not see: "when a bone segment is not visible to
the current camera, its 3D joint angle value is often ambiguous and cannot be reliably
estimated" (Wei 2012, 7.4). The system failure rate counts every joint, seen or not; this
module lets the evaluation say which failed frames failed on a joint that was in view.

A joint is *visible* in a frame when at least ``min_pixels`` pixels labelled as one of the
parts meeting at it (:data:`JOINT_PARTS`), with a depth reading, lie within the joint's radius
of it in 3D. The radius spans the flesh between the joint centre and the surface the camera
sees: 10 cm at the limbs' joints (upper arm 5-6 cm, forearm 3.6 cm, thigh about 9 cm on the
dev bodies), 15 cm at the hips (inside the thigh's top) and 20 cm at the trunk's joints (the
spine lies some 5 cm behind the middle of a trunk 25 cm deep).
"""

from __future__ import annotations

import numpy as np
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.labels import JOINT_PARTS, PART_NAMES

__all__ = ["JOINT_PARTS", "visible_joints", "recording_joint_visibility"]


def visible_joints(
    depth_m: np.ndarray,
    labels: np.ndarray,
    joints: np.ndarray,
    joint_names: tuple[str, ...] | list[str],
    intr: Intrinsics,
    min_pixels: int = 5,
) -> np.ndarray:
    """Which joints one frame shows (module docstring).

    Args:
        depth_m: (H, W) metres, 0 = no reading; labels: (H, W) part labels
            (``shared.labels.PART_NAMES``); joints: (J, 3) ground-truth joints, camera frame.
        joint_names: (J,) names; a name not in :data:`JOINT_PARTS` counts as visible.
        intr: the recording's intrinsics; min_pixels: labelled pixels needed near a joint.
    Returns:
        (J,) bool.
    """
    depth = np.asarray(depth_m, dtype=np.float64)
    labels = np.asarray(labels)
    if depth.shape != labels.shape:
        raise ValueError(f"depth {depth.shape} and labels {labels.shape} differ in size")
    v, u = np.nonzero((depth > 0) & (labels > 0))
    z = depth[v, u]
    points = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], -1)
    part = labels[v, u]
    joints = np.asarray(joints, dtype=np.float64)
    out = np.ones(len(joint_names), dtype=bool)
    for j, name in enumerate(joint_names):
        if name not in JOINT_PARTS:
            continue
        parts, radius = JOINT_PARTS[name]
        ids = [PART_NAMES.index(p) for p in parts]
        near = np.linalg.norm(points[np.isin(part, ids)] - joints[j], axis=-1) < radius
        out[j] = int(near.sum()) >= min_pixels
    return out


def recording_joint_visibility(
    recording, joints: np.ndarray, joint_names: tuple[str, ...] | list[str], min_pixels: int = 5
) -> np.ndarray | None:
    """(F, J) bool visibility of the ground-truth ``joints`` (F, J, 3) in a recording's first F
    frames, or None when it has no part labels.

    Args:
        recording: a :class:`shared.recording.Recording` (its frames are read here).
    """
    if not recording.has_labels:
        return None
    return np.stack([
        visible_joints(
            recording.read_depth(f), recording.read_labels(f), joints[f], joint_names,
            recording.intrinsics, min_pixels,
        )
        for f in range(len(joints))
    ])  # fmt: skip
