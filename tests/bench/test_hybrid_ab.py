"""Hybrid settings timed against each other, alternated per recording (bench.hybrid_ab)."""

from __future__ import annotations

import numpy as np
import pytest
from depthmocap.bench.hybrid_ab import ab_rows, benchmark_settings, main, parse_setting


@pytest.fixture
def recordings(two_demo_recordings):
    return two_demo_recordings


def test_settings_alternate_per_recording_and_are_compared_to_the_first(recordings, one_thread):
    recs = sorted(p for p in recordings.iterdir())
    off = {"detector": {"reset_limbs": "none"}}
    results = benchmark_settings(recs, {"shipped": None, "no_resets": off})
    assert list(results) == ["shipped", "no_resets"]
    np.testing.assert_array_equal(results["shipped"]["order"], [0, 1])
    np.testing.assert_array_equal(results["no_resets"]["order"], [1, 0])
    for r in results.values():
        assert len(r["ms"]) == 4 and (r["ms"] > 0).all() and len(r["work"]) == 4
        assert r["statuses"][0] == "detected"  # each recording starts with a detection
    rows = ab_rows(results)
    names = [r[0] for r in rows]
    assert names[0] == "[shipped]" and "[no_resets]" in names
    ratio = next(r for r in rows if r[0] == "95th percentile against shipped")
    assert ratio[2].endswith("of it") and ratio[1] > 0
    assert sum(n.startswith("median frame") for n in names) == 2


def test_the_command_line(recordings, tmp_path, capsys, one_thread):
    off = tmp_path / "off.yaml"
    off.write_text("detector:\n  reset_limbs: none\n")
    args = ["--recordings", str(recordings), "--every", "2"]
    assert main([*args, "--setting", "shipped=", "--setting", f"off={off}"]) == 0
    out = capsys.readouterr().out
    assert "== 1 recordings" in out and "mean against shipped" in out
    two = ["--setting", "a=", "--setting", "b="]
    for bad in (
        ["--setting", "shipped="],
        ["--setting", "x=missing.yaml", "--setting", "y="],
        ["--every", "0", *two],
    ):
        with pytest.raises(SystemExit):
            main([*args, *bad])
    assert parse_setting("a=") == ("a", None)
    with pytest.raises(ValueError, match="NAME=FILE"):
        parse_setting("nofile")
