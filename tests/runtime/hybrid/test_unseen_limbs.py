"""Unseen limbs keep their angles (runtime.hybrid.unseen_limbs): which angles each pattern of
inferred joints holds (golden) and the prior's pose before (the hybrid passing it on:
test_hybrid.py)."""

from __future__ import annotations

import numpy as np
import torch
from depthmocap.runtime.hybrid.unseen_limbs import held_dofs, hold_unseen
from depthmocap.shared.skeleton import DOF_NAMES, JOINT_NAMES


def _observed(*inferred: str) -> np.ndarray:
    seen = np.ones(len(JOINT_NAMES), dtype=bool)
    seen[[JOINT_NAMES.index(j) for j in inferred]] = False
    return seen


def _names(held: torch.Tensor) -> set[str]:
    return {DOF_NAMES[k] for k in torch.nonzero(held).flatten().tolist()}


def test_held_dofs_golden():
    assert held_dofs(None) is None
    assert _names(held_dofs(_observed())) == set()
    arm = {"l_humerus_abd", "l_humerus_flex", "l_humerus_twist", "l_radius_flex"}
    assert _names(held_dofs(_observed("l_elbow", "l_wrist"))) == arm
    assert _names(held_dofs(_observed("l_wrist"))) == {"l_radius_flex"}
    assert _names(held_dofs(_observed("l_elbow"))) == set()  # the wrist is seen
    leg = {"r_femur_flex", "r_femur_abd", "r_femur_twist", "r_tibia_flex"}
    assert _names(held_dofs(_observed("r_knee", "r_ankle", "head"))) == leg
    assert _names(held_dofs(_observed("r_ankle"))) == {"r_tibia_flex"}


def test_hold_unseen_zeroes_the_held_velocity():
    q_prev, q_prev2 = torch.arange(34.0), -torch.arange(34.0)
    held = held_dofs(_observed("l_wrist"))
    before = hold_unseen(q_prev, q_prev2, held)
    k = DOF_NAMES.index("l_radius_flex")
    assert before[k] == q_prev[k]
    others = torch.arange(34) != k
    assert torch.equal(before[others], q_prev2[others])
    assert hold_unseen(q_prev, None, held) is None
    assert hold_unseen(q_prev, q_prev2, None) is q_prev2
