"""Settings alternated recording by recording, reports in dev_benchmark's layout."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
from depthmocap.train.evaluation import paired_runs
from depthmocap.train.evaluation.compare_runs import compare, load_runs


def test_parse_setting_and_order():
    assert paired_runs.parse_setting("a=x/y.yaml") == ("a", Path("x/y.yaml"))
    for bad in ("a", "=x.yaml", "a=", "a/b=x.yaml"):
        with pytest.raises(argparse.ArgumentTypeError):
            paired_runs.parse_setting(bad)
    assert paired_runs.setting_order(["a", "b", "c"], 0) == ["a", "b", "c"]
    assert paired_runs.setting_order(["a", "b", "c"], 1) == ["c", "b", "a"]


def test_settings_alternate_per_recording_and_reports_compare(tmp_path, monkeypatch):
    calls = []

    def fake_run_config(name, rec, out, model, device, mode_config, tracker, reuse, realtime):
        calls.append((rec.name, mode_config.name, tracker, realtime, out))
        err = 40.0 if mode_config.name == "a.yaml" else 38.0
        return {"recording": str(rec), "frames": 10, "mean_joint_error_mm": err,
                "tracking_failure_pct": 1.0}  # fmt: skip

    monkeypatch.setattr(paired_runs, "run_config", fake_run_config)
    recs = [tmp_path / f"HDM_{i}" for i in range(3)]
    settings = [("a", tmp_path / "a.yaml"), ("b", tmp_path / "b.yaml")]
    reports = paired_runs.run_paired(settings, recs, tmp_path / "out", "f.npz", realtime=True)
    assert [(r, c) for r, c, *_ in calls] == [
        ("HDM_0", "a.yaml"), ("HDM_0", "b.yaml"), ("HDM_1", "b.yaml"), ("HDM_1", "a.yaml"),
        ("HDM_2", "a.yaml"), ("HDM_2", "b.yaml"),
    ]  # fmt: skip
    assert all(t == {"max_step_rad": 0.2} and live for _, _, t, live, _ in calls)
    row = "hybrid, default body, live @ 0.2 rad"
    folder = "hybrid_default_body_live_0.2_rad"  # dev_benchmark's folder for that row
    assert calls[0][4] == tmp_path / "out" / "a" / folder / "HDM_0"
    assert set(reports) == {"a", "b"} and row in reports["a"]
    base = load_runs([tmp_path / "out" / "a"], row)
    new = load_runs([tmp_path / "out" / "b"], row)
    assert compare(base, new)["change"] == pytest.approx(-2.0)


def test_main_refuses_one_setting_or_a_missing_file(tmp_path, capsys):
    cfg = tmp_path / "a.yaml"
    cfg.write_text("{}\n")
    with pytest.raises(SystemExit):
        paired_runs.main(["--setting", f"a={cfg}"])
    assert "two or more" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        paired_runs.main(["--setting", f"a={cfg}", "--setting", f"b={tmp_path / 'no.yaml'}"])
    assert "no such file" in capsys.readouterr().err
