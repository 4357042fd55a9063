"""Hidden-arm prior (not in Wei): an arm the forest does not see is pulled towards a relaxed pose.

When the camera sees none of an arm (the far arm in profile, an arm behind a torso bent
forward), the depth terms only say that the arm lies somewhere behind the visible surface, and
Wei 7.4 notes that such a segment's angles are "often ambiguous". Left to the
constant-acceleration prior and to whatever surface the arm lands on, the tracker bends it to
its limits (elbow flexed 60-140 degrees, the twist at -100) or lays its forearm on a visible
leg: on the full dev set (``make dev-recordings-all``) most system-failure frames were such
arms, 20-80 cm off. The people's hidden arms were mostly hanging near rest (shoulder raised
0-30 degrees, elbow 0-30 degrees), the most likely place for an arm nothing shows.

So, for each frame and arm, the share of the person's pixels the forest labels as that arm
(upper arm or forearm) decides whether it is hidden; a hidden arm's four angles get a
Gaussian pull towards ``REST_ARM_DEG`` with noise scale ``sigma_hidden_arm_rad``, added to the
normal equations as a diagonal like the constant-acceleration prior. The data terms still act
on the arm: they keep it out of sight, the pull only chooses where behind the surface.
"""

from __future__ import annotations

import math

import torch

from shared import skeleton as sk

__all__ = ["REST_ARM_DEG", "arm_label_shares", "hidden_arm_weights", "rest_pull_system"]

# Relaxed arm (abduction, flexion, twist, elbow flexion), degrees: q = 0 is the arm hanging
# straight down; people's relaxed arms sit a little out and forward with the elbow bent.
REST_ARM_DEG: tuple[float, float, float, float] = (10.0, 15.0, 0.0, 20.0)

_ARM_DOF_NAMES = ("humerus_abd", "humerus_flex", "humerus_twist", "radius_flex")
# (2, 4) q indices of each arm's angles, left then right.
_ARM_DOFS = tuple(tuple(sk.DOF_NAMES.index(f"{s}_{n}") for n in _ARM_DOF_NAMES) for s in "lr")
# (2, 2) segments of each arm, left then right.
_ARM_SEGMENTS = tuple(
    (sk.SEGMENT_NAMES.index(f"{s}_upper_arm"), sk.SEGMENT_NAMES.index(f"{s}_forearm")) for s in "lr"
)


def arm_label_shares(segments: torch.Tensor, person: torch.Tensor) -> torch.Tensor:
    """Share of each frame's person pixels labelled as each arm: (B, 2), left then right.

    Args:
        segments: (B, H, W) int64 segment the forest labels each pixel as (-1: none).
        person: (B, H, W) bool person pixels; frames without any have shares 0.
    """
    arms = segments.new_tensor(_ARM_SEGMENTS)  # (2, 2)
    on_arm = (segments[..., None, None] == arms).any(-1) & person[..., None]  # (B, H, W, 2)
    count = on_arm.flatten(1, 2).sum(1).to(torch.float64)
    total = person.flatten(1).sum(1, keepdim=True).clamp_min(1).to(torch.float64)
    return count / total


def hidden_arm_weights(
    shares: torch.Tensor, hidden_share: float, sigma_rad: float, like: torch.Tensor
) -> torch.Tensor:
    """Squared weights (B, 34) of the rest pull: ``1 / sigma_rad^2`` on the angles of each arm
    whose label share (``shares`` (B, 2)) is below ``hidden_share``, 0 elsewhere; dtype and
    device of ``like``."""
    hidden = (shares < hidden_share).to(like.dtype)  # (B, 2)
    w2 = like.new_zeros(shares.shape[0], sk.NUM_DOFS)
    idx = torch.tensor(_ARM_DOFS, device=like.device)  # (2, 4)
    w2[:, idx.flatten()] = hidden.repeat_interleave(idx.shape[1], dim=1) / sigma_rad**2
    return w2


def rest_pull_system(q: torch.Tensor, w2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Diagonal (B, 34) and right-hand side (B, 34) of the pull ``w2 * (q_rest - q)^2`` towards
    the relaxed arms (every other angle's target is its own value, and its weight 0)."""
    rest = q.detach().clone()
    for dofs in _ARM_DOFS:
        rest[:, list(dofs)] = q.new_tensor([math.radians(a) for a in REST_ARM_DEG])
    return w2, w2 * (rest - q)
