"""Output-joint offsets (shared.joint_offsets): the file format and its errors, and moving
joints by offsets in their segments' frames."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.joint_offsets import (
    JointOffsets,
    JointOffsetsError,
    load_joint_offsets,
    offset_joints,
    save_joint_offsets,
)
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, rest_pose

J = len(sk.JOINT_NAMES)


def test_round_trip(tmp_path):
    offsets = np.random.default_rng(0).normal(0, 0.03, (J, 3))
    save_joint_offsets(tmp_path / "o.json", JointOffsets(offsets, 1.7, "tune set", 12))
    back = load_joint_offsets(tmp_path / "o.json")
    np.testing.assert_allclose(back.offsets_m, offsets, atol=1e-6)
    assert (back.reference_stature_m, back.fitted_on, back.frames) == (1.7, "tune set", 12)
    assert not (tmp_path / "o.json.tmp").exists()


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(format="other"), "not a depthmocap-joint-offsets"),
        (lambda d: d.update(version=3), "version 3"),
        (lambda d: d.update(pose_coefficients_m=[[[0.0] * 3] * 56] * J), "pose features None"),
        (
            lambda d: d.update(pose_features="angles_and_squares", pose_coefficients_m=[[1]]),
            "pose coefficients",
        ),
        (lambda d: d.update(joint_names=d["joint_names"][::-1]), "joints are not"),
        (lambda d: d.update(offsets_m=d["offsets_m"][:3]), "16 finite"),
        (lambda d: d.update(offsets_m=[[math.nan] * 3] * J), "16 finite"),
        (lambda d: d.update(reference_stature_m=0.0), "positive"),
        (lambda d: d.update(reference_stature_m="tall"), "could not convert"),
    ],
)
def test_bad_files_are_clear_errors(tmp_path, change, message):
    path = tmp_path / "o.json"
    save_joint_offsets(path, JointOffsets(np.zeros((J, 3)), 1.7))
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))
    with pytest.raises(JointOffsetsError, match=message):
        load_joint_offsets(path)


def test_pose_offsets_round_trip_and_version_1_files_still_read(tmp_path):
    from depthmocap.shared.joint_offsets import NUM_POSE_FEATURES

    rng = np.random.default_rng(1)
    offsets, coef = rng.normal(0, 0.03, (J, 3)), rng.normal(0, 0.01, (J, NUM_POSE_FEATURES, 3))
    save_joint_offsets(tmp_path / "o.json", JointOffsets(offsets, 1.7, pose_coefficients_m=coef))
    back = load_joint_offsets(tmp_path / "o.json")
    np.testing.assert_allclose(back.pose_coefficients_m, coef, atol=1e-7)
    data = json.loads((tmp_path / "o.json").read_text())
    assert data["version"] == 2 and data["pose_features"] == "angles_and_squares"
    del data["pose_features"], data["pose_coefficients_m"]
    data["version"] = 1
    (tmp_path / "v1.json").write_text(json.dumps(data))
    old = load_joint_offsets(tmp_path / "v1.json")
    assert old.pose_coefficients_m is None
    np.testing.assert_allclose(old.offsets_m, offsets, atol=1e-6)


def test_pose_offsets_follow_the_joint_angles():
    """offsets_at: the zero-pose offsets plus the angles' and their squares' coefficients;
    the root's dofs do not count."""
    from depthmocap.shared.joint_offsets import NUM_POSE_FEATURES, offsets_at

    q = torch.zeros(3, sk.NUM_DOFS, dtype=torch.float64)
    q[1, 3:6] = 1.0  # the root turned only
    knee = sk.DOF_NAMES.index("l_tibia_flex")
    q[2, knee] = 0.5
    base = torch.zeros(J, 3, dtype=torch.float64)
    base[12] = torch.tensor([0.0, 0.0, 0.01])
    coef = torch.zeros(J, NUM_POSE_FEATURES, 3, dtype=torch.float64)
    a = knee - sk.ANGLE_DOFS.start
    coef[12, a, 2] = 0.02  # linear in the angle
    coef[12, 28 + a, 2] = 0.04  # and in its square
    out = offsets_at(q, base, coef)
    torch.testing.assert_close(out[0], base)
    torch.testing.assert_close(out[1], base)
    assert float(out[2, 12, 2]) == pytest.approx(0.01 + 0.02 * 0.5 + 0.04 * 0.25)
    torch.testing.assert_close(offsets_at(q, base, None), base.expand(3, -1, -1))


def test_missing_and_corrupt_files(tmp_path):
    with pytest.raises(JointOffsetsError, match="no such"):
        load_joint_offsets(tmp_path / "none.json")
    (tmp_path / "bad.json").write_bytes(b"\x00{not json")
    with pytest.raises(JointOffsetsError, match="not a readable"):
        load_joint_offsets(tmp_path / "bad.json")


def test_offsets_turn_with_their_segment_and_scale_with_stature():
    body = BodyShape.default(torch.float64)
    q = rest_pose(2, root_position=(0.0, 0.0, 2.5), dtype=torch.float64)
    q[1, 3:6] = torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64)  # turned about z
    kin = forward_kinematics(q, body)
    joints = named_joint_positions(kin)
    offsets = torch.zeros(J, 3, dtype=torch.float64)
    offsets[0] = torch.tensor([0.1, 0.0, 0.0])  # the head, 10 cm along its segment's x
    moved = offset_joints(joints, kin.rotations, offsets, torch.tensor([1.0, 2.0]))
    shift = moved - joints
    head_rot = kin.rotations[:, sk.JOINT_SEGMENT[0]]
    torch.testing.assert_close(shift[0, 0], head_rot[0, :, 0] * 0.1)
    torch.testing.assert_close(shift[1, 0], head_rot[1, :, 0] * 0.2)  # turned and doubled
    assert not torch.allclose(head_rot[0, :, 0], head_rot[1, :, 0])
    assert float(shift[:, 1:].abs().max()) == 0.0
