"""Putting back an arm the track has hidden behind the torso while the camera sees it.

In profile (jog, 4.2 m away) the tracker can slip the far arm behind the torso: the model
then shows none of it, the arm's real pixels are explained by a torso turned a little, and
the failure tests still pass, so the detector is never asked; the hidden arm drifts 20-35 cm
from the truth. The model's own rendering says which arm it hides
(:func:`runtime.tracker.signals.limb_visibility`) and the forest says whether the camera
sees that arm anyway; when both hold and the fit is suspect, the hybrid refines the frame
from each of a few arm poses (:func:`arm_candidates`) and keeps the best-fitting one.

The same search puts back an arm the track shows in the wrong place: laid on a leg or the
torso, it explains their pixels and passes every test, but the forest labels most of the
points it explains as something else (:func:`arm_label_conflict`).
"""

from __future__ import annotations

import math

import torch
from depthmocap.runtime.raycast import SegmentGeometry, segment_distances
from depthmocap.runtime.tracker.signals import LIMB_SEGMENTS
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import Kinematics, clamp_to_limits
from depthmocap.shared.labels import PART_NAMES

__all__ = [
    "AGREEMENT_MARGIN_M",
    "CONFLICT_MARGIN_M",
    "ARM_FLEXION_DEG",
    "ELBOW_FLEXION_DEG",
    "agreement_from_distances",
    "arm_candidates",
    "arm_label_agreement",
    "arm_label_conflict",
    "arm_pixel_fraction",
    "arm_pixels",
    "label_conflict_from_distances",
    "near_other_arm",
    "near_other_arm_from_distances",
]

# Starting arm poses: shoulder flexion (negative: the arm behind the body) x elbow flexion,
# abduction and twist at zero; a few tracker iterations take each from there.
ARM_FLEXION_DEG: tuple[float, ...] = (-40.0, 0.0, 40.0, 80.0)
ELBOW_FLEXION_DEG: tuple[float, ...] = (0.0, 90.0)

# A forest arm pixel counts as on the model's arm within this distance of its surface: about
# a forearm's radius, so labels on the torso next to the arm do not count.
AGREEMENT_MARGIN_M = 0.05

# An observed point belongs to the model's arm within this distance of its surface (and
# nearer to it than to any other part): the depth term's points the arm explains.
CONFLICT_MARGIN_M = 0.03

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


def arm_pixels(labels: torch.Tensor, mask: torch.Tensor, side: str) -> torch.Tensor:
    """Pixels of the person (``mask`` (H, W) bool) the forest labels (``labels`` (H, W)
    int) as the ``side`` arm: (H, W) bool."""
    upper, fore = _ARM_CLASSES[side]
    return ((labels == upper) | (labels == fore)) & mask


def arm_label_agreement(
    points: torch.Tensor,
    kin: Kinematics,
    body: BodyShape,
    side: str,
    margin_m: float,
    geom: SegmentGeometry | None = None,
) -> torch.Tensor:
    """Share of ``points`` (N, 3), the forest's pixels of the ``side`` arm, within
    ``margin_m`` of that arm's surface in the pose ``kin`` (batch B): (B,), NaN for N = 0.

    The fit's signals hardly tell a hidden arm's places apart (a refit 40 cm off can fit
    as well as the truth), but the forest's labels of that arm do: a refit that leaves
    them farther from the arm than the track does has moved the arm somewhere else.
    ``geom``: the body's ``segment_geometry``, when the caller keeps it.
    """
    ref = kin.origins
    flat = points.to(ref).expand(ref.shape[0], -1, -1)
    signed = segment_distances(flat, kin, body.to(dtype=ref.dtype, device=ref.device), geom)
    return agreement_from_distances(signed, side, margin_m)


def agreement_from_distances(signed: torch.Tensor, side: str, margin_m: float) -> torch.Tensor:
    """:func:`arm_label_agreement` from the arm pixels' signed distances to every model part,
    ``signed`` (B, N, P) from :func:`runtime.raycast.segment_distances`."""
    segs = list(LIMB_SEGMENTS[0 if side == "l" else 1])
    near = signed[..., segs].min(-1).values < margin_m
    return near.to(signed.dtype).mean(-1)


