"""Putting back an arm the track has hidden behind the torso while the camera sees it.

In profile (jog, 4.2 m away) the tracker can slip the far arm behind the torso: the model
then shows none of it, the arm's real pixels are explained by a torso turned a little, and
the failure tests still pass, so the detector is never asked; the hidden arm drifts 20-35 cm
from the truth. The model's own rendering says which arm it hides
(:func:`runtime.tracker.signals.limb_visibility`) and the forest says whether the camera
sees that arm anyway; when both hold and the fit is suspect, the hybrid refines the frame
from each of a few arm poses (:func:`arm_candidates`) and keeps the best-fitting one.
"""

from __future__ import annotations

import math

import torch

from shared import skeleton as sk
from shared.kinematics import clamp_to_limits
from shared.labels import PART_NAMES

__all__ = ["ARM_FLEXION_DEG", "ELBOW_FLEXION_DEG", "arm_candidates", "arm_pixel_fraction"]

# Starting arm poses: shoulder flexion (negative: the arm behind the body) x elbow flexion,
# abduction and twist at zero; a few tracker iterations take each from there.
ARM_FLEXION_DEG: tuple[float, ...] = (-40.0, 0.0, 40.0, 80.0)
ELBOW_FLEXION_DEG: tuple[float, ...] = (0.0, 90.0)

# Forest classes of each arm: upper arm, forearm.
_ARM_CLASSES = {
    side: (PART_NAMES.index(f"{side}_upper_arm"), PART_NAMES.index(f"{side}_forearm"))
    for side in "lr"
}


def arm_candidates(q: torch.Tensor, side: str) -> torch.Tensor:
    """``q`` (34,) with the ``side`` ("l" or "r") arm set to each start pose: (K, 34).

    K = len(ARM_FLEXION_DEG) * len(ELBOW_FLEXION_DEG); every other degree of freedom (the
    clavicle included) keeps its value.
    """
    if side not in _ARM_CLASSES:
        raise ValueError(f"side must be 'l' or 'r', got {side!r}")
    idx = {n: sk.DOF_NAMES.index(f"{side}_{n}") for n in
           ("humerus_abd", "humerus_flex", "humerus_twist", "radius_flex")}  # fmt: skip
    starts = [(f, e) for f in ARM_FLEXION_DEG for e in ELBOW_FLEXION_DEG]
    out = q.detach().reshape(1, sk.NUM_DOFS).repeat(len(starts), 1)
    out[:, idx["humerus_abd"]] = 0.0
    out[:, idx["humerus_twist"]] = 0.0
    out[:, idx["humerus_flex"]] = q.new_tensor([math.radians(f) for f, _ in starts])
    out[:, idx["radius_flex"]] = q.new_tensor([math.radians(e) for _, e in starts])
    return clamp_to_limits(out)


def arm_pixel_fraction(labels: torch.Tensor, mask: torch.Tensor, side: str) -> float:
    """Share of the person's pixels (``mask`` (H, W) bool) the forest labels (``labels``
    (H, W) int) as the ``side`` arm; 0 for an empty mask."""
    upper, fore = _ARM_CLASSES[side]
    arm = ((labels == upper) | (labels == fore)) & mask
    return float(arm.sum()) / max(1, int(mask.sum()))
