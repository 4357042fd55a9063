"""group_table on hand-made dev_benchmark reports: groups pooled by frames within a run, runs
averaged (golden values), and the refusals."""

from __future__ import annotations

import json

import pytest
from depthmocap.train.evaluation import group_table as gt
from depthmocap.train.evaluation.compare_runs import CompareError, load_runs


def _report(folder, recordings, runs):
    """``runs``: {config: [(error mm, frames), ...] per recording}."""
    folder.mkdir(parents=True, exist_ok=True)
    report = {}
    for config, rows in runs.items():
        per = {}
        for rec, (err, n) in zip(recordings, rows, strict=True):
            per[rec.name] = {
                "recording": str(rec), "frames": n, "mean_joint_error_mm": err,
                "mean_joint_error_offset_normalized_mm": err - 10.0, "precision_10cm": 0.9,
                "tracking_failure_pct": 5.0, "system_failure_pct": 10.0,
                "system_failure_observed_pct": None,
            }  # fmt: skip
        report[config] = {"per_recording": per}
    (folder / "report.json").write_text(json.dumps(report))
    return folder


@pytest.fixture
def recordings(tmp_path):
    recs = []
    for i, cls in enumerate(["jog", "jog", "squat"]):
        rec = tmp_path / "data" / f"rec{i}"
        rec.mkdir(parents=True)
        (rec / "protocol.json").write_text(json.dumps({"motion_class": cls}))
        recs.append(rec)
    return recs


def test_groups_pooled_by_frames_then_runs_averaged(recordings, tmp_path):
    out = _report(tmp_path / "out", recordings, {
        "r1": [(40.0, 10), (10.0, 30), (50.0, 20)],
        "r2": [(60.0, 10), (30.0, 30), (50.0, 20)],
    })  # fmt: skip
    table = gt.group_figures([load_runs([out], "r1"), load_runs([out], "r2")], "motion_class")
    assert list(table) == ["jog", "squat", "all"]
    # jog: run 1 (400 + 300) / 40 = 17.5, run 2 (600 + 900) / 40 = 37.5 -> 27.5
    assert table["jog"]["mean_joint_error_mm"] == pytest.approx(27.5)
    assert (table["jog"]["recordings"], table["jog"]["frames"]) == (2, 40)
    # all: run 1 1700 / 60, run 2 2500 / 60 -> 35.0
    assert table["all"]["mean_joint_error_mm"] == pytest.approx(35.0)
    assert table["all"]["mean_joint_error_offset_normalized_mm"] == pytest.approx(25.0)
    nan = table["all"]["system_failure_observed_pct"]
    assert nan != nan  # no recording has it
    text = gt.format_group_table(table, "motion_class")
    assert "| jog (2, 40) | 27.5 | 17.5 | 90.0 |" in text and "| **all** (3, 60) | 35.0" in text


def test_runs_of_different_recordings_are_refused(recordings, tmp_path, capsys):
    a = _report(tmp_path / "a", recordings, {"r": [(1.0, 1)] * 3})
    b = _report(tmp_path / "b", recordings[:2], {"r": [(1.0, 1)] * 2})
    with pytest.raises(CompareError):
        gt.group_figures([load_runs([a], "r"), load_runs([b], "r")], "motion_class")
    assert gt.main([str(a), "--configs", "r", "nope"]) == 2
    assert "nope" in capsys.readouterr().err
    assert gt.main([str(a), "--configs", "r"]) == 0
    assert "| squat (1, 1) |" in capsys.readouterr().out
