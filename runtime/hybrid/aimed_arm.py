"""An arm start aimed at the forest's pixels of that arm: the arm search's data-driven start.

The arm search's fixed starts (:func:`runtime.hybrid.arm_labels.arm_candidates`) sweep the
shoulder's flexion with the arm in the body's sagittal plane. An arm held out sideways or
reaching towards the camera (a throw's wind-up, a swing, a bowl: real takes' worst frames,
``docs/real_data.md``) lies between them, and a few tracker iterations from the nearest do
not reach it. Here the arm's own labelled pixels place it: the centroids of its upper arm's
and forearm's pixels, pushed behind the surface as the detector's are
(:func:`runtime.detector.centroids.class_centroids`), are the targets of an inverse
kinematics fit whose other markers hold every other named joint where the track has it. Only
the arm's four angles are taken from that fit; the rest of the start is the track's pose.
"""

from __future__ import annotations

import math

import torch
from depthmocap.runtime.detector.centroids import class_centroids, part_markers
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.ik import NAMED_JOINT_MARKERS, Markers, fit_pose
from depthmocap.shared.kinematics import clamp_to_limits, forward_kinematics, named_joint_positions
from depthmocap.shared.labels import PART_NAMES

__all__ = ["ARM_INITS_DEG", "aimed_arm_start"]

# Where the fit starts the arm besides the track's own angles (abduction, flexion, twist,
# elbow; degrees): out sideways, and reaching forward. The best fit of the three is the start.
ARM_INITS_DEG: tuple[tuple[float, float, float, float], ...] = (
    (90.0, 0.0, 0.0, 0.0),
    (0.0, 90.0, 0.0, 0.0),
)
_ARM_DOFS = ("humerus_abd", "humerus_flex", "humerus_twist", "radius_flex")


def _arm_dofs(side: str) -> list[int]:
    return [sk.DOF_NAMES.index(f"{side}_{n}") for n in _ARM_DOFS]


def aimed_arm_start(
    q: torch.Tensor, side: str, points: torch.Tensor, labels: torch.Tensor, body: BodyShape
) -> torch.Tensor:
    """``q`` (34,) with the ``side`` ("l" or "r") arm aimed at its labelled pixels: (K, 34),
    K = 1, or K = 0 when neither the upper arm nor the forearm has enough pixels.

    Args:
        q: the track's pose.
        points: (N, 3) camera-frame points of the arm's labelled pixels.
        labels: (N,) their part labels (the side's upper arm or forearm class).
        body: the body tracked (unbatched).
    """
    if side not in ("l", "r"):
        raise ValueError(f"side must be 'l' or 'r', got {side!r}")
    dt = torch.float64
    classes = [PART_NAMES.index(f"{side}_upper_arm"), PART_NAMES.index(f"{side}_forearm")]
    body64 = body.to(dtype=dt, device=q.device)
    cent = class_centroids(points.to(dt), labels, torch.ones_like(labels, dtype=torch.bool), body64)
    arm_w = cent.weights[[c - 1 for c in classes]]
    if not bool((arm_w > 0).any()):
        return q.new_zeros(0, sk.NUM_DOFS)
    q0 = q.detach().to(dt).reshape(1, sk.NUM_DOFS)
    joints = named_joint_positions(forward_kinematics(q0, body64))[0]  # (J, 3)
    hold = torch.ones(len(sk.JOINT_NAMES), dtype=dt, device=q.device)
    hold[[sk.JOINT_NAMES.index(f"{side}_{j}") for j in ("elbow", "wrist")]] = 0.0
    parts = part_markers(body64)
    markers = Markers(
        NAMED_JOINT_MARKERS.segment + tuple(parts.segment[c - 1] for c in classes),
        NAMED_JOINT_MARKERS.fraction + tuple(parts.fraction[c - 1] for c in classes),
    )
    targets = torch.cat([joints, cent.targets[[c - 1 for c in classes]]])
    weights = torch.cat([hold, arm_w])
    dofs = _arm_dofs(side)
    inits = q0.repeat(1 + len(ARM_INITS_DEG), 1)
    for k, angles in enumerate(ARM_INITS_DEG, start=1):
        inits[k, dofs] = torch.tensor([math.radians(a) for a in angles], dtype=dt)
    inits = clamp_to_limits(inits)
    fit = fit_pose(
        targets.expand(len(inits), -1, -1),
        inits,
        body64,
        weights.expand(len(inits), -1),
        markers,
        q_ref=q0.expand(len(inits), -1),
    )
    best = int(torch.argmin(fit.rms))
    start = q.detach().clone().reshape(1, sk.NUM_DOFS)
    start[0, dofs] = fit.q[best, dofs].to(start)
    return clamp_to_limits(start)
