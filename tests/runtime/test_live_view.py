"""``runtime-track --view``: the optional rerun live view."""

from __future__ import annotations

import sys

import pytest

from runtime.track_cli import main


def test_view_without_rerun_is_a_clear_error(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # makes `import rerun` fail
    code = main(["--input", "demo", "--mode", "tracker", "--output", str(tmp_path / "o"),
                 "--stop", "2", "--view", "-q"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "rerun-sdk" in err and "Traceback" not in err


def test_view_saves_a_recording(tmp_path):
    pytest.importorskip("rerun")
    rrd = tmp_path / "live.rrd"
    code = main(["--input", "demo", "--mode", "tracker", "--output", str(tmp_path / "o"),
                 "--stop", "3", "--view", str(rrd), "-q"])  # fmt: skip
    assert code == 0 and rrd.is_file() and rrd.stat().st_size > 1000
