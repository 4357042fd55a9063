"""Which named joints the camera confirms: observed (tracked) against inferred joints.

One depth camera cannot place a limb it does not see (Wei 2012, 7.4: a hidden segment's
joint angles "cannot be reliably estimated"); the tracker still reports a pose for it, from
the motion prior and the free space behind the visible surface. A user needs to know which
joints are measured and which are the model's guess, as the Kinect SDK's per-joint "tracked"
and "inferred" states tell. A joint counts as *observed* when the model's surface near it is
seen and confirmed by the depth image: the pixels where one of the segments meeting at the
joint is the front-most rendered surface, the observed depth agrees with it (Wei's region G,
within the depth gate), and the rendered point lies within the joint's radius of it in 3D.
Their area on the body, each pixel's footprint ``z^2 / (fx fy)`` summed, must reach a
threshold; an area, unlike a pixel count, does not depend on the working resolution or the
person's distance.

Depth agreement alone is not enough: a hidden arm that the tracker has laid on the torso or a
leg is rendered in front, at the depth the camera measures there, and would count as seen.
Where the forest's part labels are at hand (the hybrid computes them every frame), a pixel
counts only when the forest puts it on the same body group as the model's segment: the
torso with head and neck, or one of the four limbs (an arm with its clavicle). On the 39 dev
takes (``python -m depthmocap.train.evaluation.dev_benchmark --recordings data/dev_all``,
0.2 rad) that
took the failed frames counting only the joints called observed from 5.6% to 1.9%, while the flags
still cover 95% of the joints the camera sees (98.5% without the labels); the group, not the
segment, because the forest confuses the upper arm and forearm near the elbow.

The parts and radii are the evaluation's ground-truth visibility's
(:data:`shared.labels.JOINT_PARTS`): 10 cm at the limbs' joints, 15 cm at the hips, 20 cm at
the trunk's joints, whose centres lie well inside the body.
"""

from __future__ import annotations

import torch
from depthmocap.runtime.raycast import BodyRender
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.compiled import compiled_float32
from depthmocap.shared.kinematics import named_joint_positions
from depthmocap.shared.labels import JOINT_PARTS, PART_NAMES, PART_SEGMENT

from .regions import Regions, rendered_points

__all__ = ["JOINT_SUPPORT", "joint_support_cm2", "observed_joints"]

# Named joint -> (the model segments that meet at it, radius in metres): the segments of
# shared.labels.JOINT_PARTS' parts.
JOINT_SUPPORT: dict[str, tuple[tuple[str, ...], float]] = {
    joint: (
        tuple(dict.fromkeys(sk.SEGMENT_NAMES[PART_SEGMENT[PART_NAMES.index(p)]] for p in parts)),
        radius,
    )
    for joint, (parts, radius) in JOINT_PARTS.items()
}

# (S,) body group of each segment: torso with head and neck, left arm, right arm, left leg,
# right leg (the clavicles with their arms).
_GROUP = torch.tensor(
    [
        0 if name in ("pelvis", "abdomen", "chest", "neck", "head")
        else (1 if name[0] == "l" else 2) if name[2:] in ("clavicle", "upper_arm", "forearm")
        else (3 if name[0] == "l" else 4)
        for name in sk.SEGMENT_NAMES
    ]
)  # fmt: skip

# (S, 2) the joints each segment meets (no segment meets more than two), padded with J; the
# padded (J + 1,) radii are 0 there, so a pad never counts.
_MET = [
    [j for j, joint in enumerate(sk.JOINT_NAMES) if seg in JOINT_SUPPORT[joint][0]]
    for seg in sk.SEGMENT_NAMES
]
assert max(map(len, _MET)) <= 2
_SEGMENT_JOINTS = torch.tensor([(met + [len(sk.JOINT_NAMES)] * 2)[:2] for met in _MET])
_RADIUS = torch.tensor([JOINT_SUPPORT[joint][1] for joint in sk.JOINT_NAMES] + [0.0])


def joint_support_cm2(
    render: BodyRender, regions: Regions, intr: Intrinsics, labels: torch.Tensor | None = None
) -> torch.Tensor:
    """Area of each named joint's surface the depth image confirms (module docstring).

    Args:
        render: B poses rendered with ``intr`` (the working resolution).
        regions: their pixel classes against the observation; ``regions.good`` is G.
        intr: intrinsics of the rendering.
        labels: (B, H, W) int64 segment the forest labels each pixel as (-1: none), as in
            ``Observation.labels``; a pixel then counts only where that segment's body group
            is the rendered segment's. None: depth agreement alone.
    Returns:
        (B, J) float64 square centimetres, J = ``len(skeleton.JOINT_NAMES)``.
    """
    B, J = render.depth.shape[0], len(sk.JOINT_NAMES)
    idx = regions.good.nonzero()
    joints = named_joint_positions(render.kin)
    kernel = compiled_float32("depthmocap.runtime.tracker.support_kernel", render.depth, joints)
    if kernel is not None:
        padded = torch.cat([joints, joints.new_zeros(B, 1, 3)], 1)
        return kernel.joint_support_cpu(
            render.depth, render.segment, idx, intr, labels, _GROUP, padded, _SEGMENT_JOINTS,
            _RADIUS,
        )  # fmt: skip
    points, segment = rendered_points(render, idx, intr)
    seg = segment.clamp_min(0)
    b = idx[:, 0]
    counts = segment >= 0
    if labels is not None:
        said = labels[idx.unbind(1)]
        group = _GROUP.to(segment.device)
        counts = counts & (said >= 0) & (group[said.clamp_min(0)] == group[seg])
    # Each pixel is compared with the (at most two) joints its segment meets only.
    joints = torch.cat([joints, points.new_zeros(B, 1, 3)], 1)
    slots = _SEGMENT_JOINTS.to(seg.device)[seg]  # (N, 2) in [0, J]
    near = (points[:, None, :] - joints[b[:, None], slots]).norm(dim=-1) < _RADIUS.to(points)[slots]
    footprint = points[:, 2].double() ** 2 / (intr.fx * intr.fy) * 1e4  # cm^2 per pixel
    weight = (near & counts[:, None]).double() * footprint[:, None]
    area = torch.zeros(B * (J + 1), dtype=torch.float64, device=points.device)
    area.index_add_(0, (b[:, None] * (J + 1) + slots).reshape(-1), weight.reshape(-1))
    return area.reshape(B, J + 1)[:, :J]


def observed_joints(support_cm2: torch.Tensor, min_area_cm2: float) -> torch.Tensor:
    """(..., J) bool: joints whose confirmed area (:func:`joint_support_cm2`) reaches
    ``min_area_cm2``."""
    return support_cm2 >= min_area_cm2
