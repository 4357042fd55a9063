"""Errors and tracking failures by the frames' index in their take
(train.evaluation.error_by_time): golden values of the pooling, a recording with a result
end to end through the command, with and without a base run."""

from __future__ import annotations

import json

import numpy as np
import pytest
from depthmocap.runtime.export import ResultWriter
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.recording import RecordingWriter
from depthmocap.train.evaluation import error_by_time as ebt

CAM = Intrinsics(fx=10.0, fy=10.0, cx=10.0, cy=10.0, width=20, height=20)
CONFIG = "hybrid, default body @ 0.2 rad"


def test_pooled_by_bin_golden():
    a = {
        "index": np.array([0, 1, 2, 3, 4]),
        "error": np.array([0.010, 0.020, np.nan, 0.040, 0.050]),
        "failure": np.array([False, True, False, False, True]),
    }
    b = {"index": np.array([0, 7]), "error": np.array([0.030, 0.070]),
         "failure": np.array([False, False])}  # fmt: skip
    rows = ebt.pooled_by_bin([a, b], bin_frames=2, bins=3)
    assert [(r["first"], r["last"], r["frames"]) for r in rows] == [
        (0, 1, 3),
        (2, 3, 2),
        (4, None, 2),
    ]
    assert rows[0]["error_mm"] == pytest.approx(20.0)  # 10, 20, 30
    assert rows[1]["error_mm"] == pytest.approx(40.0)  # the frame without a pose left out
    assert rows[2]["error_mm"] == pytest.approx(60.0)  # frames 4 and 7: the open last bin
    assert [r["failure_pct"] for r in rows] == pytest.approx([100 / 3, 0.0, 50.0])
    empty = ebt.pooled_by_bin([], 4, 2)
    assert [r["frames"] for r in empty] == [0, 0] and np.isnan(empty[0]["error_mm"])
    with pytest.raises(ValueError):
        ebt.pooled_by_bin([a], 0, 3)
    text = ebt.format_table(rows, base=rows)
    assert "| 0-1 | 3 | 20.0 -> 20.0 | 33.3% -> 33.3% |" in text and "| 4- | 2 |" in text


def test_pose_kinds_and_their_table_golden():
    status = np.array(["detected", "tracked", "tracked", "tracked", "detected", "lost",
                       "detected", "tracked"])  # fmt: skip
    nan = np.nan
    errors = {
        "rechecked": np.array([nan, nan, 1.0, nan, nan, nan, nan, nan]),
        "kept_over_detector": np.array([nan, nan, nan, 1.0, nan, nan, nan, nan]),
        "detector_waited": np.array([nan, nan, nan, nan, nan, nan, nan, 1.0]),
        "overlap": np.full(8, 0.8),  # a signal, not a flag
    }
    kinds = ebt.pose_kinds(status, errors).tolist()
    assert kinds == ["track start", "tracked", "tracked, rechecked", "tracked, tests failed",
                     "detection taken", "lost", "track start",
                     "tracked, detector waited"]  # fmt: skip
    run = {
        "kind": np.array(kinds, dtype=object),
        "error": np.array([0.05, 0.02, 0.04, 0.30, 0.06, nan, 0.05, 0.03]),
        "worst": np.array([0.10, 0.05, 0.25, 0.50, 0.10, nan, 0.10, 0.10]),
    }
    rows = {r["kind"]: r for r in ebt.pooled_by_kind([run])}
    assert list(rows) == [k for k in ebt.KINDS if k in kinds]  # in KINDS order
    assert rows["track start"]["frames"] == 2 and rows["track start"]["error_mm"] == pytest.approx(
        50.0
    )
    assert rows["tracked, tests failed"]["gross_pct"] == pytest.approx(50.0)  # 1 of 2 frames
    assert rows["tracked"]["frames_pct"] == pytest.approx(12.5)
    assert np.isnan(rows["lost"]["error_mm"]) and rows["lost"]["gross_pct"] == 0.0
    assert "| tracked, tests failed | 1 | 12.5% | 300.0 | 50.0% |" in ebt.format_kinds(
        list(rows.values())
    )
    assert ebt.pooled_by_kind([]) == []


