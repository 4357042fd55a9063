"""The arm start aimed at the arm's labelled pixels."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.runtime.hybrid.aimed_arm import aimed_arm_start
from depthmocap.runtime.raycast import render_body
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics, masked_points
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, rest_pose
from depthmocap.shared.labels import PART_NAMES

ARM = ("humerus_abd", "humerus_flex", "humerus_twist", "radius_flex")


def _pose(side: str, abd: float, flex: float, elbow: float) -> torch.Tensor:
    q = rest_pose(1, root_position=(0.0, 0.1, 3.0))[0]
    for name, deg in zip(("humerus_abd", "humerus_flex", "radius_flex"), (abd, flex, elbow)):
        q[sk.DOF_NAMES.index(f"{side}_{name}")] = math.radians(deg)
    return q


def _arm_pixels(q: torch.Tensor, side: str, body: BodyShape):
    """The rendered arm's points and their true part labels."""
    intr = Intrinsics.kinect_v1(320)
    render = render_body(q[None], body, intr)
    mask = render.mask[0]
    points = masked_points(render.depth[0], mask, intr)
    segment = render.segment[0][mask]
    labels = torch.zeros_like(segment)
    for part in ("upper_arm", "forearm"):
        labels[segment == sk.SEGMENT_NAMES.index(f"{side}_{part}")] = PART_NAMES.index(
            f"{side}_{part}"
        )
    keep = labels > 0
    return points[keep], labels[keep]


@pytest.mark.parametrize("side", ["l", "r"])
@pytest.mark.parametrize("angles", [(80.0, 0.0, 0.0), (60.0, 40.0, 90.0)])
def test_aimed_start_finds_an_arm_held_out(side, angles):
    body = BodyShape.default()
    truth = _pose(side, *angles)
    points, labels = _arm_pixels(truth, side, body)
    track = _pose(side, 0.0, 0.0, 0.0)  # the track's arm hangs beside the body
    start = aimed_arm_start(track, side, points, labels, body)
    assert start.shape == (1, sk.NUM_DOFS)
    joints = named_joint_positions(forward_kinematics(start, body))[0]
    expected = named_joint_positions(forward_kinematics(truth[None], body))[0]
    error = (joints - expected).norm(dim=-1)
    for joint in ("elbow", "wrist"):
        assert float(error[sk.JOINT_NAMES.index(f"{side}_{joint}")]) < 0.05
    # Only the arm's four angles change: the rest of the start is the track's pose.
    arm = [sk.DOF_NAMES.index(f"{side}_{n}") for n in ARM]
    rest = torch.ones(sk.NUM_DOFS, dtype=torch.bool)
    rest[arm] = False
    assert torch.equal(start[0, rest], track[rest])


def test_aimed_start_needs_labelled_pixels():
    body = BodyShape.default()
    track = _pose("l", 0.0, 0.0, 0.0)
    points, labels = _arm_pixels(_pose("l", 80.0, 0.0, 0.0), "l", body)
    few = aimed_arm_start(track, "l", points[:5], labels[:5], body)
    assert few.shape == (0, sk.NUM_DOFS)
    with pytest.raises(ValueError, match="side"):
        aimed_arm_start(track, "x", points, labels, body)
