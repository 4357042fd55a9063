"""Measuring the size search's bias (bench.body_scale_fit)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from depthmocap.bench import body_scale_fit as fit


def test_correction_is_the_median_ratio():
    rng = np.random.default_rng(0)
    needed = rng.uniform(0.85, 1.15, 41)
    found = needed / 1.03 * (1 + rng.normal(0, 0.002, 41))
    found[:5] = 1.0  # a few searches far off move a median little
    assert fit.correction_of(needed, found) == pytest.approx(1.03, abs=0.002)
    with pytest.raises(ValueError, match="non-empty"):
        fit.correction_of(np.ones(3), np.ones(2))
    with pytest.raises(ValueError, match="non-empty"):
        fit.correction_of(np.ones(0), np.ones(0))


def test_size_errors_in_centimetres_of_stature():
    e = fit.size_errors(np.array([1.0, 1.0]), np.array([0.98, 1.01]), stature_m=1.75)
    assert e["bias_cm"] == pytest.approx(100 * 1.75 * (-0.01) / 2)
    assert e["mean_abs_cm"] == pytest.approx(100 * 1.75 * 0.015)
    assert e["max_abs_cm"] == pytest.approx(3.5)
    assert e["std_cm"] == pytest.approx(100 * 1.75 * 0.015)


def test_cross_validation_uses_the_other_half():
    needed = np.array([1.0, 1.0, 1.0, 1.0])
    found = np.array([0.5, 0.8, 0.5, 0.8])  # evens need 2, odds 1.25
    np.testing.assert_allclose(fit.cross_validated(needed, found), [0.625, 1.6, 0.625, 1.6])


def test_cli_resumes_and_reports(tmp_path, monkeypatch, capsys):
    """Recordings already measured are not measured again; a torn last line is; the report
    holds the correction and the errors before and after it."""
    recs = tmp_path / "recs"
    for name in "abcd":
        (recs / name).mkdir(parents=True)
        (recs / name / "body.json").write_text("{}")
    measured = []

    def fake(rec, population, model=None):
        measured.append(rec.name)
        needed = {"a": 0.9, "b": 1.0, "c": 1.1, "d": 1.05}[rec.name]
        return {"recording": rec.name, "needed": needed, "found": needed / 1.02, "frames": 30,
                "curves": [[0.5, 0.6]], "factors": [0.9, 1.1]}  # fmt: skip

    monkeypatch.setattr(fit, "search_recording", fake)
    out = tmp_path / "fit" / "searches.jsonl"
    out.parent.mkdir()
    row_a = {"recording": "a", "needed": 0.9, "found": 0.9 / 1.02}
    out.write_text(json.dumps(row_a) + "\n" + '{"recording": "b", "nee')
    assert fit.main(["--recordings", str(recs), "--out", str(out)]) == 0
    assert measured == ["b", "c", "d"]
    assert len(out.read_text().splitlines()) == 4
    report = json.loads(out.with_suffix(".report.json").read_text())
    assert report["correction"] == pytest.approx(1.02)
    assert report["recordings"] == 4 and report["not_ended"] == 0
    assert report["before"]["bias_cm"] < -1 and abs(report["after"]["bias_cm"]) < 1e-9
    assert "correction 1.0200" in capsys.readouterr().out


def test_cli_errors(tmp_path, capsys):
    with pytest.raises(SystemExit):
        fit.main(["--recordings", str(tmp_path / "none"), "--out", str(tmp_path / "o.jsonl")])
    with pytest.raises(SystemExit):  # a folder without recordings
        fit.main(["--recordings", str(tmp_path), "--out", str(tmp_path / "o.jsonl")])


@pytest.mark.slow
def test_search_on_a_stream_ends_with_its_curves(one_thread):
    """The shipped search on the built-in demo: it ends within the grid, uncorrected, after
    its samples, with one overlap curve per sample."""
    from depthmocap.runtime.hybrid.body_scale import BodyScaleConfig
    from depthmocap.runtime.streams import open_stream

    cfg = BodyScaleConfig()
    row = fit.search_stream(open_stream("demo"))
    assert row["found"] is not None and cfg.min_scale <= row["found"] <= cfg.max_scale
    G, S = len(cfg.girths), len(cfg.scales())
    curves = np.asarray(row["curves"], dtype=float)  # None (a girth not refitted): NaN
    assert curves.shape == (cfg.samples, G * S) and row["girths"] == list(cfg.girths)
    assert row["girth"] in cfg.girths
    refitted = np.isfinite(curves).reshape(cfg.samples, G, S).all(axis=2)  # (samples, G)
    first = cfg.samples if cfg.girth_samples is None else min(cfg.girth_samples, cfg.samples)
    assert refitted[:first].all()  # every girth until the girth is kept, then that one
    assert (refitted[first:] == (np.asarray(cfg.girths) == row["girth"])).all()
    assert row["frames"] > (cfg.samples - 1) * cfg.every  # every k-th tracked frame


def test_a_bad_recording_is_a_clear_error_and_keeps_what_was_measured(tmp_path, capsys):
    recs = tmp_path / "recs"
    for name in ("a", "b"):
        (recs / name).mkdir(parents=True)
        (recs / name / "body.json").write_text("{}")
    out = tmp_path / "searches.jsonl"
    out.write_text(json.dumps({"recording": "a", "needed": 1.0, "found": 0.97}) + "\n")
    # "b"'s body file is not one: the loader's error, named by recording.
    assert fit.main(["--recordings", str(recs), "--out", str(out)]) == 2
    assert "error: b:" in capsys.readouterr().err
    assert json.loads(out.read_text().splitlines()[0])["recording"] == "a"


def test_extent_calibration_recovers_the_ratio_and_the_gap():
    """Extents at 0.91 of each true stature (within 1%) and a search 3% short: the ratio
    over the search's bodies is 0.91 / 0.97 and the sizes it gives land within 1% of the
    search's (the gap's percentiles too), the ratio over the true stature comes back with
    statures within 2%; recordings without enough extents are left out, and fewer than two
    give None."""
    rng = np.random.default_rng(1)
    stature = 1.75
    needed = rng.uniform(0.85, 1.15, 40)
    rows = [
        {"recording": str(k), "needed": n, "found": n * 0.97,
         "extents": list(0.91 * n * stature * (1 + rng.uniform(-0.01, 0.01, 5)))}
        for k, n in enumerate(needed)
    ]  # fmt: skip
    rows.append({"recording": "short", "needed": 1.0, "found": 1.0, "extents": [1.0, 1.0]})
    rows.append({"recording": "old", "needed": 1.0, "found": 1.0})  # measured before extents
    figures = fit.extent_figures(rows, stature, frames=5)
    assert figures["recordings"] == 40
    assert figures["ratio"] == pytest.approx(0.91 / 0.97, rel=0.005)
    assert figures["disagreement"]["p99"] < 0.01 and figures["size_gap_cross_validated"] < 0.01
    assert figures["stature_ratio"] == pytest.approx(0.91, rel=0.005)
    assert figures["stature_errors_cross_validated"]["max_abs_cm"] < 0.02 * 100 * stature
    # A search 3% short in one recording only: the gap's maximum shows it.
    rows[0] = {**rows[0], "found": rows[0]["found"] * 0.97}
    assert fit.extent_figures(rows, stature, frames=5)["disagreement"]["max"] == pytest.approx(
        0.03, abs=0.012
    )
    assert fit.extent_figures(rows[-3:], stature, frames=5) is None
