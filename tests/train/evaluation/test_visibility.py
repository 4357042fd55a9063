"""Joint visibility from part labels (golden cases on hand-made frames) and the evaluation's
seen-joints-only system failure rate end to end."""

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
from depthmocap.shared.labels import PART_NAMES
from depthmocap.shared.recording import Recording, RecordingWriter
from depthmocap.train.evaluation import metrics as m
from depthmocap.train.evaluation.cli import main
from depthmocap.train.evaluation.dev_benchmark import format_failures
from depthmocap.train.evaluation.evaluate import format_failed_frames
from depthmocap.train.evaluation.visibility import (
    JOINT_PARTS,
    recording_joint_visibility,
    visible_joints,
)

CAM = Intrinsics.kinect_v1(160)
FOREARM = PART_NAMES.index("l_forearm")


def _patch(point: np.ndarray, part: int, half: int = 3, depth_offset: float = 0.0):
    """Depth (m) and labels of a frame showing a (2 half + 1)^2 pixel patch of ``part`` at the
    projection of ``point``, ``depth_offset`` behind it."""
    depth = np.zeros((CAM.height, CAM.width))
    labels = np.zeros((CAM.height, CAM.width), np.uint8)
    u = int(round(CAM.fx * point[0] / point[2] + CAM.cx))
    v = int(round(CAM.fy * point[1] / point[2] + CAM.cy))
    depth[v - half : v + half + 1, u - half : u + half + 1] = point[2] + depth_offset
    labels[v - half : v + half + 1, u - half : u + half + 1] = part
    return depth, labels


def test_every_joint_has_parts_and_a_radius():
    assert set(JOINT_PARTS) == set(sk.JOINT_NAMES)
    for parts, radius in JOINT_PARTS.values():
        assert all(p in PART_NAMES for p in parts) and 0.05 <= radius <= 0.25


def test_a_joint_is_visible_only_with_enough_of_its_parts_near_it():
    wrist = np.array([0.1, -0.2, 2.0])
    names = ["l_wrist", "r_wrist", "nose"]
    joints = np.stack([wrist, wrist, wrist])
    # 49 left-forearm pixels on the wrist, 5 cm in front of it: the left wrist is seen; the
    # right wrist is not (wrong part), an unknown name counts as seen.
    depth, labels = _patch(wrist, FOREARM, depth_offset=-0.05)
    np.testing.assert_array_equal(
        visible_joints(depth, labels, joints, names, CAM), [True, False, True]
    )
    # The same pixels 30 cm in front (another limb over the wrist): beyond the 10 cm radius.
    depth, labels = _patch(wrist, FOREARM, depth_offset=-0.30)
    assert not visible_joints(depth, labels, joints, names, CAM)[0]
    # Pixels without a depth reading do not count; fewer than min_pixels do not either.
    depth, labels = _patch(wrist, FOREARM)
    assert not visible_joints(np.zeros_like(depth), labels, joints, names, CAM)[0]
    depth, labels = _patch(wrist, FOREARM, half=1)  # 9 pixels
    assert visible_joints(depth, labels, joints, names, CAM, min_pixels=9)[0]
    assert not visible_joints(depth, labels, joints, names, CAM, min_pixels=10)[0]
    with pytest.raises(ValueError, match="differ in size"):
        visible_joints(depth[:-1], labels, joints, names, CAM)


def test_failures_counted_on_seen_joints_only_golden():
    err = np.array([[0.05, 0.30], [0.25, 0.05], [np.nan, np.nan], [0.01, 0.02]])
    seen = np.array([[True, False], [True, True], [False, False], [True, True]])
    np.testing.assert_array_equal(m.system_failures(err, 0.20), [1, 1, 1, 0])
    # Frame 0 failed on a hidden joint only; a frame without a pose fails either way.
    np.testing.assert_array_equal(m.system_failures(err, 0.20, seen), [0, 1, 1, 0])


