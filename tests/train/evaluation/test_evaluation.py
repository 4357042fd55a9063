"""Evaluation metrics on hand-made arrays (golden values) and train-eval end to end on a tiny
recording plus a result written by the runtime's ResultWriter."""

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
from depthmocap.shared.so3 import rotvec_to_matrix
from depthmocap.train.evaluation import metrics as m
from depthmocap.train.evaluation.cli import main
from depthmocap.train.evaluation.evaluate import evaluate, format_failed_frames, held_frames
from depthmocap.train.evaluation.plot import render_plot


def _random_rotations(shape, seed=0) -> np.ndarray:
    rv = np.random.default_rng(seed).normal(size=shape + (3,))
    return rotvec_to_matrix(torch.as_tensor(rv)).numpy()


def test_identical_predictions_give_zero_error_and_full_precision():
    gt = np.random.default_rng(0).normal(size=(5, 4, 3))
    err = m.joint_errors(gt, gt)
    assert m.mean_error_mm(err) == 0.0 and m.precision_at(err) == 1.0
    assert m.mean_error_mm(m.offset_normalized_errors(gt, gt, None)) == 0.0
    assert not m.system_failures(err).any()


def test_constant_offset_is_removed_by_normalization_but_not_by_raw_error():
    rng = np.random.default_rng(1)
    gt = rng.normal(size=(20, 3, 3))
    offset = np.array([0.03, -0.04, 0.0])  # 5 cm
    pred = gt + offset
    raw = m.joint_errors(pred, gt)
    np.testing.assert_allclose(m.mean_error_mm(raw), 50.0)
    np.testing.assert_allclose(m.per_joint_error_mm(raw), [50.0] * 3)
    assert m.mean_error_mm(m.offset_normalized_errors(pred, gt, None)) < 1e-9
    np.testing.assert_allclose(m.local_offsets(pred, gt, None), np.tile(offset, (3, 1)))


def test_offset_normalization_works_in_the_joints_local_frames():
    # A fixed displacement in each joint's own frame, which turns with the joint (Helten IV-C).
    rng = np.random.default_rng(2)
    gt = rng.normal(size=(30, 2, 3))
    rot = _random_rotations((30, 2))
    local = np.array([[0.02, 0.0, 0.05], [0.0, -0.03, 0.0]])
    pred = gt + (rot @ local[..., None])[..., 0]
    pred[4, 1] = np.nan  # a missing prediction stays missing and does not bias the offset
    norm = m.offset_normalized_errors(pred, gt, rot)
    assert np.isnan(norm[4, 1]) and np.nanmax(norm) < 1e-12
    np.testing.assert_allclose(m.local_offsets(pred, gt, rot), local, atol=1e-12)
    # A camera-frame offset cannot explain it.
    assert m.mean_error_mm(m.offset_normalized_errors(pred, gt, None)) > 10.0


def test_precision_failures_and_percentages_golden():
    err = np.array([[0.05, 0.15], [np.nan, 0.10], [np.nan, np.nan], [0.01, 0.25]])
    assert m.precision_at(err, 0.10) == pytest.approx(3 / 5)  # NaN: no estimate, not counted
    np.testing.assert_allclose(m.per_joint_precision_at(err, 0.10), [1.0, 1 / 3])
    np.testing.assert_allclose(m.per_frame_error_mm(err), [100.0, 100.0, np.nan, 130.0])
    # Failed: frame 2 (no pose) and frame 3 (a joint 25 cm off); 15 cm is tolerated.
    np.testing.assert_array_equal(m.system_failures(err, 0.20), [False, False, True, True])
    assert m.percent(m.system_failures(err, 0.20)) == 50.0
    assert m.percent(m.system_failures(err, 0.12)) == 75.0
    status = np.array(["detected", "tracked", "tracked", "lost", "tracked", "tracked"])
    # The first frame starts the track: not a failure; the lost frame is one.
    assert m.tracking_failure_pct(status) == pytest.approx(100 * 1 / 6)
    assert m.detector_frames_pct(status) == pytest.approx(100 * 2 / 6)
    status = np.array(["detected", "detected", "tracked", "lost", "detected", "tracked"])
    np.testing.assert_array_equal(m.initializations(status), [1, 0, 0, 0, 1, 0])
    assert m.tracking_failure_pct(status) == pytest.approx(100 * 2 / 6)
    assert m.distance_quantile(np.arange(101.0), 0.97) == pytest.approx(97.0)
    assert m.sequence_surface_error_mm(np.array([10.0, np.nan, 20.0])) == 15.0
    assert np.isnan(m.sequence_surface_error_mm(np.full(3, np.nan)))


