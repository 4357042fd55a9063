"""``make bench`` (bench.cli): argument errors are reported before anything is timed."""

from __future__ import annotations

import pytest
from depthmocap.bench.cli import main


def test_bench_refuses_a_missing_recordings_folder(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--recordings", str(tmp_path / "nowhere")])
    assert exit_info.value.code == 2
    assert "no such folder" in capsys.readouterr().err
