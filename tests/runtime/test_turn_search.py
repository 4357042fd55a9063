"""Start poses of the hybrid's turn search: the body turned rigidly about its spine."""

from __future__ import annotations

import math

import pytest
import torch

from runtime.turn_search import TURN_DEG, turn_candidates
from shared import skeleton as sk
from shared.body import BodyShape
from shared.kinematics import forward_kinematics, named_joint_positions, rest_pose
from shared.so3 import axis_angle_to_matrix

BODY = BodyShape.default()


def _joints(q: torch.Tensor) -> torch.Tensor:
    return named_joint_positions(forward_kinematics(q, BODY.to(dtype=q.dtype)))


def _leaning_pose(dtype=torch.float64) -> torch.Tensor:
    q = rest_pose(1, (0.1, -0.1, 2.6), dtype=dtype)[0]
    q[3:6] = q[3:6] + q.new_tensor([0.2, 0.3, -0.1])  # turned and leaning
    q[sk.DOF_NAMES.index("l_humerus_abd")] = 0.6
    q[sk.DOF_NAMES.index("lower_back_y")] = 0.2
    return q


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_turn_candidates_turn_the_whole_body_rigidly_about_its_spine(dtype):
    q = _leaning_pose(dtype)
    out = turn_candidates(q, BODY)
    assert out.shape == (len(TURN_DEG), sk.NUM_DOFS) and out.dtype == dtype
    torch.testing.assert_close(out[:, 6:], q[6:].expand(len(out), -1))  # joint angles kept
    torch.testing.assert_close(out[:, 0:3], q[0:3].expand(len(out), 3))  # root stays
    before = _joints(q[None])[0]
    up = before[sk.JOINT_NAMES.index("neck")] - before[sk.JOINT_NAMES.index("pelvis")]
    up = up / up.norm()
    tol = {"atol": 1e-4, "rtol": 1e-4} if dtype == torch.float32 else {}
    for angle, turned in zip(TURN_DEG, _joints(out)):
        rot = axis_angle_to_matrix(up, torch.tensor(math.radians(angle), dtype=dtype))
        expected = (before - q[0:3]) @ rot.T + q[0:3]
        torch.testing.assert_close(turned, expected, **tol)


def test_turn_candidates_golden_quarter_turn_of_an_upright_body():
    q = rest_pose(1, (0.0, 0.0, 2.5), dtype=torch.float64)[0]
    j0 = _joints(q[None])[0]
    names = sk.JOINT_NAMES
    shoulders = j0[names.index("l_shoulder")] - j0[names.index("r_shoulder")]
    assert abs(float(shoulders[2])) < 1e-6  # facing the camera: shoulders square to it
    out = turn_candidates(q, BODY, (90.0, -90.0))
    for sign, turned in zip((1, -1), _joints(out)):
        s = turned[names.index("l_shoulder")] - turned[names.index("r_shoulder")]
        # A quarter turn puts the shoulder line along the viewing axis, each way once; the
        # body's up is -y in the camera frame, so +90 degrees takes +x to +z.
        assert float(s[0]) == pytest.approx(0.0, abs=1e-6)
        assert float(s[2]) == pytest.approx(sign * float(shoulders[0]), rel=1e-6)