def test_plot_draws_an_image():
    img = render_plot(
        np.array([10.0, np.nan, 150.0, 40.0]),
        np.array(["detected", "missing", "tracked", "lost"]),
        ["a", "b"],
        np.array([30.0, np.nan]),
        np.array([10.0, 5.0]),
        title="t",
    )
    assert img.dtype == np.uint8 and img.ndim == 3 and img.std() > 0


# --- end to end -------------------------------------------------------------------------------
FRAMES = 10
CAM = Intrinsics.kinect_v1(160)


def _gt_poses() -> np.ndarray:
    q = rest_pose(FRAMES, root_position=(0.0, 0.1, 2.5), dtype=torch.float64).numpy()
    t = np.linspace(0, 1, FRAMES)
    q[:, 0] += 0.2 * t
    q[:, 4] += 0.8 * t  # turning about the vertical
    q[:, 6 + 12] = 1.2 * t  # l_humerus_abd: raising the left arm
    q[:, 6 + 20] = 0.6 * t  # l_femur_flex
    return q


def _joints(q: np.ndarray, body: BodyShape) -> np.ndarray:
    return named_joint_positions(forward_kinematics(torch.as_tensor(q), body)).numpy()


@pytest.fixture
def recording(tmp_path):
    body = BodyShape.default(torch.float64)
    q = _gt_poses()
    path = tmp_path / "rec"
    with RecordingWriter(path, CAM, fps=30.0, source="test") as w:
        for _ in range(FRAMES):
            w.write_frame(np.zeros((CAM.height, CAM.width), np.uint16))
        w.write_groundtruth(_joints(q, body), sk.JOINT_NAMES, q=q)
    return path, q, body


def _result(path, q, body, frames, status, shift=None):
    joints = _joints(q, body)
    if shift is not None:
        joints = joints + shift
    with ResultWriter(path, body, 30.0, CAM, "hybrid", "test") as w:
        for i in frames:
            lost = status[i] == "lost"
            w.write_frame(
                i,
                i / 30,
                status[i],
                None if lost else joints[i],
                None if lost else q[i],
                {"surface_error_q97_mm": 10.0 * i},
            )


def test_held_frames_point_back_to_the_last_written_one():
    written = np.array([False, True, False, False, True, False])
    np.testing.assert_array_equal(held_frames(written), [-1, 1, 1, 1, 4, 4])
    assert held_frames(np.zeros(0, bool)).shape == (0,)


def test_a_skipped_frame_is_scored_with_the_last_pose_when_held(recording, tmp_path):
    """``runtime-track --realtime`` skips frames; held, frame 3 is scored with frame 2's pose
    (what motion.bvh shows there), otherwise it is a frame without a pose."""
    rec, q, body = recording
    status = ["detected"] + ["tracked"] * 9
    _result(tmp_path / "res", q, body, [0, 1, 2, 4, 5, 6, 7, 8, 9], status)
    plain = evaluate(rec, tmp_path / "res").report
    held = evaluate(rec, tmp_path / "res", hold_skipped=True).report
    assert plain["frames_held"] == 0 and held["frames_held"] == 1
    assert plain["frames_missing"] == held["frames_missing"] == 1
    assert plain["mean_joint_error_mm"] == pytest.approx(0.0, abs=1e-2)  # written rounded
    assert plain["system_failure_pct"] == pytest.approx(10.0)  # frame 3: no pose
    joints = _joints(q, body)
    step = np.linalg.norm(joints[2] - joints[3], axis=-1)  # (J,) how far each joint moved
    assert held["mean_joint_error_mm"] == pytest.approx(1000 * step.sum() / (10 * 16), abs=1e-2)
    assert held["system_failure_pct"] == 0.0 and step.max() < 0.2
    assert any("skipped frames scored" in n for n in held["notes"])


