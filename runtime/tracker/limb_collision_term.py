"""Limb collision term (not in Wei): a limb's axis must not pass through the other side's limb.

A limb the camera does not see is held only by the prior and by what it happens to explain.
In profile the far arm is laid onto the near one (and the far leg onto the near leg), where
both explain the same pixels equally well: on the broad protocol, of the gross errors (over
20 cm) whose true joint is hidden and whose estimate lies on a surface the camera sees, about
a third are a wrist, elbow, knee or ankle on the other side's same limb
(``train.evaluation.error_sources``). Two real limbs cannot share their space: this term
pushes sample points on each upper arm, forearm, thigh and shank out of the other side's two
capsules of the same limb, as :mod:`~runtime.tracker.collision_term` keeps the arms out of the
torso. A point deeper than ``LIMB_TOLERANCE_M`` inside gives the row ``n^T dp/dq dq = depth -
tolerance`` along that capsule's outward direction n; the hand and foot halves of forearms and
shanks get ``LIMB_HAND_TOLERANCE_M`` (hands clasp, feet cross). The DoFs both limbs move with
(root, lower back) are dropped from the row, so each side's rows move that side's limb only;
both sides have rows, and the limb the data hold stays.
"""

from __future__ import annotations

import torch
from depthmocap.runtime.raycast import SegmentGeometry
from depthmocap.shared import skeleton as sk
from depthmocap.shared.kinematics import Kinematics, segment_axis_points

from .gauss_newton import Rows
from .label_term import capsule_offsets

__all__ = ["LIMB_HAND_TOLERANCE_M", "LIMB_SAMPLES", "LIMB_TOLERANCE_M", "limb_collision_rows"]

# Axis points may lie this deep inside the other side's limb capsule before the term acts (m):
# limbs pressed together (knees in a squat) overlap as capsules by a centimetre or two.
LIMB_TOLERANCE_M = 0.02
# The same for the hand and foot halves of forearms and shanks (m): hands clasp and feet cross.
LIMB_HAND_TOLERANCE_M = 0.04
_LIMBS = (("upper_arm", "forearm"), ("thigh", "shank"))
# (segment, fraction of its length from the joint, the other side's two capsules, hand/foot).
LIMB_SAMPLES: tuple[tuple[int, float, tuple[int, int], bool], ...] = tuple(
    (
        sk.SEGMENT_NAMES.index(f"{side}_{part}"),
        frac,
        tuple(sk.SEGMENT_NAMES.index(f"{'r' if side == 'l' else 'l'}_{p}") for p in limb),
        part == limb[1] and frac > 0.5,
    )
    for limb in _LIMBS
    for side in "lr"
    for part in limb
    for frac in (0.25, 0.5, 0.75, 1.0)
)


def limb_collision_rows(kin: Kinematics, geom: SegmentGeometry) -> tuple[Rows, torch.Tensor]:
    """Rows of the term for B poses and the Jacobian columns each keeps: (:class:`Rows` of
    B * M rows, (B * M, 34) 0/1 mask); points no deeper than their tolerance in both of the
    other side's capsules get zero weight (a fixed row count)."""
    dev, dtype = kin.origins.device, kin.origins.dtype
    seg = torch.as_tensor([s for s, _, _, _ in LIMB_SAMPLES], device=dev)
    frac = torch.as_tensor([f for _, f, _, _ in LIMB_SAMPLES], dtype=dtype, device=dev)
    other = torch.as_tensor([o for _, _, o, _ in LIMB_SAMPLES], device=dev)  # (M, 2)
    hand = torch.as_tensor([h for _, _, _, h in LIMB_SAMPLES], device=dev)
    points = segment_axis_points(kin, seg, frac)  # (B, M, 3)
    B, M = points.shape[:2]
    T = other.shape[1]
    b = torch.arange(B, device=dev)[:, None, None].expand(B, M, T).reshape(-1)
    p = other[None].expand(B, M, T).reshape(-1)
    rot, origin = geom.frames(kin)
    signed, direction = capsule_offsets(
        points[:, :, None].expand(B, M, T, 3).reshape(-1, 3),
        rot[b, p],
        origin[b, p],
        geom.basis[p],
        geom.span.expand(B, -1, -1)[b, p],
        geom.scale.expand(B, -1, -1)[b, p],
    )
    signed, direction = signed.reshape(B, M, T), direction.reshape(B, M, T, 3)
    deepest = signed.argmin(-1)  # (B, M)
    signed = signed.gather(-1, deepest[..., None])[..., 0]
    direction = direction.gather(2, deepest[..., None, None].expand(B, M, 1, 3))[:, :, 0]
    tolerance = torch.where(hand, LIMB_HAND_TOLERANCE_M, LIMB_TOLERANCE_M).to(dtype)
    excess = (-tolerance - signed).clamp_min(0.0)
    weight = (excess > 0).to(dtype) / _sigma()
    capsule = other[None].expand(B, M, T).gather(-1, deepest[..., None])[..., 0]  # (B, M)
    affects = torch.as_tensor(sk.DOF_AFFECTS_SEGMENT, dtype=dtype, device=dev)
    columns = 1.0 - affects[capsule.reshape(-1)]  # drop the DoFs both limbs move with
    rows = Rows(
        torch.arange(B, device=dev).repeat_interleave(M),
        points.reshape(-1, 3),
        seg.repeat(B),
        direction.reshape(-1, 3),
        excess.reshape(-1),
        weight.reshape(-1),
    )
    return rows, columns


def _sigma() -> float:
    from .collision_term import SIGMA_COLLISION_M

    return SIGMA_COLLISION_M
