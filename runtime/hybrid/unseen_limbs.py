"""Which joint angles an unseen limb keeps: the hybrid's ``hold_unseen_limbs``.

Wei's prior predicts every angle at constant velocity from the last two poses. For a limb the
camera does not see that velocity is whatever the limb last drifted at, and nothing stops it:
the broad protocol's largest share of gross error is unseen limbs placed wrong
(``train.evaluation.error_sources``). When the last tracked pose called a limb's far joints
inferred (``PoseEstimate.observed``: elbow and wrist, or knee and ankle), the hybrid predicts
that limb's angles at their last value instead: the data still move it where they reach it.
"""

from __future__ import annotations

import numpy as np
import torch
from depthmocap.shared.skeleton import DOF_NAMES, JOINT_NAMES

__all__ = ["HELD_LIMBS", "held_dofs", "hold_unseen"]

# (joints that must all be inferred, the angles then held): a whole arm or leg when its middle
# and end joints are unseen, the forearm or shank when only the end is.
HELD_LIMBS: tuple[tuple[tuple[str, ...], tuple[str, ...]], ...] = tuple(
    item
    for s in "lr"
    for item in (
        ((f"{s}_elbow", f"{s}_wrist"),
         tuple(f"{s}_humerus_{a}" for a in ("abd", "flex", "twist")) + (f"{s}_radius_flex",)),
        ((f"{s}_wrist",), (f"{s}_radius_flex",)),
        ((f"{s}_knee", f"{s}_ankle"),
         tuple(f"{s}_femur_{a}" for a in ("flex", "abd", "twist")) + (f"{s}_tibia_flex",)),
        ((f"{s}_ankle",), (f"{s}_tibia_flex",)),
    )
)  # fmt: skip
_INDEX = tuple(
    ([JOINT_NAMES.index(j) for j in joints], [DOF_NAMES.index(d) for d in dofs])
    for joints, dofs in HELD_LIMBS
)


def held_dofs(observed: np.ndarray | None) -> torch.Tensor | None:
    """(34,) bool: the angles of the limbs whose joints in :data:`HELD_LIMBS` the (16,)
    ``observed`` flags all call inferred; None without flags."""
    if observed is None:
        return None
    held = torch.zeros(len(DOF_NAMES), dtype=torch.bool)
    seen = np.asarray(observed, dtype=bool)
    for joints, dofs in _INDEX:
        if not seen[joints].any():
            held[dofs] = True
    return held


def hold_unseen(
    q_prev: torch.Tensor, q_prev2: torch.Tensor | None, held: torch.Tensor | None
) -> torch.Tensor | None:
    """The pose before ``q_prev`` (34,) as the prior should see it: ``q_prev2`` with the
    ``held`` angles at ``q_prev``'s, so their predicted velocity is zero."""
    if q_prev2 is None or held is None:
        return q_prev2
    return torch.where(held.to(q_prev2.device), q_prev, q_prev2)
