"""compare_runs on hand-made dev_benchmark reports: pooled figures, each recording's share of
the change (golden values), groups from protocol.json, and the refusals."""

from __future__ import annotations

import json

import pytest
from depthmocap.train.evaluation import compare_runs as cr

CONFIG = "hybrid, default body"


def _write_run(folder, recordings, errors, frames=None):
    """A dev_benchmark --out folder whose recordings have ``errors`` (mm) and the figures
    derived from them; the recordings' protocol.json alternate two motion classes."""
    folder.mkdir(parents=True)
    per = {}
    for i, (rec, err) in enumerate(zip(recordings, errors)):
        n = 10 if frames is None else frames[i]
        per[rec.name] = {
            "recording": str(rec),
            "frames": n,
            "mean_joint_error_mm": err,
            "mean_joint_error_offset_normalized_mm": err - 10.0,
            "precision_10cm": 0.9,
            "tracking_failure_pct": 5.0,
            "system_failure_pct": 10.0,
            "system_failure_observed_pct": None,
        }
    (folder / "report.json").write_text(json.dumps({CONFIG: {"per_recording": per}}))
    return folder


@pytest.fixture
def recordings(tmp_path):
    recs = []
    for i in range(8):
        rec = tmp_path / "data" / f"rec{i}"
        rec.mkdir(parents=True)
        spec = {"motion_class": "jog" if i % 2 else "squat", "view": "side"}
        (rec / "protocol.json").write_text(json.dumps(spec))
        recs.append(rec)
    return recs


def test_compare_golden(recordings, tmp_path):
    base = [40.0] * 8
    new = [40.0, 45.0, 40.0, 40.0, 38.5, 40.0, 40.0, 30.0]  # one big gain, one loss
    frames = [10, 10, 10, 10, 10, 10, 10, 30]
    a = _write_run(tmp_path / "a", recordings, base, frames)
    b = _write_run(tmp_path / "b", recordings, new, frames)
    c = cr.compare(cr.load_runs([a]), cr.load_runs([b]))
    assert c["recordings"] == 8 and c["frames"] == 100
    assert c["pooled"]["mean_joint_error_mm"] == pytest.approx((40.0, 37.35))
    none = c["pooled"]["system_failure_observed_pct"][0]
    assert none != none  # no recording has it: NaN
    assert c["change"] == pytest.approx(-3.0 + 0.5 - 0.15)
    assert (c["better"], c["worse"]) == (2, 1)
    assert c["largest_gains"][0] == (pytest.approx(-3.0), "rec7")
    assert c["largest_losses"][0] == (pytest.approx(0.5), "rec1")
    assert c["trimmed"] == pytest.approx(0.0)
    jog = c["groups"]["motion_class"]["jog"]  # rec1, 3, 5, 7
    assert jog[2] == 4 and jog[1] == pytest.approx((450 + 400 + 400 + 900) / 60)
    assert set(c["groups"]) == {"motion_class", "view"}
    text = cr.format_comparison(c)
    assert "| joint error mm | 40.00 | 37.35 |" in text
    assert "by motion class: 1 of 2 better by over 0.5 mm, 0 worse" in text


def test_halves_pool_and_refusals(recordings, tmp_path, capsys):
    a1 = _write_run(tmp_path / "a1", recordings[:4], [40.0] * 4)
    a2 = _write_run(tmp_path / "a2", recordings[4:], [50.0] * 4)
    b = _write_run(tmp_path / "b", recordings, [45.0] * 8)
    c = cr.compare(cr.load_runs([a1, a2]), cr.load_runs([b]))
    assert c["pooled"]["mean_joint_error_mm"] == pytest.approx((45.0, 45.0))
    assert c["change"] == pytest.approx(0.0) and (c["better"], c["worse"]) == (4, 4)
    assert cr.main(["--base", str(a1), str(a2), "--new", str(b)]) == 0
    assert "8 recordings, 80 frames" in capsys.readouterr().out
    # Different recordings, a folder without a report, the same recording twice.
    assert cr.main(["--base", str(a1), "--new", str(b)]) == 2
    assert "different recordings" in capsys.readouterr().err
    with pytest.raises(cr.CompareError, match="no report.json"):
        cr.load_runs([tmp_path])
    with pytest.raises(cr.CompareError, match="more than one"):
        cr.load_runs([a1, a1])
    with pytest.raises(cr.CompareError, match="no configuration"):
        cr.load_runs([a1], "hybrid")
