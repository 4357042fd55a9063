"""The whole-hybrid timing of ``runtime-bench`` (the GPU command of issue 38), run on the CPU."""

from __future__ import annotations

import numpy as np
import pytest
from depthmocap.bench.cli import main
from depthmocap.bench.hybrid import benchmark_hybrid, hybrid_rows


def test_benchmark_hybrid_times_every_frame(one_thread):
    r = benchmark_hybrid("demo", "cpu", frames=3, warmup=1)
    assert r["ms"].shape == (3,) and np.all(r["ms"] > 0) and r["device"] == "cpu"
    assert set(r["statuses"]) <= {"tracked", "detected", "lost"}
    assert r["work"].shape == (3,) and r["work"][0].startswith(("detector", "size search"))


def test_frames_are_classed_by_what_they_ran():
    from depthmocap.bench.hybrid import frame_work, work_rows

    assert frame_work("tracked", {"depth_error_cm": 1.0}, False) == "track only"
    assert frame_work("detected", {}, False) == "detector"
    assert frame_work("tracked", {"depth_error_cm": 3.1, "rechecked": 1.0}, False) == "detector"
    assert frame_work("tracked", {"kept_over_detector": 1.0}, False) == "detector"
    # A doubted frame revised by the look-back carries the refit's errors and the flag.
    assert frame_work("detected", {"overlap": 0.9, "looked_back": 1.0}, False) == "detector"
    assert frame_work("lost", {"tracker_overlap": 0.1, "labelled_pixels": 0.0}, False) == "detector"
    assert frame_work("lost", {"labelled_pixels": 3.0}, False) == "detector"  # found nobody
    assert frame_work("lost", {}, False) == "no person"  # nobody in the frame: nothing ran
    assert frame_work("tracked", {"arms_searched": 1.0}, True) == "size search + arm search"
    ms = np.array([10.0, 20.0, 100.0, 60.0])
    work = np.array(["track only", "track only", "detector", "arm search"])
    rows = work_rows(ms, work)
    assert [r[0].strip() for r in rows] == ["detector", "arm search", "track only"]
    assert rows[2][1] == 15.0 and "50.0% of frames, 16% of the time, 0 over 50 ms" in rows[2][2]
    assert "1 over 50 ms" in rows[0][2]


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


def test_paced_latency_replays_a_camera_where_the_newest_frame_wins():
    from depthmocap.bench.hybrid import paced_latency

    # Every frame faster than the camera: each waits for nothing, none skipped.
    assert paced_latency(np.full(5, 10.0), fps=30.0) == (10.0, 0.0)
    # 50 ms frames, a camera frame every 33.3 ms: frame 0 is done at 50 ms, frame 1 (arrived
    # at 33.3) at 100, when frame 3 arrives: frame 2 is skipped; frame 3 is done at 150,
    # frame 4 (133.3) at 200, frame 5 (166.7) at 250.
    latency, skipped = paced_latency(np.full(6, 50.0), fps=30.0)
    period = 1000.0 / 30.0
    done_at = {0: 50.0, 1: 100.0, 3: 150.0, 4: 200.0, 5: 250.0}
    expected = np.mean([t - i * period for i, t in done_at.items()])
    assert latency == pytest.approx(expected) and skipped == pytest.approx(1 / 6)
    assert np.isnan(paced_latency(np.zeros(0))[0])


def test_recordings_rows_time_every_recording(tmp_path, one_thread, write_demo_recordings):
    """The whole hybrid on a folder of recordings: pooled rows, then one per recording; a
    folder that is itself a recording counts as one."""
    from depthmocap.bench.hybrid import recordings_in, recordings_rows

    write_demo_recordings(tmp_path, ("b", "a"))
    (tmp_path / "notes").mkdir()
    assert [p.name for p in recordings_in(tmp_path)] == ["a", "b"]
    assert recordings_in(tmp_path / "a") == [tmp_path / "a"]
    rows = recordings_rows(tmp_path, "cpu")
    assert rows[0][0] == "median frame (2 recordings, 4 frames)"
    assert [r[0].strip() for r in rows[-2:]] == ["a", "b"]
    assert any(r[0].strip() == "detector" for r in rows)  # the first frames are detected
    assert all(r[1] > 0 for r in rows)
    assert recordings_rows(tmp_path / "notes", "cpu") == []
    assert not any("first second" in r[0] for r in rows)  # 2-frame recordings: no such frames
    later = recordings_rows(tmp_path, "cpu", startup=1)
    names = [r[0] for r in later]
    assert "95th-percentile frame after the first second" in names


def test_after_startup_rows_pool_the_later_frames():
    from depthmocap.bench.hybrid import after_startup_rows

    runs = [np.array([90.0, 10.0, 20.0]), np.array([80.0, 30.0]), np.array([70.0])]
    (median, p95) = after_startup_rows(runs, 1)
    assert median[1] == 20.0 and p95[1] == pytest.approx(np.percentile([10, 20, 30], 95))
    assert "3 frames after each recording's first 1" in median[2]
    assert after_startup_rows(runs, 3) == [] and after_startup_rows([], 1) == []