def test_failure_texts_mark_hidden_joints():
    frames = [
        {"frame": 3, "worst_joint": "l_wrist", "error_mm": 312.0, "worst_joint_visible": False},
        {"frame": 4, "worst_joint": "l_elbow", "error_mm": 250.0, "worst_joint_visible": True},
    ]
    assert format_failed_frames(frames) == "3 l_wrist 31 cm (hidden), 4 l_elbow 25 cm"
    text = format_failures(
        "hybrid", {"HDM_a": {"system_failure_frames": frames}}, {"system_failure_visible_pct": 0.5}
    )
    assert text.splitlines()[-1] == "  counting only the joints the camera sees: 0.5%"


FRAMES = 4


@pytest.fixture
def labelled_recording(tmp_path):
    """A rest pose whose left wrist the camera sees in frames 0 and 1 only."""
    body = BodyShape.default(torch.float64)
    q = rest_pose(FRAMES, root_position=(0.0, 0.1, 2.5), dtype=torch.float64).numpy()
    joints = named_joint_positions(forward_kinematics(torch.as_tensor(q), body)).numpy()
    wrist = sk.JOINT_NAMES.index("l_wrist")
    path = tmp_path / "rec"
    with RecordingWriter(path, CAM, fps=30.0, source="test") as w:
        for f in range(FRAMES):
            depth, labels = _patch(joints[f, wrist], FOREARM if f < 2 else 0)
            w.write_frame((depth * 1000).astype(np.uint16), labels)
        w.write_groundtruth(joints, sk.JOINT_NAMES, q=q)
    return path, q, joints, body


def test_evaluation_reports_failures_on_seen_joints(labelled_recording, tmp_path, capsys):
    rec, q, joints, body = labelled_recording
    wrist = sk.JOINT_NAMES.index("l_wrist")
    vis = recording_joint_visibility(Recording(rec), joints, sk.JOINT_NAMES)
    np.testing.assert_array_equal(vis[:, wrist], [True, True, False, False])
    pred = joints.copy()
    pred[1:3, wrist, 0] += 0.3  # the wrist 30 cm off in frame 1 (seen) and 2 (hidden)
    with ResultWriter(tmp_path / "res", body, 30.0, CAM, "hybrid", "test") as w:
        for f in range(FRAMES):
            w.write_frame(f, f / 30, "tracked", pred[f], q[f], {"surface_error_q97_mm": 10.0})
    out = tmp_path / "eval.json"
    assert (
        main(["--recording", str(rec), "--result", str(tmp_path / "res"), "--json", str(out)]) == 0
    )
    printed = capsys.readouterr().out
    assert "1 l_wrist 30 cm, 2 l_wrist 30 cm (hidden)" in printed
    assert "seen joints only    25.00 %" in printed
    r = json.loads(out.read_text())
    assert r["system_failure_pct"] == pytest.approx(50.0)
    assert r["system_failure_visible_pct"] == pytest.approx(25.0)
    assert [f["worst_joint_visible"] for f in r["system_failure_frames"]] == [True, False]


def test_observed_flag_agreement_golden():
    observed = np.array([[1.0, 0.0, np.nan], [1.0, 1.0, 0.0]])
    visible = np.array([[True, True, True], [False, True, False]])
    flagged, recall, precision = m.observed_flag_agreement(observed, visible)
    assert flagged == pytest.approx(60.0)  # 3 of the 5 flags say observed
    assert recall == pytest.approx(200 / 3)  # 2 of the 3 visible joints with a flag
    assert precision == pytest.approx(200 / 3)  # 2 of the 3 observed flags are visible
    assert all(np.isnan(m.observed_flag_agreement(np.full((1, 3), np.nan), visible[:1])))


