"""Collision term (not in Wei): an arm's axis must not pass through the torso.

An arm the camera cannot see (the far arm in profile) is held only by the prior, and the
track folds it into the torso, where every data term is blind to it: on the 39 dev takes the
model's left arm axis lay inside the torso in 61% of the frames whose left wrist was more
than 20 cm off (42% deeper than 3 cm), against 4% deeper than 3 cm in the other frames, while
the ground-truth poses, posed on the same capsules, never put the upper arm's axis deeper than
1.1 cm inside. This term pushes sample points on each upper arm and forearm out of the
pelvis, abdomen and chest capsules: a point deeper than
``COLLISION_TOLERANCE_M`` gives the row ``n^T dp/dq dq = depth - tolerance`` along the
torso capsule's outward direction n at the point (the capsule's signed-distance gradient).
The hand half of the forearm has its own, larger tolerance
(``COLLISION_HAND_TOLERANCE_M``): hands rest on the hips and the belly (ground truth: up
to 3-6 cm inside at the wrist).

The penetration depth is a relative quantity, so only the degrees of freedom between the
torso capsule and the arm point move it; the ones they share (the root and, for the
abdomen and chest, the lower back) turn both together, and their Jacobian columns are dropped
(exact when the point lies on the torso's surface, where the row acts).
"""

from __future__ import annotations

import functools

import torch
from depthmocap.runtime.raycast import SegmentGeometry
from depthmocap.shared import skeleton as sk
from depthmocap.shared.compiled import compiled_float32
from depthmocap.shared.kinematics import Kinematics, segment_axis_points

from .gauss_newton import Rows
from .label_term import capsule_offsets

__all__ = [
    "ARM_SAMPLES",
    "HAND_SAMPLES",
    "TORSO_SEGMENTS",
    "SIGMA_COLLISION_M",
    "COLLISION_TOLERANCE_M",
    "COLLISION_HAND_TOLERANCE_M",
    "arm_sample_points",
    "collision_rows",
]

# Noise scale per arm sample point, depth beyond the tolerance (m). Strong: a hidden arm has
# no data to hold it, and the forest's arm labels on the torso pull it in (at 5 mm arm axes
# still lay 3-5 cm inside).
SIGMA_COLLISION_M = 0.001
# Arm axis points may lie this deep inside the torso capsules before the term acts (m): the
# capsules only approximate the body (ground-truth poses: upper arm axis at most 1.1 cm inside
# on the 39 dev takes).
COLLISION_TOLERANCE_M = 0.02
# The same for the hand half of each forearm (m): hands rest on the hips and the belly (ground
# truth: the wrist up to 3.4 cm inside in 1% of the 39 dev takes' frames).
COLLISION_HAND_TOLERANCE_M = 0.04

# (segment, fraction of its length from the joint) of the arm points kept out of the torso.
ARM_SAMPLES: tuple[tuple[int, float], ...] = tuple(
    (sk.SEGMENT_NAMES.index(f"{side}_{part}"), frac)
    for side in "lr"
    for part in ("upper_arm", "forearm")
    for frac in (0.25, 0.5, 0.75, 1.0)
)
# The samples on the hand half of a forearm, which get COLLISION_HAND_TOLERANCE_M.
HAND_SAMPLES: tuple[bool, ...] = tuple(
    sk.SEGMENT_NAMES[s].endswith("forearm") and frac > 0.5 for s, frac in ARM_SAMPLES
)
TORSO_SEGMENTS: tuple[int, ...] = tuple(
    sk.SEGMENT_NAMES.index(n) for n in ("pelvis", "abdomen", "chest")
)


