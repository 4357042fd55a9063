"""Arm-in-torso depth, the hybrid's plausibility signal for arms the camera cannot see."""

from __future__ import annotations

import math

import pytest
import torch

from runtime.arm_penetration import TORSO_SEGMENTS, arm_penetration
from runtime.raycast import segment_distances
from shared import skeleton as sk
from shared.body import BodyShape
from shared.kinematics import forward_kinematics, named_joint_positions, rest_pose


def _pose(dtype=torch.float64, device="cpu", **angles_deg) -> torch.Tensor:
    q = rest_pose(1, (0.1, 0.0, 2.5), dtype=dtype, device=device)
    for name, deg in angles_deg.items():
        q[0, sk.DOF_NAMES.index(name)] = math.radians(deg)
    return q


def _depth(q: torch.Tensor, body: BodyShape) -> torch.Tensor:
    body = body.to(dtype=q.dtype, device=q.device)
    return arm_penetration(forward_kinematics(q, body), body)


def test_rest_pose_buries_no_arm(device, dtype):
    out = _depth(_pose(dtype, device), BodyShape.default())
    assert out.shape == (1, 2) and out.dtype == dtype and out.device.type == device.type
    assert (out == 0).all()


@pytest.mark.parametrize("side", ["l", "r"])
def test_an_arm_swung_into_the_hip_is_buried_by_its_wrist_depth(side):
    """A straight arm adducted 20 degrees ends with the hand inside the pelvis: its depth is
    the wrist's (the deepest sample), the other arm's is zero."""
    body = BodyShape.default().to(dtype=torch.float64)
    q = _pose(**{f"{side}_humerus_abd": -20.0})
    out = _depth(q, body)[0]
    k = "lr".index(side)
    assert out[1 - k] == 0
    kin = forward_kinematics(q, body)
    wrist = named_joint_positions(kin)[:, [sk.JOINT_NAMES.index(f"{side}_wrist")]]
    signed = segment_distances(wrist, kin, body)[0, 0, list(TORSO_SEGMENTS)]
    torch.testing.assert_close(out[k], -signed.min())
    assert out[k] > 0.1


def test_depth_grows_as_the_arm_sinks_deeper_and_poses_batch():
    body = BodyShape.default()
    qs = torch.cat([_pose(l_humerus_abd=a) for a in (0.0, -8.0, -14.0, -20.0)])
    out = _depth(qs, body)
    assert (out[:, 1] == 0).all() and out[0, 0] == 0
    assert (out[1:, 0] > out[:-1, 0]).all() and out[-1, 0] > 0.1
    for b in range(len(qs)):  # one pose at a time gives the same
        torch.testing.assert_close(_depth(qs[b : b + 1], body), out[b : b + 1])


def test_an_arm_raised_forward_is_out_of_the_torso():
    q = _pose(l_humerus_flex=90.0, l_radius_flex=90.0, r_humerus_flex=45.0)
    out = _depth(q, BodyShape.default())
    assert (out == 0).all()
