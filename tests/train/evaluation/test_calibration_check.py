"""The calibration pose check on random bodies (train.evaluation.calibration_check), end to end
on two bodies at the ends of the range: rendered with anny, calibrated by runtime-calibrate."""

from __future__ import annotations

import json

from depthmocap.train.evaluation.calibration_check import check_phenotypes, main


def test_phenotypes_span_sex_height_and_weight():
    bodies = check_phenotypes(20, seed=0)
    assert len(bodies) == 20
    genders = [b["gender"] for b in bodies]
    assert sum(g > 0.5 for g in genders) == 10
    heights = sorted(b["height"] for b in bodies)
    weights = sorted(b["weight"] for b in bodies)
    assert heights[0] < 0.3 and heights[-1] > 0.45
    assert weights[0] < 0.25 and weights[-1] > 0.75
    assert check_phenotypes(20, seed=0) == bodies and check_phenotypes(20, seed=1) != bodies


def test_two_bodies_are_accepted_and_calibrated(tmp_path, capsys):
    # A short woman and a medium man (the first two bodies of seed 0), six frames each.
    code = main(["--bodies", "2", "--frames", "6", "--out", str(tmp_path)])
    rows = json.loads((tmp_path / "calibration_check.json").read_text())
    assert [r["accepted"] for r in rows] == [True, True], rows
    assert code == 0
    for r in rows:
        assert abs(r["stature_m"] - r["true_stature_m"]) < 0.1
        assert r["length_error_cm"] < 3.0
    assert "accepted 2 of 2 bodies" in capsys.readouterr().out


def test_bad_options_are_refused(tmp_path, capsys):
    import pytest

    for argv in (["--bodies", "0"], ["--frames", "0"], ["--max-yaw", "120"]):
        with pytest.raises(SystemExit) as err:
            main([*argv, "--out", str(tmp_path)])
        assert err.value.code == 2
    assert "--bodies and --frames" in capsys.readouterr().err
