"""train-eval on a recording whose only comparison is a reference skeleton (another tracker,
synthetic here): the joint map, offset normalization in the result's frames, the normalized
rates, and the output saying plainly that this is not ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from depthmocap.runtime.export import ResultWriter
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, rest_pose
from depthmocap.shared.recording import RecordingWriter
from depthmocap.train.evaluation.cli import main

FRAMES = 10
CAM = Intrinsics.kinect_v1(160)
# The other tracker's names for our joints ("theirs_<ours>"), plus one joint we lack.
MAP = [(n, f"theirs_{n}") for n in sk.JOINT_NAMES]
THEIR_NAMES = ["theirs_toe"] + [theirs for _, theirs in MAP][::-1]


def _poses() -> np.ndarray:
    q = rest_pose(FRAMES, root_position=(0.0, 0.1, 2.5), dtype=torch.float64).numpy()
    t = np.linspace(0, 1, FRAMES)
    q[:, 4] += 0.8 * t  # turning about the vertical
    q[:, 6 + 12] = 1.2 * t  # raising the left arm
    return q


def _tracked(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joints (F, 16, 3) and each joint's segment rotation (F, 16, 3, 3) of poses q."""
    kin = forward_kinematics(torch.as_tensor(q), BodyShape.default(torch.float64))
    return named_joint_positions(kin).numpy(), kin.rotations.numpy()[:, sk.JOINT_SEGMENT]


def _recording(path, reference_ours: np.ndarray, groundtruth: np.ndarray | None = None):
    """A recording whose reference.npz holds ``reference_ours`` (F, 16, 3) under the other
    tracker's names and order, and a joint without counterpart."""
    theirs = np.zeros((FRAMES, len(THEIR_NAMES), 3))
    for ours, their in MAP:
        theirs[:, THEIR_NAMES.index(their)] = reference_ours[:, sk.JOINT_NAMES.index(ours)]
    theirs[:, 0] = [0.0, 0.9, 2.5]
    with RecordingWriter(path, CAM, fps=30.0, source="test") as w:
        for _ in range(FRAMES):
            w.write_frame(np.zeros((CAM.height, CAM.width), np.uint16))
        w.write_reference(theirs, THEIR_NAMES, "Test tracker (another tracker)", MAP)
        if groundtruth is not None:
            w.write_groundtruth(groundtruth, sk.JOINT_NAMES)
    return path


def _result(path, q: np.ndarray, joints: np.ndarray) -> None:
    with ResultWriter(path, BodyShape.default(), 30.0, CAM, "hybrid", "test") as w:
        for i in range(FRAMES):
            w.write_frame(i, i / 30, "tracked", joints[i], q[i], {})


def _evaluate(tmp_path, rec, capsys) -> tuple[dict, str]:
    out = tmp_path / "eval.json"
    args = ["--recording", str(rec), "--result", str(tmp_path / "res"), "--json", str(out)]
    assert main(args + ["--plot", ""]) == 0
    return json.loads(out.read_text()), capsys.readouterr().out


def test_local_offsets_vanish_and_the_output_says_it_is_not_ground_truth(tmp_path, capsys):
    q = _poses()
    joints, rot = _tracked(q)
    # The other tracker puts every joint 4 cm off along its segment's own axes: a pure
    # definition difference, constant in the tracked joint's frame.
    reference = joints + (rot @ np.array([0.04, -0.02, 0.01])[:, None])[..., 0]
    _result(tmp_path / "res", q, joints)
    r, printed = _evaluate(tmp_path, _recording(tmp_path / "rec", reference), capsys)
    assert r["truth"] == "reference" and r["truth_source"] == "Test tracker (another tracker)"
    assert r["joints"] == list(sk.JOINT_NAMES)
    assert r["reference_joints_without_counterpart"] == ["theirs_toe"]
    assert r["offset_frame"] == "predicted_q"  # a reference has no pose of its own
    assert r["mean_joint_error_mm"] == pytest.approx(np.sqrt(21e-4) * 1e3, abs=0.01)
    assert r["mean_joint_error_offset_normalized_mm"] < 0.01
    assert r["precision_10cm_offset_normalized"] == 1.0
    assert r["system_failure_offset_normalized_pct"] == 0.0
    assert "NOT ground truth" in printed and "agreement with another tracker" in printed
    assert "theirs_toe" in printed and "distance mm" in printed
    assert any("NOT with ground truth" in n for n in r["notes"])


def test_normalized_rates_by_joint_golden(tmp_path, capsys):
    q = _poses()
    joints, _ = _tracked(q)
    reference = joints.copy()
    wrist, knee = sk.JOINT_NAMES.index("r_wrist"), sk.JOINT_NAMES.index("l_knee")
    # The wrist disagrees by 30 cm in frames 0-1 and the knee by 12 cm in frames 0-4, and
    # both agree elsewhere: the mean offset (6 cm, 6 cm) is removed from every frame.
    reference[:2, wrist, 0] += 0.30
    reference[:5, knee, 1] += 0.12
    _result(tmp_path / "res", q, joints)
    r, _ = _evaluate(tmp_path, _recording(tmp_path / "rec", reference), capsys)
    # Normalized wrist errors: 24 cm twice, 6 cm eight times; knee: 6 cm everywhere (to a
    # millimetre: the turn is not exactly about the camera axis the offsets lie along).
    assert r["per_joint_error_offset_normalized_mm"]["r_wrist"] == pytest.approx(96.0, abs=1)
    assert r["per_joint_error_offset_normalized_mm"]["l_knee"] == pytest.approx(60.0, abs=1)
    assert r["per_joint_failure_offset_normalized_pct"]["r_wrist"] == pytest.approx(20.0)
    assert r["per_joint_failure_offset_normalized_pct"]["l_knee"] == 0.0
    assert r["per_joint_precision_10cm_offset_normalized"]["r_wrist"] == pytest.approx(0.8)
    assert r["precision_10cm_offset_normalized"] == pytest.approx(1 - 2 / (16 * FRAMES))
    assert r["system_failure_offset_normalized_pct"] == pytest.approx(20.0)
    assert [f["frame"] for f in r["system_failure_offset_normalized_frames"]] == [0, 1]
    assert r["system_failure_offset_normalized_frames"][0]["worst_joint"] == "r_wrist"
    # Raw: the wrist's 30 cm in frames 0-1 and nothing else beyond 20 cm.
    assert r["system_failure_pct"] == pytest.approx(20.0)
    assert r["per_joint_precision_10cm"]["l_knee"] == pytest.approx(0.5)


def test_ground_truth_wins_over_a_reference(tmp_path, capsys):
    q = _poses()
    joints, _ = _tracked(q)
    rec = _recording(tmp_path / "rec", joints + 0.5, groundtruth=joints)
    _result(tmp_path / "res", q, joints)
    r, printed = _evaluate(tmp_path, rec, capsys)
    assert r["truth"] == "ground_truth" and r["mean_joint_error_mm"] < 0.01
    assert "NOT ground truth" not in printed and r["reference_joints_without_counterpart"] == []
