"""Where each kind of frame's time goes (bench.frame_phases): a diagnostic, checked for shape."""

from __future__ import annotations

import numpy as np
import pytest
from depthmocap.bench import frame_phases
from depthmocap.bench.frame_phases import PHASES, main, phase_rows, phase_timer, run_phases
from depthmocap.runtime.hybrid.estimator import HybridEstimator


@pytest.fixture
def recordings(two_demo_recordings):
    return two_demo_recordings


def test_phases_of_every_timed_frame(recordings, one_thread):
    recs = sorted(recordings.iterdir())
    r = run_phases(recs)
    ms, work, phases = r["ms"], r["work"], r["phases"]
    assert len(ms) == len(work) == phases.shape[0] == 4
    assert phases.shape[1] == len(PHASES) + 1
    names = [p[0] for p in PHASES]
    estimate = phases[:, -1]
    assert (estimate > 0).all() and (estimate <= ms + 1.0).all()  # a frame includes its estimate
    assert (phases[:, :-1] <= estimate[:, None] + 1e-6).all()  # each phase within its estimate
    detected = work != "track only"
    assert detected[0] and detected[2]  # each recording starts with a detection
    assert (phases[[0, 2], names.index("detector")] > 0).all()
    assert (phases[[0, 2], names.index("refits")] > 0).all()  # inside the detector
    lines = phase_rows(ms, work, phases)
    assert lines[0].startswith("kind of frame") and len(lines) >= 2


def test_the_originals_are_put_back():
    before = HybridEstimator.__dict__["estimate"], HybridEstimator.__dict__["_fit"]
    with pytest.raises(KeyError), phase_timer() as records:
        assert HybridEstimator.__dict__["_fit"] is not before[1]
        raise KeyError("interrupted")
    assert records == []
    assert (HybridEstimator.__dict__["estimate"], HybridEstimator.__dict__["_fit"]) == before


def test_the_command_line(recordings, capsys, one_thread):
    assert main(["--recordings", str(recordings), "--every", "2"]) == 0
    out = capsys.readouterr().out
    assert "1 recordings, 2 frames" in out and "detector" in out
    with pytest.raises(SystemExit):
        main(["--recordings", str(recordings / "missing")])
    assert frame_phases.__doc__.startswith("``python -m depthmocap.bench.frame_phases``")


def test_rows_list_slow_frames_apart():
    ms = np.array([10.0, 60.0, 70.0])
    work = np.array(["track only", "detector", "detector"])
    phases = np.zeros((3, len(PHASES) + 1))
    phases[:, -1] = ms - 1
    lines = phase_rows(ms, work, phases)
    assert lines[1].startswith("detector") and lines[2].lstrip().startswith("over 50 ms")
    assert lines[3].startswith("track only") and len(lines) == 4
