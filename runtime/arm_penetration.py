"""How deep each arm's bones sink into the torso: a plausibility signal the data cannot give.

An arm hidden behind the torso leaves no pixels, so the depth, silhouette and label terms
say nothing about where it is, only where it is not (in front of the visible surface). The
tracker then often parks it *inside* the torso, where it is hidden as well: on the dev
recordings an arm's bone axis sank 2 cm or more into the torso's capsules in 53-83% of the
frames more than 20 cm off, against 1% of the others and never in the rendered ground truth
(at most 1.8 cm, where soft tissue meets). The hybrid uses this depth to search the arm's
pose again and to refuse refits that bury it (:mod:`runtime.hybrid`).

A penalty on the same depth inside the tracker's energy was tried before (README: the
self-collision term) and pushed the arm out through the nearest, visible side; here it only
ranks whole refits, each of which the data have already fitted.
"""

from __future__ import annotations

import torch

from runtime.raycast import segment_distances
from shared import skeleton as sk
from shared.body import BodyShape
from shared.kinematics import Kinematics, named_joint_positions

__all__ = ["ARM_SAMPLE_FRACTIONS", "TORSO_SEGMENTS", "arm_penetration"]

# The torso's primitives the arms may not enter.
TORSO_SEGMENTS: tuple[int, ...] = tuple(
    sk.SEGMENT_NAMES.index(n) for n in ("pelvis", "abdomen", "chest")
)

# Points sampled along each arm's axis, as fractions of the shoulder -> elbow -> wrist chain
# (0: shoulder, 1: elbow, 2: wrist); the shoulder itself sits at the torso's edge by design.
ARM_SAMPLE_FRACTIONS: tuple[float, ...] = (0.5, 1.0, 1.5, 2.0)

_CHAIN = {
    side: tuple(sk.JOINT_NAMES.index(f"{side}_{j}") for j in ("shoulder", "elbow", "wrist"))
    for side in "lr"
}


def _arm_points(joints: torch.Tensor, side: str) -> torch.Tensor:
    """Points along the ``side`` arm's axis: (B, len(ARM_SAMPLE_FRACTIONS), 3)."""
    chain = joints[:, list(_CHAIN[side])]  # (B, 3, 3) shoulder, elbow, wrist
    pts = []
    for f in ARM_SAMPLE_FRACTIONS:
        k = min(int(f), 1)  # the bone the point lies on: 0 upper arm, 1 forearm
        t = f - k
        pts.append(chain[:, k] + t * (chain[:, k + 1] - chain[:, k]))
    return torch.stack(pts, 1)


def arm_penetration(kin: Kinematics, body: BodyShape) -> torch.Tensor:
    """Depth (m) to which each arm's axis lies inside the torso, 0 when outside: (B, 2),
    left arm first.

    The depth of a sample point is minus its signed distance to the nearest torso capsule
    (:func:`runtime.raycast.segment_distances`: exact for circular sections, an upper bound
    for the elliptic chest); an arm's penetration is its deepest sample.
    """
    joints = named_joint_positions(kin)
    points = torch.cat([_arm_points(joints, s) for s in "lr"], 1)  # (B, 2S, 3)
    ref = kin.origins
    signed = segment_distances(points, kin, body.to(dtype=ref.dtype, device=ref.device))
    inside = (-signed[..., list(TORSO_SEGMENTS)].min(-1).values).clamp_min(0.0)  # (B, 2S)
    return inside.reshape(inside.shape[0], 2, -1).amax(-1)
