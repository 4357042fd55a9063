"""The automatic reference-pose check (runtime.calibration.pose_check): limb directions,
facing about the body's own vertical, uprightness, the person's stature from a frame."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.runtime.calibration import (
    CalibrationConfig,
    is_reference_pose,
    person_stature,
    reference_pose,
)
from depthmocap.runtime.calibration.pose_check import facing_angle, limb_directions
from depthmocap.runtime.raycast import render_body
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.so3 import matrix_to_rotvec, rotvec_to_matrix

INTR = Intrinsics.kinect_v1(320)
CFG = CalibrationConfig()
D = {n: i for i, n in enumerate(sk.DOF_NAMES)}


def _seen_from(q: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
    """Pose ``q`` (34,) as a camera rotated by ``rot`` (3, 3) about the body's root sees it."""
    out = q.clone().double()
    out[3:6] = matrix_to_rotvec(rot.double() @ rotvec_to_matrix(out[3:6]))
    return out


def _pitch(deg: float) -> torch.Tensor:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]], dtype=torch.float64)


def _yaw(deg: float) -> torch.Tensor:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=torch.float64)


def test_reference_limbs_point_sideways_and_down():
    dirs = limb_directions(reference_pose(CFG, dtype=torch.float64)[None], BodyShape.default())[0]
    # Body frame: +x the person's left, +y up. Arms out to the sides, legs down.
    assert float(dirs[0, 0]) > 0.95 and float(dirs[1, 0]) > 0.95  # left arm
    assert float(dirs[4, 0]) < -0.95 and float(dirs[5, 0]) < -0.95  # right arm
    assert (dirs[[2, 3, 6, 7], 1] < -0.9).all()  # legs
    assert float(facing_angle(reference_pose(CFG, dtype=torch.float64)[None])[0]) < 1e-6


def test_a_camera_looking_down_does_not_turn_the_person():
    ref = reference_pose(CFG, dtype=torch.float64)
    pitched = _seen_from(ref, _pitch(40.0))  # a camera mounted high, looking down 40 deg
    assert float(facing_angle(pitched[None])[0]) == pytest.approx(0.0, abs=1e-6)
    assert is_reference_pose(pitched, CFG)
    # With the floor known, the body must stand on it: the same camera sees "up" pitched too.
    up = _pitch(40.0) @ torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    assert is_reference_pose(pitched, CFG, up=up)
    assert not is_reference_pose(ref, CFG, up=up)  # leaning 40 deg against that floor


@pytest.mark.parametrize("yaw, held", [(20.0, True), (-30.0, True), (50.0, False), (180.0, False)])
def test_facing_is_a_turn_about_the_vertical(yaw, held):
    q = reference_pose(CFG, dtype=torch.float64)
    # Turn the body about its own vertical axis (the root stays where it is).
    turned = q.clone()
    turned[3:6] = matrix_to_rotvec(rotvec_to_matrix(q[3:6]) @ _yaw(yaw))
    assert float(facing_angle(turned[None])[0]) == pytest.approx(math.radians(abs(yaw)), abs=1e-4)
    assert is_reference_pose(turned, CFG) is held


def test_limbs_compared_by_direction_not_by_angle():
    q = reference_pose(CFG, dtype=torch.float64)
    # Shoulders raised 20 deg by the clavicles, arms lowered 20 deg at the shoulder: the arms
    # point nearly the same way, though two angles are 20 deg off the reference.
    for s in "lr":
        q[D[f"{s}_clavicle_elev"]] = math.radians(20.0)
        q[D[f"{s}_humerus_abd"]] -= math.radians(20.0)
    assert is_reference_pose(q, CFG)
    bent = reference_pose(CFG, dtype=torch.float64)
    bent[D["l_radius_flex"]] = math.radians(60.0)  # an elbow bent 60 deg
    assert not is_reference_pose(bent, CFG)
    knee = reference_pose(CFG, dtype=torch.float64)
    knee[D["r_tibia_flex"]] = math.radians(40.0)
    assert not is_reference_pose(knee, CFG)


@pytest.mark.parametrize("scale", [0.85, 1.0, 1.12])
def test_stature_from_a_frame(scale):
    body = BodyShape.default().scaled(scale)
    q = reference_pose(CFG, (0.0, 0.0, 3.0), torch.float64)
    r = render_body(q[None], body.to(dtype=torch.float64), INTR)
    depth = r.depth[0]
    mask = depth > 0
    # The floor: through the lowest point of the body, level with the camera (up = -y).
    ys = torch.arange(INTR.height, dtype=torch.float64)[:, None].expand_as(depth)
    y_cam = (ys - INTR.cy) / INTR.fy * depth
    floor_y = float(y_cam[mask].max())
    floor = (torch.tensor([0.0, -1.0, 0.0]), torch.tensor([0.0, floor_y, 0.0]))
    expected = float(y_cam[mask].max() - y_cam[mask].min())
    got = person_stature(depth, mask, INTR, floor)
    assert got == pytest.approx(expected, abs=0.02)
    assert got == pytest.approx(float(body.stature()), rel=0.06)
    # Without a floor: the vertical extent plus the floor band (feet removed with the floor).
    assert person_stature(depth, mask, INTR, None) == pytest.approx(expected + 0.05, abs=0.02)
    assert person_stature(depth, torch.zeros_like(mask), INTR, floor) is None
