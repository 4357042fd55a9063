"""Where the forest sees each joint's body parts, measured from the tracked joint.

The tracker's own evidence for a joint (``runtime.tracker.joint_support``) asks whether the
model's surface near the joint lies on the depth image. A limb can lie on the right depth in the
wrong place: an arm laid along the torso's side, a leg on the other leg. The forest labels the
pixels independently of the fit, so the distance from a tracked joint to the nearest pixels
the forest gives that joint's parts says whether the two agree: a wrist 30 cm from every
pixel labelled its forearm is rarely where the model put it. The count of those pixels says
how much the forest saw of the parts at all (none: hidden or out of view).

Per joint ``j``: ``near_m``, the ``k``-th smallest distance (metres, :data:`NEAREST_K`, so a few
stray labels do not count) from the joint to a pixel labelled one of its parts
(:data:`JOINT_PARTS`), inf where fewer than ``k`` such pixels exist; and ``count``, the number
of such pixels. Read by version 3 of the joint confidence (``shared.joint_confidence``).
"""

from __future__ import annotations

import numpy as np
import torch

from . import skeleton as sk
from .camera import Intrinsics, masked_points
from .compiled import compiled_module
from .labels import PART_NAMES

__all__ = ["JOINT_PARTS", "NEAREST_K", "image_part_evidence", "part_distances", "part_membership"]

# The forest's parts (``shared.labels.PART_NAMES``) whose pixels lie around each named joint:
# the trunk's joints their own part, the limbs' joints the segments either side (the forest
# has no hand or foot parts: a wrist is the forearm's end, an ankle the shank's).
JOINT_PARTS: dict[str, tuple[str, ...]] = {
    "head": ("head",),
    "neck": ("neck",),
    "spine": ("abdomen", "chest"),
    "pelvis": ("pelvis",),
    "l_shoulder": ("l_clavicle", "l_upper_arm"),
    "r_shoulder": ("r_clavicle", "r_upper_arm"),
    "l_elbow": ("l_upper_arm", "l_forearm"),
    "r_elbow": ("r_upper_arm", "r_forearm"),
    "l_wrist": ("l_forearm",),
    "r_wrist": ("r_forearm",),
    "l_hip": ("l_thigh_upper", "pelvis"),
    "r_hip": ("r_thigh_upper", "pelvis"),
    "l_knee": ("l_thigh_lower", "l_shank_upper"),
    "r_knee": ("r_thigh_lower", "r_shank_upper"),
    "l_ankle": ("l_shank_lower",),
    "r_ankle": ("r_shank_lower",),
}
# The k-th nearest labelled pixel is read, not the nearest: one stray label near the joint
# would otherwise confirm it.
NEAREST_K = 5


def _membership() -> np.ndarray:
    member = np.zeros((len(PART_NAMES), len(sk.JOINT_NAMES)), dtype=bool)
    for j, name in enumerate(sk.JOINT_NAMES):
        for part in JOINT_PARTS[name]:
            member[PART_NAMES.index(part), j] = True
    return member


# Built once: every frame reads it.
_MEMBER = _membership()


def part_membership(device: torch.device | None = None) -> torch.Tensor:
    """(C, J) bool: part class c is one of named joint j's parts (:data:`JOINT_PARTS`); a
    copy, the module's table stays as it is."""
    return torch.tensor(_MEMBER, device=device)


def part_distances(
    points: torch.Tensor, labels: torch.Tensor, joints: torch.Tensor, k: int = NEAREST_K
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each joint's ``k``-th nearest pixel of its parts, and how many there are.

    Args:
        points: (N, 3) camera-frame points of the person's labelled pixels, metres.
        labels: (N,) int part classes of those pixels (``shared.labels``; 0, background, and
            any value outside the classes is nobody's part, as in the compiled pass).
        joints: (J, 3) the named joints (``skeleton.JOINT_NAMES``), same frame.
        k: which nearest pixel to read (>= 1).
    Returns:
        near_m (J,) the distance in metres, inf with fewer than ``k`` pixels of the joint's
        parts; count (J,) the number of those pixels; both in ``joints``' dtype.
    """
    if k < 1:
        raise ValueError(f"k must be at least 1, got {k}")
    joints = torch.as_tensor(joints)
    labels = labels.long()
    known = (labels >= 0) & (labels < len(PART_NAMES))
    member = part_membership(points.device)[labels.clamp(0, len(PART_NAMES) - 1)]  # (N, J)
    member &= known[:, None]
    dist = torch.cdist(joints.to(points.dtype), points)  # (J, N)
    dist = torch.where(member.T, dist, torch.full_like(dist, float("inf")))
    count = member.sum(0).to(joints.dtype)
    if dist.shape[1] < k:  # fewer pixels than k in all: every joint lacks them
        return torch.full_like(count, float("inf")), count
    near = dist.topk(k, dim=1, largest=False).values[:, -1]
    return near.to(joints.dtype), count


def image_part_evidence(
    depth_m: torch.Tensor,
    mask: torch.Tensor,
    labels: torch.Tensor,
    intrinsics: Intrinsics,
    joints: torch.Tensor,
) -> torch.Tensor:
    """:func:`part_distances` of a frame: (J, 2) float64 (near_m, count) of ``joints`` (J, 3)
    against the labelled person pixels of ``depth_m`` (H, W, metres, 0: no reading), ``mask``
    (H, W) bool and ``labels`` (H, W) int, on the depth's device (a compiled pass on the CPU,
    :mod:`shared.part_evidence_kernel`, where numba is installed)."""
    if depth_m.device.type == "cpu" and depth_m.dtype == torch.float32:
        kernel = compiled_module("depthmocap.shared.part_evidence_kernel")
        if kernel is not None:
            intr = intrinsics
            out = kernel.part_evidence_cpu(
                depth_m.numpy(), mask.bool().numpy(), labels.long().numpy(),
                _MEMBER,
                np.array([intr.fx, intr.fy, intr.cx, intr.cy], np.float32),
                torch.as_tensor(joints, dtype=torch.float64).numpy(), NEAREST_K,
            )  # fmt: skip
            return torch.from_numpy(out)
    keep = mask.bool() & (depth_m > 0) & (labels > 0)
    points = masked_points(depth_m, keep, intrinsics)
    joints = torch.as_tensor(joints, dtype=torch.float64, device=depth_m.device)
    near, count = part_distances(points.double(), labels[keep], joints)
    return torch.stack([near, count], -1)
