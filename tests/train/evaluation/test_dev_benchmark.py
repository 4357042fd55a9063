"""The dev benchmark's table rows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from depthmocap.train.evaluation.dev_benchmark import (
    HEADER,
    body_file,
    body_length_reports,
    format_failures,
    format_row,
    main,
    mean_of_runs,
)


def test_rows_match_the_header_and_detector_modes_have_no_tracking_failure():
    agg = {"mean_joint_error_mm": 36.1, "precision_10cm": 0.963, "tracking_failure_pct": 2.0,
           "detector_frames_pct": 3.9, "system_failure_pct": 7.2}  # fmt: skip
    columns = HEADER.splitlines()[0].count("|")
    hybrid, detector = format_row("hybrid", agg), format_row("detector", agg)
    assert hybrid.count("|") == detector.count("|") == columns
    assert "| 36.1 |" in hybrid and "| 96.3% |" in hybrid and "| 2.0% | 3.9% | 7.2% |" in hybrid
    assert "| (every frame) | 3.9% |" in detector and "2.0%" not in detector
    assert "| n/a |" in hybrid  # missing metrics are marked, not invented


def test_failure_lines_name_frames_and_worst_joints():
    reports = {
        "HDM_a": {"system_failure_frames": [
            {"frame": 0, "worst_joint": "l_wrist", "error_mm": 312.4},
            {"frame": 7, "worst_joint": None, "error_mm": None},
        ]},
        "HDM_b": {"system_failure_frames": []},
        "HDM_c": {},  # a report from before the field existed
    }  # fmt: skip
    text = format_failures("hybrid", reports)
    assert text.splitlines()[1:] == ["  HDM_a: 0 l_wrist 31 cm, 7 no pose"]
    assert format_failures("hybrid", {"HDM_b": reports["HDM_b"]}).endswith("\n  none")


def test_mean_of_runs_and_rows_of_runs():
    a = {"mean_joint_error_mm": 34.0, "system_failure_pct": 1.1, "fps": None}
    b = {"mean_joint_error_mm": 35.0, "system_failure_pct": 1.5, "fps": 12.0}
    mean = mean_of_runs([a, b])
    assert mean["mean_joint_error_mm"] == 34.5 and mean["system_failure_pct"] == 1.3
    assert mean["fps"] is None and mean["precision_10cm"] is None  # missing in a run: no mean
    # Rows of a run are named freely; the mode decides the tracking column.
    assert "| 1.3% | n/a |" in format_row("hybrid, mean of 2", mean, "hybrid")
    assert "(every frame)" in format_row("detector @ run 2", mean, "detector")


@pytest.mark.parametrize(
    "args, message",
    [
        (["--trust-regions", "0.2", "nan"], "--trust-regions must be positive radians"),
        (["--trust-regions", "-0.1"], "--trust-regions must be positive radians"),
        (["--mode-config", "no/such.yaml"], "--mode-config: no such file"),
    ],
)
def test_bad_arguments_exit_2_before_running_anything(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as exit_info:
        main(["--recordings", str(tmp_path), "--out", str(tmp_path / "out"), *args])
    assert exit_info.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_the_ground_truth_labels_row_reads_each_recording_s_own_labels(tmp_path, monkeypatch):
    import depthmocap.train.evaluation.dev_benchmark as bench
    import yaml

    commands = []
    monkeypatch.setattr(bench, "_run", commands.append)
    monkeypatch.setattr(
        bench, "evaluate", lambda rec, result, **kw: type("E", (), {"report": {}})()
    )
    rec, out = tmp_path / "HDM_a", tmp_path / "out" / "hybrid" / "HDM_a"
    cfg = tmp_path / "hybrid.yaml"
    cfg.write_text("epsilon1_cm: 3.0\ntracker:\n  use_labels: true\n")
    bench.run_config(
        "hybrid, ground-truth labels", rec, out, "forest.npz", "cpu", cfg, {"max_step_rad": 0.2}
    )
    cmd = commands[0]
    written = yaml.safe_load(Path(cmd[cmd.index("--config") + 1]).read_text())
    assert written["labels_from_recording"] == str(rec)
    assert written["epsilon1_cm"] == 3.0  # the preset's other settings stay
    assert written["tracker"] == {"use_labels": True, "max_step_rad": 0.2}


def test_calibration_recordings_are_looked_up_beside_the_recordings_folder(tmp_path):
    """data/dev_all's clips hold other bodies than data/dev's of the same name: each set's
    calibration recordings live in its own OUT_calib folder."""
    rec = tmp_path / "dev_all" / "HDM_mm_squat1Reps_037_120"
    rec.mkdir(parents=True)
    (tmp_path / "dev_calib" / rec.name).mkdir(parents=True)  # the other set's: not used
    with pytest.raises(RuntimeError, match=r"dev_all_calib/HDM_mm_squat1Reps_037_120"):
        body_file("calibrated", rec, tmp_path / "bodies", "forest.npz")


def test_body_length_reports_compare_made_bodies_and_name_unreadable_ones(tmp_path):
    import torch
    from depthmocap.shared.body import BodyShape

    body = BodyShape.default(torch.float64)
    recs = [tmp_path / "recs" / n for n in ("HDM_a", "HDM_b", "HDM_c")]
    for r in recs:
        r.mkdir(parents=True)
        body.save(r / "body.json")
    bodies = tmp_path / "bodies"
    for r, scale in ((recs[0], 1.0), (recs[1], 1.1)):  # HDM_c has no calibrated body
        (bodies / "calibrated" / r.name).mkdir(parents=True)
        body.scaled(scale).save(bodies / "calibrated" / r.name / "body.json")
    reports = body_length_reports(bodies, recs, {"calibrated", "gt", "personalized"})
    assert list(reports) == ["calibrated"]  # no personalized bodies were made; gt is no estimate
    errors, text = reports["calibrated"]
    assert errors["bodies"] == 2 and errors["per_body_cm"][0] == 0.0
    assert errors["per_body_cm"][1] == pytest.approx(10 * float(body.lengths.mean()), abs=1e-3)
    assert text.startswith("calibrated bodies (2): bone lengths")
    # A corrupt reference body: named, and no exception (the runs' report is still written).
    (recs[1] / "body.json").write_text("{broken")
    errors, text = body_length_reports(bodies, recs, {"calibrated"})["calibrated"]
    assert errors is None and "not compared" in text and "HDM_b" in text


def test_speed_line_median_rate_worst_p95_and_weighted_latency():
    from depthmocap.train.evaluation.dev_benchmark import format_speed

    per_rec = {
        "a": {"frame_time_p50_ms": 20.0, "frame_time_p95_ms": 40.0, "latency_mean_ms": 30.0,
              "frames": 100},
        "b": {"frame_time_p50_ms": 50.0, "frame_time_p95_ms": 90.0, "latency_mean_ms": 60.0,
              "frames": 300},
        "c": {"frame_time_p50_ms": 25.0, "frame_time_p95_ms": 45.0, "latency_mean_ms": 30.0,
              "frames": 100},
    }  # fmt: skip
    line = format_speed("hybrid", per_rec)
    # Median of 50, 20 and 40 frames/s; the worst p95; latency (30*100+60*300+30*100)/500.
    assert "median frame rate 40.0 frames/s" in line
    assert "95th-percentile frame time 90.0 ms" in line and "median 45.0" in line
    assert "mean latency 48.0 ms" in line
    assert "not recorded" in format_speed("old", {"a": {"frame_time_p50_ms": None}})


# ---------------------------------------------------------------------------------------------
# The broad protocol's tables (--protocol broad)


def test_group_aggregates_weight_by_frames_and_skip_recordings_without_a_group():
    from depthmocap.train.evaluation.dev_benchmark import group_aggregates

    reports = {
        "a": {"frames": 10, "mean_joint_error_mm": 10.0, "system_failure_pct": 0.0},
        "b": {"frames": 30, "mean_joint_error_mm": 30.0, "system_failure_pct": 10.0},
        "c": {"frames": 60, "mean_joint_error_mm": 50.0, "system_failure_pct": None},
        "d": {"frames": 99, "mean_joint_error_mm": 99.0},  # not in any group
    }
    groups = {"a": "squat", "b": "squat", "c": "jog", "e": "hop"}  # e was not run
    out = group_aggregates(reports, groups)
    assert list(out) == ["jog", "squat"]  # sorted; no empty "hop"
    squat, n, frames = out["squat"]
    assert (n, frames) == (2, 40)
    assert squat["mean_joint_error_mm"] == pytest.approx((10 * 10 + 30 * 30) / 40)
    assert squat["system_failure_pct"] == pytest.approx(7.5)
    assert out["jog"][0]["mean_joint_error_mm"] == 50.0
    assert out["jog"][0]["system_failure_pct"] is None  # no run measured it


def test_group_tables_and_diagnostic_labels():
    from depthmocap.train.evaluation.dev_benchmark import format_group_table, row_label

    assert row_label("hybrid, default body") == "hybrid, default body"
    assert row_label("hybrid, calibrated body") == "hybrid, calibrated body"
    assert row_label("hybrid") == "hybrid (diagnostic: true body)"
    assert "diagnostic: true body and labels" in row_label("hybrid, ground-truth labels")
    assert "diagnostic" in row_label("tracker")
    reports = {"a": {"frames": 10, "mean_joint_error_mm": 41.0}, "b": {"frames": 5}}
    text = format_group_table("camera", "hybrid, default body", "hybrid", reports,
                              {"a": "side", "b": "frontal"})  # fmt: skip
    lines = text.splitlines()
    assert lines[0] == "hybrid, default body, per camera:"
    assert lines[2].startswith("| camera (recordings, frames) |")
    assert lines[2].count("|") == HEADER.splitlines()[0].count("|") == lines[-1].count("|")
    assert lines[4].startswith("| frontal (1, 5) | n/a |")
    assert lines[5].startswith("| side (1, 10) | 41.0 |")


def _protocol_folder(tmp_path, names, version=1, render=None):
    """A protocol folder with a manifest naming ``names`` and tiny recordings for ``render``."""
    import json

    from depthmocap.shared.camera import Intrinsics
    from depthmocap.shared.recording import RecordingWriter

    folder = tmp_path / "dev_broad"
    folder.mkdir()
    classes = {"r1": "squat", "r2": "squat", "r3": "jog"}
    recs = [{"name": n, "motion_class": classes[n], "view": "side" if n == "r2" else "frontal",
             "cut": "feet" if n == "r3" else "none", "sex": "female",
             "height_class": "tall", "frames": 2} for n in names]  # fmt: skip
    (folder / "manifest.json").write_text(json.dumps({"version": version, "recordings": recs}))
    for n in names if render is None else render:
        with RecordingWriter(folder / n, Intrinsics.kinect_v1(80), fps=30.0) as w:
            for _ in range(2):
                w.write_frame(np.zeros((60, 80), np.uint16))
            w.write_groundtruth(np.zeros((2, 1, 3), np.float32), ["head"])
    return folder


@pytest.mark.parametrize(
    "version, render, message",
    [
        (None, None, "no protocol manifest"),
        (2, None, "this code reads version 1"),
        (1, ["r1", "r3"], "1 of the manifest's 3 recordings are missing"),
    ],
)
def test_broad_protocol_refuses_a_bad_or_incomplete_folder(
    tmp_path, capsys, version, render, message
):
    folder = _protocol_folder(tmp_path, ["r1", "r2", "r3"], version or 1, render)
    if version is None:
        (folder / "manifest.json").unlink()
    args = ["--protocol", "broad", "--recordings", str(folder), "--out", str(tmp_path / "out")]
    assert main(args) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_broad_protocol_prints_the_headline_then_tables_per_group(tmp_path, capsys, monkeypatch):
    import json

    import depthmocap.train.evaluation.dev_benchmark as bench

    folder = _protocol_folder(tmp_path, ["r1", "r2", "r3"])
    errors = {"r1": 30.0, "r2": 60.0, "r3": 90.0}
    ran = []

    def fake_run(name, rec, out, *args):
        ran.append((name, rec.name))
        return {"frames": 2, "mean_joint_error_mm": errors[rec.name], "system_failure_pct": 0.0}

    monkeypatch.setattr(bench, "run_config", fake_run)
    out = tmp_path / "out"
    args = ["--protocol", "broad", "--recordings", str(folder), "--out", str(out)]
    assert main([*args, "--configs", "hybrid", "hybrid, default body"]) == 0
    text = capsys.readouterr().out
    assert "3 dev recordings from" in text and "(6 frames, broad protocol version 1)" in text
    rows = [line for line in text.splitlines() if line.startswith("| hybrid")]
    assert rows[0].startswith("| hybrid, default body | 60.0 |")  # the headline first
    assert rows[1].startswith("| hybrid (diagnostic: true body) | 60.0 |")
    assert "hybrid, default body, per motion class:" in text
    assert "| jog (1, 2) | 90.0 |" in text and "| squat (2, 4) | 45.0 |" in text
    assert "| cut (feet) (1, 2) | 90.0 |" in text and "| uncut (2, 4) | 45.0 |" in text
    report = json.loads((out / "report.json").read_text())
    per_class = report["hybrid, default body"]["per_group"]["motion class"]
    assert per_class["squat"] == {
        "mean": pytest.approx(per_class["squat"]["mean"]), "recordings": 2, "frames": 4
    }  # fmt: skip
    assert per_class["squat"]["mean"]["mean_joint_error_mm"] == 45.0
    # By default only the headline runs; --limit takes the first recordings.
    ran.clear()
    assert main([*args, "--limit", "2"]) == 0
    assert ran == [("hybrid, default body", "r1"), ("hybrid, default body", "r2")]


def test_reuse_results_evaluates_complete_results_and_tracks_the_rest(tmp_path, monkeypatch):
    import json

    import depthmocap.train.evaluation.dev_benchmark as bench

    commands = []
    monkeypatch.setattr(bench, "_run", commands.append)
    monkeypatch.setattr(
        bench, "evaluate", lambda rec, result, **kw: type("E", (), {"report": {}})()
    )
    done, partial = tmp_path / "out" / "a", tmp_path / "out" / "b"
    stopped = tmp_path / "out" / "c"  # closed cleanly by a signal: complete files, too few frames
    summaries = ((done, {"complete": True, "extra": {"stopped": None}}),
                 (partial, {"complete": False}),
                 (stopped, {"complete": True, "extra": {"stopped": "terminated"}}))  # fmt: skip
    for out, summary in summaries:
        (out / "result").mkdir(parents=True)
        (out / "result" / "summary.json").write_text(json.dumps(summary))
    cfg = tmp_path / "hybrid.yaml"
    cfg.write_text("{}\n")
    for out in (done, partial, stopped):
        bench.run_config("hybrid, default body", tmp_path / out.name, out, "f.npz", "cpu", cfg,
                         reuse=True)  # fmt: skip
    assert len(commands) == 2
    assert str(partial / "result") in commands[0] and str(stopped / "result") in commands[1]
    bench.run_config("hybrid, default body", tmp_path / "a", done, "f.npz", "cpu", cfg)
    assert len(commands) == 3  # without reuse, tracked again


def test_realtime_tracks_paced_and_holds_the_skipped_frames(tmp_path, monkeypatch):
    """``--realtime``: runtime-track paces the recording (the newest frame wins), and the
    evaluation scores each skipped frame with the last pose written."""
    import depthmocap.train.evaluation.dev_benchmark as bench

    commands, held = [], []
    monkeypatch.setattr(bench, "_run", commands.append)

    def fake_evaluate(rec, result, hold_skipped=False):
        held.append(hold_skipped)
        return type("E", (), {"report": {"frames_held": 2}})()

    monkeypatch.setattr(bench, "evaluate", fake_evaluate)
    rec, out = tmp_path / "HDM_a", tmp_path / "out" / "HDM_a"
    assert bench.run_config("hybrid, default body", rec, out, "f.npz", "cpu", None,
                            realtime=True) == {"frames_held": 2}  # fmt: skip
    bench.run_config("hybrid, default body", rec, out, "f.npz", "cpu", None)
    assert "--realtime" in commands[0] and "--realtime" not in commands[1]
    assert held == [True, False]
