"""The stature read off an upright frame's silhouette (runtime.hybrid.stature_extent)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depthmocap.bench.scenes import camera_motion
from depthmocap.runtime.hybrid.stature_extent import (
    EXTENT_QUANTILE,
    is_upright,
    torso_extent,
    upright_extent,
)
from depthmocap.runtime.raycast import render_body
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics, masked_points
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
from depthmocap.shared.skeleton import JOINT_NAMES

AT = {n: k for k, n in enumerate(JOINT_NAMES)}


def _figure(thigh=(0, 1, 0), shank=(0, 1, 0), wrist_y=0.1) -> np.ndarray:
    """(J, 3) joints of a torso upright in the camera (y down), both legs along ``thigh``
    and ``shank``, wrists at height ``wrist_y`` (the head at -0.75)."""
    j = np.zeros((len(JOINT_NAMES), 3))
    j[:, 2] = 3.0
    j[AT["neck"], 1], j[AT["head"], 1] = -0.5, -0.75
    for side, x in (("l", 0.1), ("r", -0.1)):
        hip = np.array((x, 0.0, 3.0))
        j[AT[f"{side}_hip"]] = hip
        j[AT[f"{side}_knee"]] = hip + 0.4 * np.asarray(thigh, float) / np.linalg.norm(thigh)
        j[AT[f"{side}_ankle"]] = j[AT[f"{side}_knee"]] + 0.4 * np.asarray(shank, float)
        j[AT[f"{side}_wrist"]] = (2 * x, wrist_y, 3.0)
    return j


def test_upright_means_thighs_along_the_torso_and_hands_below_the_head():
    assert is_upright(_figure())
    assert not is_upright(_figure(thigh=(0, 0, -1)))  # seated
    one_raised = _figure()
    one_raised[AT["l_knee"]] = one_raised[AT["l_hip"]] + (0.0, 0.0, -0.4)
    assert is_upright(one_raised)  # a kick: the other leg carries the height
    assert is_upright(_figure(shank=(0, 0, 1)))  # knees not read
    assert is_upright(_figure(thigh=(0, math.cos(0.3), -math.sin(0.3))))  # 17 degrees
    assert not is_upright(_figure(thigh=(0, math.cos(0.4), -math.sin(0.4))))  # 23 degrees
    assert not is_upright(_figure(wrist_y=-0.9))  # a hand above the head
    batch = np.stack([_figure(), _figure(thigh=(0, 0, -1))])[None]
    np.testing.assert_array_equal(is_upright(batch), [[True, False]])  # (1, 2)
    flat = _figure()
    flat[AT["neck"]] = flat[AT["pelvis"]]
    assert not is_upright(flat)  # no torso line


def test_extent_of_points_along_the_torso_golden_and_rotation_free():
    """Points spread evenly from the soles (y = 0.85) to the head's top (y = -0.9): the
    span between the end quantiles, whichever way the body and the points are turned."""
    y = torch.linspace(-0.9, 0.85, 10001, dtype=torch.float64)
    points = torch.stack([0.05 * torch.sin(40 * y), y, 3.0 + 0.1 * torch.cos(30 * y)], -1)
    golden = 1.75 * (1 - 2 * EXTENT_QUANTILE)
    assert torso_extent(points, _figure()) == pytest.approx(golden, rel=1e-6)
    c, s = math.cos(0.7), math.sin(0.7)
    turn = torch.tensor([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=torch.float64)
    turned = torso_extent(points @ turn.T, _figure() @ turn.numpy().T)
    assert turned == pytest.approx(golden, rel=1e-6)
    assert math.isnan(torso_extent(points[:0], _figure()))


def test_the_extent_of_a_rendered_body_grows_with_its_size():
    """The default body rendered at two sizes in the same standing poses: the extents
    differ by the factor, and stay a steady share of the stature over the frames."""
    intr = Intrinsics.kinect_v1(320)
    shares = {}
    for factor in (1.0, 1.1):
        body = BodyShape.default().scaled(factor)
        q = camera_motion("arm_cross", 6, seed=0, body=body).float()
        depth = render_body(q, body, intr).depth
        joints = named_joint_positions(forward_kinematics(q, body)).numpy()
        assert is_upright(joints).all()
        extents = [
            torso_extent(masked_points(depth[i], depth[i] > 0, intr), joints[i])
            for i in range(len(q))
        ]
        shares[factor] = np.array(extents) / float(body.stature())
    np.testing.assert_allclose(shares[1.1], shares[1.0], rtol=0.01)
    assert 0.9 < shares[1.0].mean() < 1.0 and np.ptp(shares[1.0]) < 0.01


def test_a_frame_shows_the_full_height_only_upright_and_uncut():
    """The extent of an upright pose's frame; NaN when the pose is seated, the mask touches
    the top or bottom row, or there is no person."""
    intr = Intrinsics.kinect_v1(320)
    body = BodyShape.default()
    q = camera_motion("arm_cross", 1, seed=0, body=body).float()
    depth = render_body(q, body, intr).depth[0]
    joints = named_joint_positions(forward_kinematics(q, body)).numpy()[0]
    mask = depth > 0
    mask[0] = mask[-1] = False  # the render's own rows at the edges, if any
    whole = upright_extent(depth, mask, intr, joints)
    assert whole == pytest.approx(torso_extent(masked_points(depth, mask, intr), joints))
    assert 0.5 < whole < 2.5
    for cut_row in (0, -1):
        cut = mask.clone()
        cut[cut_row, 100:110] = True
        assert math.isnan(upright_extent(depth, cut, intr, joints))
    seated = joints.copy()
    for side in "lr":
        seated[AT[f"{side}_knee"]] = seated[AT[f"{side}_hip"]] + (0.0, 0.0, -0.4)
    assert math.isnan(upright_extent(depth, mask, intr, seated))
    assert math.isnan(upright_extent(depth, torch.zeros_like(mask), intr, joints))