def arm_label_conflict(
    points: torch.Tensor,
    labels: torch.Tensor,
    kin: Kinematics,
    body: BodyShape,
    side: str,
    margin_m: float,
    other_arm_counts: bool = True,
    geom: SegmentGeometry | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """How much of what the ``side`` arm explains the forest calls something else.

    Of the person's ``points`` (N, 3), with forest ``labels`` (N,) int, those whose nearest
    model part in the pose ``kin`` (batch B) is that arm and that lie within ``margin_m`` of
    its surface are the arm's points; the share of them the forest does not label as that
    arm, and their number, are returned: ((B,), (B,)), the share NaN where the arm has none.
    With ``other_arm_counts`` false, points labelled as the other arm count as the arm's
    own: the forest swaps left and right arms often (profile views), so such labels are weak
    evidence that the arm is misplaced.

    A track can lay a hidden or lost arm on a leg or the torso (kick: the forearm along the
    kicking thigh, 40-60 cm from the real one): the depth data fit, the failure signals
    pass, and only the forest, which labels those pixels leg or torso, says the arm is not
    there (dev takes: the forest labels 80-95% of a well placed visible arm's points as
    that arm). ``geom``: the body's ``segment_geometry``, when the caller keeps it.
    """
    ref = kin.origins
    flat = points.to(ref).expand(ref.shape[0], -1, -1)
    signed = segment_distances(flat, kin, body.to(dtype=ref.dtype, device=ref.device), geom)
    return label_conflict_from_distances(signed, labels, side, margin_m, other_arm_counts)


def label_conflict_from_distances(
    signed: torch.Tensor,
    labels: torch.Tensor,
    side: str,
    margin_m: float,
    other_arm_counts: bool = True,
    nearest: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`arm_label_conflict` from the points' signed distances to every model part,
    ``signed`` (B, N, P) from :func:`runtime.raycast.segment_distances`: one evaluation
    serves both arms. ``nearest``: ``signed.min(-1)`` (values, indices), when the caller
    keeps it for both arms."""
    segs = torch.as_tensor(list(LIMB_SEGMENTS[0 if side == "l" else 1]), device=signed.device)
    values, indices = signed.min(-1) if nearest is None else nearest
    own = torch.isin(indices, segs) & (values < margin_m)  # (B, N)
    mine = _ARM_CLASSES[side] if other_arm_counts else (*_ARM_CLASSES["l"], *_ARM_CLASSES["r"])
    other = ~torch.isin(labels, torch.as_tensor(mine, device=labels.device)).to(signed.device)
    count = own.sum(-1)
    share = (own & other).sum(-1).to(signed.dtype) / count.to(signed.dtype)
    return share, count


def arm_pixel_fraction(
    labels: torch.Tensor, mask: torch.Tensor, side: str, explained: torch.Tensor | None = None
) -> float:
    """Share of the person's pixels (``mask`` (H, W) bool) the forest labels (``labels``
    (H, W) int) as the ``side`` arm, leaving out those in ``explained`` (H, W) bool, if
    given; 0 for an empty mask."""
    arm = arm_pixels(labels, mask, side)
    if explained is not None:
        arm = arm & ~explained
    return float(arm.sum()) / max(1, int(mask.sum()))


def near_other_arm(
    points: torch.Tensor, kin: Kinematics, body: BodyShape, side: str, margin_m: float
) -> torch.Tensor:
    """Which ``points`` (..., 3) lie within ``margin_m`` of the model's other arm (the one
    that is not ``side``), ``kin`` being one pose (batch 1): (...) bool.

    Forest labels swap left and right; in profile the far arm's labels land on the near
    arm's pixels (grabHigh), and moving the hidden arm onto them puts both arms on one.
    Labelled pixels the other arm already explains are no evidence that ``side`` is seen.
    """
    flat = points.reshape(1, -1, 3)
    ref = kin.origins
    signed = segment_distances(flat.to(ref), kin, body.to(dtype=ref.dtype, device=ref.device))
    return near_other_arm_from_distances(signed[0], side, margin_m).reshape(points.shape[:-1])


def near_other_arm_from_distances(signed: torch.Tensor, side: str, margin_m: float) -> torch.Tensor:
    """:func:`near_other_arm` from the points' signed distances to every model part in the
    one pose, ``signed`` (N, P): (N,) bool."""
    other = LIMB_SEGMENTS[1 if side == "l" else 0]  # the right arm's segments, or the left's
    return signed[:, list(other)].min(-1).values < margin_m