@functools.cache
def _tables(dtype: torch.dtype, device: torch.device) -> dict[str, torch.Tensor]:
    """The term's constant tables on ``device``, made once: a copy from the host per call
    would make a GPU wait."""
    return {
        "segment": torch.as_tensor([s for s, _ in ARM_SAMPLES], device=device),
        "fraction": torch.as_tensor([f for _, f in ARM_SAMPLES], dtype=dtype, device=device),
        "hand": torch.as_tensor(HAND_SAMPLES, device=device),
        "torso": torch.as_tensor(TORSO_SEGMENTS, device=device),
        "affects": torch.as_tensor(sk.DOF_AFFECTS_SEGMENT, dtype=dtype, device=device),
    }


def arm_sample_points(kin: Kinematics) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-frame points on the arms' axes (:data:`ARM_SAMPLES`): (B, M, 3), and the
    segment each rides on, (M,) int64."""
    tables = _tables(kin.origins.dtype, kin.origins.device)
    seg = tables["segment"]
    return segment_axis_points(kin, seg, tables["fraction"]), seg


def collision_rows(kin: Kinematics, geom: SegmentGeometry) -> tuple[Rows, torch.Tensor]:
    """Rows of the collision term for B poses, and the Jacobian columns each row keeps:
    (:class:`Rows` of B * M rows, (B * M, 34) 0/1 mask for
    :func:`runtime.tracker.gauss_newton.normal_equations`).

    Points at most ``COLLISION_TOLERANCE_M`` (hand samples: ``COLLISION_HAND_TOLERANCE_M``)
    inside every torso capsule get zero weight (fixed row count: no branching on the data).
    """
    points, seg = arm_sample_points(kin)  # (B, M, 3)
    B, M = points.shape[:2]
    tables = _tables(points.dtype, points.device)
    torso = tables["torso"]
    kernel = compiled_float32("depthmocap.runtime.tracker.collision_kernel", points)
    if kernel is not None:  # one compiled call, the same rows and columns
        rot, origin = geom.frames(kin)
        *rows, columns = kernel.collision_rows_cpu(
                points, seg, torso, torch.as_tensor(HAND_SAMPLES), rot, origin, geom,
                (COLLISION_TOLERANCE_M, COLLISION_HAND_TOLERANCE_M, SIGMA_COLLISION_M),
            )  # fmt: skip
        return Rows(*rows), columns
    T = torso.shape[0]
    # Every (pose, point, torso capsule) triple, flattened: b and p index pose and capsule.
    b = torch.arange(B, device=points.device)[:, None, None].expand(B, M, T).reshape(-1)
    p = torso.expand(B, M, T).reshape(-1)
    rot, origin = geom.frames(kin)  # (B, P, 3, 3), (B, P, 3)
    signed, direction = capsule_offsets(
        points[:, :, None].expand(B, M, T, 3).reshape(-1, 3),
        rot[b, p],
        origin[b, p],
        geom.basis[p],
        geom.span.expand(B, -1, -1)[b, p],
        geom.scale.expand(B, -1, -1)[b, p],
    )
    signed, direction = signed.reshape(B, M, T), direction.reshape(B, M, T, 3)
    deepest = signed.argmin(-1)  # (B, M): the torso capsule the point is deepest in
    signed = signed.gather(-1, deepest[..., None])[..., 0]
    direction = direction.gather(2, deepest[..., None, None].expand(B, M, 1, 3))[:, :, 0]
    hand = tables["hand"]
    tolerance = torch.where(hand, COLLISION_HAND_TOLERANCE_M, COLLISION_TOLERANCE_M).to(
        points.dtype
    )
    excess = (-tolerance - signed).clamp_min(0.0)  # (B, M)
    weight = (excess > 0).to(points.dtype) / SIGMA_COLLISION_M
    batch = torch.arange(B, device=points.device).repeat_interleave(M)
    affects = tables["affects"]
    columns = 1.0 - affects[torso[deepest].reshape(-1)]  # drop the DoFs the torso moves with
    rows = Rows(
        batch,
        points.reshape(-1, 3),
        seg.repeat(B),
        direction.reshape(-1, 3),
        excess.reshape(-1),
        weight.reshape(-1),
    )
    return rows, columns
