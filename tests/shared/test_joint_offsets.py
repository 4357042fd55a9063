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
        (lambda d: d.update(version=2), "version 2"),
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