@pytest.mark.parametrize("wrist_flags", [(True, True, False, False), (True, True, True, True)])
def test_evaluation_counts_failures_on_joints_the_result_calls_observed(
    labelled_recording, tmp_path, capsys, wrist_flags
):
    """The wrist is 30 cm off in frames 1 (seen) and 2 (hidden): flagged as the camera sees
    it, only frame 1 fails on observed joints; flagged observed throughout, both fail."""
    rec, q, joints, body = labelled_recording
    wrist = sk.JOINT_NAMES.index("l_wrist")
    pred = joints.copy()
    pred[1:3, wrist, 0] += 0.3
    with ResultWriter(tmp_path / "res", body, 30.0, CAM, "hybrid", "test") as w:
        for f in range(FRAMES):
            flags = np.ones(16, dtype=bool)
            flags[wrist] = wrist_flags[f]
            w.write_frame(f, f / 30, "tracked", pred[f], q[f], {}, flags)
    out = tmp_path / "eval.json"
    main(["--recording", str(rec), "--result", str(tmp_path / "res"), "--json", str(out)])
    r = json.loads(out.read_text())
    honest = not wrist_flags[2]
    assert r["system_failure_observed_pct"] == pytest.approx(25.0 if honest else 50.0)
    assert r["observed_joints_pct"] == pytest.approx(100.0 * (60 + sum(wrist_flags)) / 64)
    assert r["observed_flag_recall_pct"] == pytest.approx(100.0)
    seen = int(recording_joint_visibility(Recording(rec), joints, sk.JOINT_NAMES).sum())
    assert r["observed_flag_precision_pct"] == pytest.approx(100.0 * seen / (60 + sum(wrist_flags)))
    assert "observed joints only" in capsys.readouterr().out


def test_frames_without_flags_count_every_joint(labelled_recording, tmp_path):
    """Frame 2's wrist is 30 cm off and the result gives no flags for that frame: it fails
    on the observed-joints rate too (saying nothing is not calling the wrist inferred)."""
    rec, q, joints, body = labelled_recording
    wrist = sk.JOINT_NAMES.index("l_wrist")
    pred = joints.copy()
    pred[2, wrist, 0] += 0.3
    with ResultWriter(tmp_path / "res", body, 30.0, CAM, "hybrid", "test") as w:
        for f in range(FRAMES):
            flags = None if f == 2 else np.ones(16, dtype=bool)
            w.write_frame(f, f / 30, "tracked", pred[f], q[f], {}, flags)
    out = tmp_path / "eval.json"
    main(["--recording", str(rec), "--result", str(tmp_path / "res"), "--json", str(out)])
    r = json.loads(out.read_text())
    assert r["system_failure_observed_pct"] == pytest.approx(25.0)
    assert r["system_failure_pct"] == pytest.approx(25.0)


def test_results_without_observed_flags_have_no_observed_rate(labelled_recording, tmp_path):
    rec, q, joints, body = labelled_recording
    with ResultWriter(tmp_path / "res", body, 30.0, CAM, "hybrid", "test") as w:
        for f in range(FRAMES):
            w.write_frame(f, f / 30, "tracked", joints[f], q[f], {})
    out = tmp_path / "eval.json"
    main(["--recording", str(rec), "--result", str(tmp_path / "res"), "--json", str(out)])
    r = json.loads(out.read_text())
    assert r["system_failure_observed_pct"] is None and r["observed_flag_recall_pct"] is None


def test_recordings_without_labels_have_no_seen_joints_rate(tmp_path):
    q = rest_pose(1, dtype=torch.float64).numpy()
    with RecordingWriter(tmp_path / "rec", CAM, fps=30.0, source="test") as w:
        w.write_frame(np.zeros((CAM.height, CAM.width), np.uint16))
        w.write_groundtruth(np.zeros((1, 16, 3)), sk.JOINT_NAMES, q=q)
    assert (
        recording_joint_visibility(
            Recording(tmp_path / "rec"), np.zeros((1, 16, 3)), sk.JOINT_NAMES
        )
        is None
    )
