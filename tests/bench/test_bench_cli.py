"""``make bench`` (bench.cli): argument errors are reported before anything is timed."""

from __future__ import annotations

import pytest
from depthmocap.bench.cli import main


def test_bench_refuses_a_missing_recordings_folder(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--recordings", str(tmp_path / "nowhere")])
    assert exit_info.value.code == 2
    assert "no such folder" in capsys.readouterr().err


def test_bench_refuses_cuda_without_a_gpu(monkeypatch, capsys):
    """``--device cuda`` without a GPU is an error, not an empty report; ``make bench``
    passes ``--device all``, which times CUDA only where torch sees it."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(SystemExit) as exit_info:
        main(["--device", "cuda"])
    assert exit_info.value.code == 2
    assert "no CUDA device" in capsys.readouterr().err
