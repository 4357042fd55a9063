"""The whole-hybrid timing of ``runtime-bench`` (the GPU command of issue 38), run on the CPU."""

from __future__ import annotations

import numpy as np
from depthmocap.bench.cli import main
from depthmocap.bench.hybrid import benchmark_hybrid, hybrid_rows


def test_benchmark_hybrid_times_every_frame(one_thread):
    r = benchmark_hybrid("demo", "cpu", frames=3, warmup=1)
    assert r["ms"].shape == (3,) and np.all(r["ms"] > 0) and r["device"] == "cpu"
    assert set(r["statuses"]) <= {"tracked", "detected", "lost"}


def test_rows_and_the_one_command(one_thread, capsys, monkeypatch):
    rows = hybrid_rows("demo", "cpu", frames=2)
    assert [r[0] for r in rows][0].startswith("median frame (2 frames)")
    # The command a GPU session runs, here on the CPU, with the other sections cut short.
    import depthmocap.bench.cli as cli

    monkeypatch.setattr(cli, "kinematics_rows", lambda batch, dev: [])
    monkeypatch.setattr(cli, "_print_segmentation", lambda: None)
    monkeypatch.setattr(cli, "_print_forest", lambda threads: None)
    monkeypatch.setattr(cli, "_print_tracker", lambda dev, name: None)
    main(["--device", "cpu", "--hybrid-frames", "2", "--threads", "1"])
    out = capsys.readouterr().out
    assert "the whole hybrid on CPU" in out and "95th-percentile frame" in out
