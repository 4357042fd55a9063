"""Collision term (not in Wei): an arm's axis must not pass through the torso, nor a leg's
through the other leg.

An arm the camera cannot see (the far arm in profile) is held only by the prior, and the
track folds it into the torso, where every data term is blind to it: on the 39 dev takes the
model's left arm axis lay inside the torso in 61% of the frames whose left wrist was more
than 20 cm off (42% deeper than 3 cm), against 4% deeper than 3 cm in the other frames, while
the ground-truth poses, posed on the same capsules, never put the upper arm's axis deeper than
1.1 cm inside. This term pushes sample points on each upper arm and forearm out of the
pelvis, abdomen and chest capsules: a point deeper than
``COLLISION_TOLERANCE_M`` gives the row ``n^T dp/dq dq = depth - tolerance`` along the
target capsule's outward direction n at the point (the capsule's signed-distance gradient).
The hand half of the forearm has its own, larger tolerance
(``COLLISION_HAND_TOLERANCE_M``): hands rest on the hips and the belly (ground truth: up
to 3-6 cm inside at the wrist).

The far leg in profile fails the same way: the detector or the track lays it onto the near
leg, where the depth cannot tell them apart (broad protocol, shipped system: the two legs'
axes closer than 6 cm in 1.8% of the frames, every one of them a frame with a leg joint more
than 20 cm off; the ground truth never brings them closer than 17 cm). With ``legs`` the
samples on each thigh and shank are kept out of the other leg's thigh and shank capsules, up
to ``COLLISION_LEG_TOLERANCE_M`` inside: legs that touch (knees or ankles together) keep
their axes a capsule radius or more apart, deeper is interpenetration.

The penetration depth is a relative quantity, so only the degrees of freedom between the
target capsule and the sample point move it; the ones they share (the root and, for the
abdomen and chest, the lower back) turn both together, and their Jacobian columns are dropped
(exact when the point lies on the capsule's surface, where the row acts). A leg's row moves
only the leg the point rides on; the other leg gets its own rows from its own samples.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

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
    "LEG_SAMPLES",
    "TORSO_SEGMENTS",
    "SIGMA_COLLISION_M",
    "COLLISION_TOLERANCE_M",
    "COLLISION_HAND_TOLERANCE_M",
    "COLLISION_LEG_TOLERANCE_M",
    "CollisionSamples",
    "collision_samples",
    "sample_tolerances",
    "arm_sample_points",
    "collision_sample_points",
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

# Leg axis points may lie this deep inside the other leg's thigh and shank capsules (m): 0
# keeps axes a capsule radius apart (shank 5.5 cm, thigh 8 cm on the average body), so legs
# pressed together stay legal and only a leg laid into the other is pushed out.
COLLISION_LEG_TOLERANCE_M = 0.0

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
# (segment, fraction) of the leg points kept out of the other leg: the knee end of each thigh
# (its hip end is a hip width from the other leg) and each shank down to the ankle.
LEG_SAMPLES: tuple[tuple[int, float], ...] = tuple(
    (sk.SEGMENT_NAMES.index(f"{side}_{part}"), frac)
    for side in "lr"
    for part, fracs in (("thigh", (0.5, 1.0)), ("shank", (0.5, 1.0)))
    for frac in fracs
)


def _other_leg(segment: int) -> tuple[int, int, int]:
    """The capsules a leg sample on ``segment`` stays out of: the other leg's thigh and shank
    (the shank twice: every sample has as many targets as an arm's, 3)."""
    other = "r" if sk.SEGMENT_NAMES[segment].startswith("l_") else "l"
    thigh, shank = (sk.SEGMENT_NAMES.index(f"{other}_{p}") for p in ("thigh", "shank"))
    return thigh, shank, shank


@dataclass(frozen=True)
class CollisionSamples:
    """The term's M sample points and what each is kept out of (segments double as capsule
    indices: the first 15 primitives are the segments' own).

    Attributes:
        segment: (M,) the segment each sample rides on.
        fraction: (M,) its place along the segment's length from the joint.
        targets: (M, 3) the capsules it is kept out of (the deepest one acts).
        kind: (M,) 0 arm, 1 hand half of a forearm, 2 leg: which tolerance applies.
    """

    segment: tuple[int, ...]
    fraction: tuple[float, ...]
    targets: tuple[tuple[int, int, int], ...]
    kind: tuple[int, ...]


@functools.cache
def collision_samples(legs: bool = False) -> CollisionSamples:
    """The arm samples (:data:`ARM_SAMPLES`, against the torso), then with ``legs`` the leg
    samples (:data:`LEG_SAMPLES`, against the other leg)."""
    arms = [(s, f, TORSO_SEGMENTS, 1 if h else 0) for (s, f), h in zip(ARM_SAMPLES, HAND_SAMPLES)]
    leg = [(s, f, _other_leg(s), 2) for s, f in LEG_SAMPLES] if legs else []
    return CollisionSamples(*(tuple(c) for c in zip(*(arms + leg))))


def sample_tolerances(
    samples: CollisionSamples, leg_tolerance: float | None = None
) -> tuple[float, ...]:
    """Each sample's tolerance (m), from the module's constants as they are now (tests patch
    them); ``leg_tolerance`` replaces ``COLLISION_LEG_TOLERANCE_M`` for the leg samples."""
    leg = COLLISION_LEG_TOLERANCE_M if leg_tolerance is None else leg_tolerance
    by_kind = (COLLISION_TOLERANCE_M, COLLISION_HAND_TOLERANCE_M, leg)
    return tuple(by_kind[k] for k in samples.kind)


@functools.cache
def _tables(
    dtype: torch.dtype, device: torch.device, legs: bool = False
) -> dict[str, torch.Tensor]:
    """The term's constant tables on ``device``, made once: a copy from the host per call
    would make a GPU wait."""
    samples = collision_samples(legs)
    return {
        "segment": torch.as_tensor(samples.segment, device=device),
        "fraction": torch.as_tensor(samples.fraction, dtype=dtype, device=device),
        "targets": torch.as_tensor(samples.targets, device=device),
        "affects": torch.as_tensor(sk.DOF_AFFECTS_SEGMENT, dtype=dtype, device=device),
    }


@functools.cache
def _tolerance_table(
    tolerances: tuple[float, ...], dtype: torch.dtype, device: torch.device
) -> torch.Tensor:
    """(M,) tolerances on ``device``, made once per set of values (not a host copy per
    iteration; tests patch the constants, which makes a new set)."""
    return torch.as_tensor(tolerances, dtype=dtype, device=device)


def collision_sample_points(
    kin: Kinematics, legs: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-frame points on the sampled axes (:func:`collision_samples`): (B, M, 3), and
    the segment each rides on, (M,) int64."""
    tables = _tables(kin.origins.dtype, kin.origins.device, legs)
    seg = tables["segment"]
    return segment_axis_points(kin, seg, tables["fraction"]), seg


def arm_sample_points(kin: Kinematics) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-frame points on the arms' axes (:data:`ARM_SAMPLES`): (B, M, 3), and the
    segment each rides on, (M,) int64."""
    return collision_sample_points(kin, legs=False)


def collision_rows(
    kin: Kinematics,
    geom: SegmentGeometry,
    legs: bool = False,
    leg_tolerance: float | None = None,
) -> tuple[Rows, torch.Tensor]:
    """Rows of the collision term for B poses, and the Jacobian columns each row keeps:
    (:class:`Rows` of B * M rows, (B * M, 34) 0/1 mask for
    :func:`runtime.tracker.gauss_newton.normal_equations`).

    Points at most their tolerance (:func:`sample_tolerances`) inside every target capsule
    get zero weight (fixed row count: no branching on the data). ``legs``: the leg samples
    too, ``leg_tolerance`` deep (m; None: ``COLLISION_LEG_TOLERANCE_M``).
    """
    points, seg = collision_sample_points(kin, legs)  # (B, M, 3)
    B, M = points.shape[:2]
    tables = _tables(points.dtype, points.device, legs)
    targets = tables["targets"]  # (M, T)
    allowed = _tolerance_table(
        sample_tolerances(collision_samples(legs), leg_tolerance), points.dtype, points.device
    )
    kernel = compiled_float32("depthmocap.runtime.tracker.collision_kernel", points)
    if kernel is not None:  # one compiled call, the same rows and columns
        rot, origin = geom.frames(kin)
        *rows, columns = kernel.collision_rows_cpu(
            points, seg, targets, allowed, rot, origin, geom, SIGMA_COLLISION_M
        )
        return Rows(*rows), columns
    T = targets.shape[1]
    # Every (pose, point, target capsule) triple, flattened: b and p index pose and capsule.
    b = torch.arange(B, device=points.device)[:, None, None].expand(B, M, T).reshape(-1)
    p = targets.expand(B, M, T).reshape(-1)
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
    deepest = signed.argmin(-1)  # (B, M): the target capsule the point is deepest in
    signed = signed.gather(-1, deepest[..., None])[..., 0]
    direction = direction.gather(2, deepest[..., None, None].expand(B, M, 1, 3))[:, :, 0]
    excess = (-allowed - signed).clamp_min(0.0)  # (B, M)
    weight = (excess > 0).to(points.dtype) / SIGMA_COLLISION_M
    batch = torch.arange(B, device=points.device).repeat_interleave(M)
    affects = tables["affects"]
    target = targets.gather(1, deepest.T).T  # (B, M)
    columns = 1.0 - affects[target.reshape(-1)]  # drop the DoFs the target moves with
    rows = Rows(
        batch,
        points.reshape(-1, 3),
        seg.repeat(B),
        direction.reshape(-1, 3),
        excess.reshape(-1),
        weight.reshape(-1),
    )
    return rows, columns