def _recording(tmp_path, frames: int):
    truth = np.zeros((frames, len(sk.JOINT_NAMES), 3))
    truth[..., 2] = 2.0
    rec = tmp_path / "rec"
    with RecordingWriter(rec, CAM, fps=30.0, source="test") as w:
        for _ in range(frames):
            w.write_frame(np.full((20, 20), 2000, np.uint16), np.ones((20, 20), np.uint8))
        w.write_groundtruth(truth, sk.JOINT_NAMES)
    return rec, truth


def _result(tmp_path, name: str, truth: np.ndarray, statuses: list[str], off_m: list[float]):
    """A result whose every joint is ``off_m[i]`` beside the truth in frame i (none when
    lost)."""
    res = tmp_path / name
    with ResultWriter(res, BodyShape.default(), 30.0, CAM, "hybrid", "test") as w:
        for i, (status, off) in enumerate(zip(statuses, off_m, strict=True)):
            joints = None if status == "lost" else truth[i] + np.array([off, 0.0, 0.0])
            w.write_frame(i, i / 30, status, joints, None if joints is None else np.zeros(34), {})
    return res


def _report(tmp_path, name: str, rec, res):
    out = tmp_path / name
    out.mkdir()
    entry = {"recording": str(rec), "result": str(res)}
    (out / "report.json").write_text(json.dumps({CONFIG: {"per_recording": {"rec": entry}}}))
    return out


def test_a_recording_end_to_end(tmp_path, capsys):
    """Detected first (a track's start, not a failure), re-detected at frame 2, lost at 4 (a
    failure, as ``tracking_failure_pct`` counts it) and found again at 5 (a new track's
    start, not one)."""
    rec, truth = _recording(tmp_path, 6)
    statuses = ["detected", "tracked", "detected", "tracked", "lost", "detected"]
    res = _result(tmp_path, "res", truth, statuses, [0.01, 0.02, 0.03, 0.04, 0.0, 0.06])
    rows = ebt.frame_rows(rec, res)
    np.testing.assert_array_equal(rows["index"], np.arange(6))
    np.testing.assert_allclose(rows["error"][[0, 1, 2, 3, 5]], [0.01, 0.02, 0.03, 0.04, 0.06])
    assert np.isnan(rows["error"][4])
    assert rows["failure"].tolist() == [False, False, True, False, True, False]
    new = _report(tmp_path, "new", rec, res)
    assert ebt.main([str(new), "--config", CONFIG, "--bin", "4", "--bins", "2"]) == 0
    text = capsys.readouterr().out
    assert "| 0-3 | 4 | 25.0 | 25.0% |" in text and "| 4- | 2 | 60.0 | 50.0% |" in text
    assert "| track start | 2 | 33.3% | 35.0 | 0.0% |" in text  # frames 0 and 5
    assert "| detection taken | 1 | 16.7% | 30.0 |" in text and "| lost | 1 |" in text
    base_res = _result(tmp_path, "base_res", truth, ["detected"] + ["tracked"] * 5, [0.05] * 6)
    base = _report(tmp_path, "base", rec, base_res)
    args = [str(new), "--base", str(base), "--config", CONFIG, "--bin", "4", "--bins", "2"]
    assert ebt.main(args) == 0
    assert "| 0-3 | 4 | 50.0 -> 25.0 | 0.0% -> 25.0% |" in capsys.readouterr().out
    real = tmp_path / "real"  # real_benchmark's report: its per_recording at the top
    real.mkdir()
    entry = {"recording": str(rec), "result": str(res)}
    (real / "report.json").write_text(json.dumps({"data": "x", "per_recording": {"rec": entry}}))
    assert len(ebt.run_entries([real, new], CONFIG)) == 2
    assert ebt.main([str(real), "--bin", "4", "--bins", "2"]) == 0
    assert "| 0-3 | 4 | 25.0 | 25.0% |" in capsys.readouterr().out
    assert ebt.main([str(tmp_path), "--config", CONFIG]) == 2  # no report.json: said
    assert "no report.json" in capsys.readouterr().err
