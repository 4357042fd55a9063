"""What a tracking result is compared with: a recording's ground truth, or failing that its
reference skeleton (another tracker's estimate, e.g. the Kinect SDK's on real data).

Both become a :class:`Truth` under our joint names, so the evaluation's matching, offset
normalization and metrics are the same code for either; only the words differ: against a
reference the figures are *agreement* with another tracker, not accuracy, and the report and
the printed table say so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from depthmocap.shared.recording import Recording, RecordingError, mapped_reference

__all__ = ["Truth", "GROUND_TRUTH", "REFERENCE", "recording_truth", "shared_joints"]

GROUND_TRUTH = "ground_truth"
REFERENCE = "reference"


@dataclass(frozen=True)
class Truth:
    """The joints a result is scored against.

    Attributes:
        kind: :data:`GROUND_TRUTH` or :data:`REFERENCE`.
        joints: (F, J, 3) camera metres, F = the recording's frames.
        joint_names: J names (ours for a reference, through its joint map).
        q: (F, 34) poses of the ground truth, or None (a reference has none).
        source: what produced them (``groundtruth.npz``, or the reference's own ``source``).
        unmapped: the reference's joints with no counterpart among ours (not evaluated).
    """

    kind: str
    joints: np.ndarray
    joint_names: tuple[str, ...]
    q: np.ndarray | None
    source: str
    unmapped: tuple[str, ...] = ()


def recording_truth(rec: Recording) -> Truth:
    """The recording's ground truth if it has one, else its reference.

    Raises:
        RecordingError: neither file, or a malformed one.
    """
    if rec.has_groundtruth:
        gt = rec.groundtruth()
        q = np.asarray(gt["q"], dtype=np.float64) if "q" in gt else None
        names = tuple(str(n) for n in gt["joint_names"])
        return Truth(GROUND_TRUTH, np.asarray(gt["joints"]), names, q, "groundtruth.npz")
    if rec.has_reference:
        ref = rec.reference()
        joints, names = mapped_reference(ref)
        mapped = {str(theirs) for theirs in np.asarray(ref["joint_map"])[:, 1]}
        unmapped = tuple(str(n) for n in ref["joint_names"] if str(n) not in mapped)
        return Truth(REFERENCE, joints, names, None, str(ref["source"]), unmapped)
    raise RecordingError(
        f"{rec.path}: recording has no ground truth (groundtruth.npz) and no reference "
        "skeleton (reference.npz) to compare with"
    )


def shared_joints(truth: Truth, result) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The J joints ``truth`` and a loaded result (:class:`~.result_io.TrackingResult`)
    share, in the truth's order, and both sides' positions over the result's N written
    frames: ``(names, ours (N, J, 3), true (N, J, 3))``, NaN where the result has no pose.

    Raises:
        ValueError: no joint in common, or a result frame past the truth's last.
    """
    names = [n for n in truth.joint_names if n in result.joint_names]
    if not names:
        raise ValueError(f"the result and the {truth.kind} share no joint")
    if len(result.frame) and int(result.frame.max()) >= len(truth.joints):
        raise ValueError(f"the result has frames past the {truth.kind}'s last")
    ours = result.joints[:, [result.joint_names.index(n) for n in names]]
    true = np.asarray(truth.joints, dtype=np.float64)[result.frame]
    return names, ours, true[:, [truth.joint_names.index(n) for n in names]]