def test_cli_end_to_end(recording, tmp_path, capsys):
    rec, q, body = recording
    status = ["detected"] + ["tracked"] * 5 + ["lost"] + ["tracked"] * 3
    shift = np.zeros((FRAMES, 16, 3))
    shift[:, sk.JOINT_NAMES.index("l_wrist"), 0] = 0.15  # one joint 15 cm off in every frame
    frames = [0, 1, 2, 4, 5, 6, 7, 8]  # frame 3 dropped, frame 9 never processed
    _result(tmp_path / "res", q, body, frames, status, shift)
    out = tmp_path / "eval.json"
    assert (
        main(["--recording", str(rec), "--result", str(tmp_path / "res"), "--json", str(out)]) == 0
    )
    printed = capsys.readouterr().out
    assert "l_wrist" in printed and "system failure" in printed
    r = json.loads(out.read_text())
    for key in (
        "mean_joint_error_mm",
        "mean_joint_error_offset_normalized_mm",
        "per_joint_error_mm",
        "precision_10cm",
        "surface_error_q97_mm",
        "tracking_failure_pct",
        "system_failure_pct",
        "fps",
        "frames",
    ):
        assert key in r, key
    assert r["frames"] == 9 and r["frames_missing"] == 1 and r["frames_unprocessed"] == 1
    assert r["frames_with_pose"] == 7  # 8 written, one of them lost
    assert r["per_joint_error_mm"]["l_wrist"] == pytest.approx(150.0, abs=1e-2)
    assert r["per_joint_error_mm"]["head"] == pytest.approx(0.0, abs=1e-2)
    assert r["mean_joint_error_mm"] == pytest.approx(150.0 / 16, abs=1e-2)
    # A constant camera-frame shift on a turning, arm-raising body is not constant in the
    # wrist's frame, so normalization reduces it a lot but need not remove it entirely.
    assert r["mean_joint_error_offset_normalized_mm"] < r["mean_joint_error_mm"] / 2
    assert r["offset_frame"] == "ground_truth_q"
    assert r["precision_10cm"] == pytest.approx(15 / 16)
    assert r["per_joint_precision_10cm"]["l_wrist"] == 0.0
    assert r["detector_frames_pct"] == pytest.approx(100 * 2 / 8)  # detected + lost of 8
    assert r["tracking_failure_pct"] == pytest.approx(100 * 1 / 8)  # frame 0 starts the track
    assert r["system_failure_pct"] == pytest.approx(100 * 2 / 9)  # missing 3 + lost 6
    assert r["system_failure_frames"] == [
        {"frame": 3, "worst_joint": None, "error_mm": None},
        {"frame": 6, "worst_joint": None, "error_mm": None},
    ]
    # Surface error: mean of the per-frame values of the frames written (lost ones too).
    assert r["surface_error_q97_mm"] == pytest.approx(10.0 * np.mean(frames))
    assert r["status_counts"] == {"tracked": 6, "detected": 1, "lost": 1}
    assert (tmp_path / "res" / "evaluation.png").is_file()


def test_cli_offset_only_result_normalizes_to_zero(recording, tmp_path, capsys):
    rec, q, body = recording
    # Shift every joint by a fixed displacement in its own (ground-truth) segment frame.
    kin = forward_kinematics(torch.as_tensor(q), body)
    rot = kin.rotations.numpy()[:, sk.JOINT_SEGMENT]
    shift = (rot @ np.array([0.02, 0.01, -0.03])[:, None])[..., 0]
    _result(tmp_path / "res", q, body, range(FRAMES), ["tracked"] * FRAMES, shift)
    out = tmp_path / "e.json"
    args = ["--recording", str(rec), "--result", str(tmp_path / "res"), "--json", str(out)]
    assert main(args + ["--plot", ""]) == 0
    r = json.loads(out.read_text())
    assert r["mean_joint_error_mm"] == pytest.approx(np.sqrt(14e-4) * 1e3, abs=1e-2)
    assert r["mean_joint_error_offset_normalized_mm"] < 0.01
    assert r["system_failure_pct"] == 0.0 and r["tracking_failure_pct"] == 0.0
    assert r["system_failure_frames"] == []
    assert not (tmp_path / "res" / "evaluation.png").exists()
    # At a 3 cm threshold every frame fails, each by its worst joint.
    assert main(args + ["--plot", "", "--failure-threshold-m", "0.03"]) == 0
    failed = json.loads(out.read_text())["system_failure_frames"]
    assert [f["frame"] for f in failed] == list(range(FRAMES))
    assert all(f["worst_joint"] in sk.JOINT_NAMES for f in failed)
    assert "system failure        100.00 % (frames 0 " in capsys.readouterr().out
    # Every joint is off by the same |shift| = sqrt(14) cm here.
    assert [f["error_mm"] for f in failed] == pytest.approx(
        [np.sqrt(14e-4) * 1e3] * FRAMES, abs=0.01
    )


def _expect_error(capsys, args, pattern):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and pattern in err, err


def test_cli_bad_inputs_exit_2(recording, tmp_path, capsys):
    rec, q, body = recording
    res = tmp_path / "res"
    _result(res, q, body, range(3), ["tracked"] * 3)
    _expect_error(capsys, ["--recording", str(tmp_path / "nope"), "--result", str(res)], "no such")
    _expect_error(capsys, ["--recording", str(rec), "--result", str(tmp_path)], "poses.jsonl")
    (res / "poses.jsonl").write_text('{"frame": 0}\n')
    _expect_error(capsys, ["--recording", str(rec), "--result", str(res)], "poses.jsonl:1")
    # A result from a longer recording.
    _result(res, np.repeat(q, 2, 0), body, range(FRAMES + 2), ["tracked"] * (FRAMES + 2))
    _expect_error(capsys, ["--recording", str(rec), "--result", str(res)], "only 10 frames")
    # A recording without ground truth.
    bare = tmp_path / "bare"
    with RecordingWriter(bare, CAM) as w:
        w.write_frame(np.zeros((CAM.height, CAM.width), np.uint16))
    _expect_error(capsys, ["--recording", str(bare), "--result", str(res)], "ground truth")
    # No joint names in common.
    other = tmp_path / "other"
    with RecordingWriter(other, CAM) as w:
        w.write_frame(np.zeros((CAM.height, CAM.width), np.uint16))
        w.write_groundtruth(np.zeros((1, 2, 3)), ["nose", "toe"])
    _result(res, q, body, range(1), ["tracked"])
    _expect_error(capsys, ["--recording", str(other), "--result", str(res)], "no joint names")


def test_failed_frames_text():
    frames = [{"frame": i, "worst_joint": "l_wrist", "error_mm": 212.0} for i in range(4)]
    frames.append({"frame": 9, "worst_joint": None, "error_mm": None})
    assert format_failed_frames(frames[3:]) == "3 l_wrist 21 cm, 9 no pose"
    assert format_failed_frames(frames, 2) == "0 l_wrist 21 cm, 1 l_wrist 21 cm ... and 3 more"
    assert format_failed_frames([]) == ""
