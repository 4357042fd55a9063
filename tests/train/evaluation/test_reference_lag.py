"""The reference-lag measurement on a tiny synthetic recording written here: a bar moving
8 px a frame with a skeleton inside it that runs a known number of frames ahead of the depth;
the parabola vertex against golden values; the command and its errors."""

from __future__ import annotations

import numpy as np
import pytest
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.recording import RecordingWriter
from depthmocap.train.evaluation.reference_lag import lag_vertex, main, refuted_by_lag

INTR = Intrinsics(80, 60, 100.0, 100.0, 39.5, 29.5)
T, STEP_PX, Z = 8, 8, 2.0


def _bar_depth(t: int) -> np.ndarray:
    """(H, W) metres: a 6-px-wide bar at 2 m whose left edge is at 4 + 8 t."""
    depth = np.zeros((INTR.height, INTR.width), np.float32)
    left = 4 + STEP_PX * t
    depth[10:50, left : left + 6] = Z
    return depth


def _skeleton(t: int) -> np.ndarray:
    """(3, 3) camera-frame joints 5 cm behind the bar's surface down its middle at frame t."""
    u = 4 + STEP_PX * t + 2.5
    rows = np.array([15.0, 30.0, 45.0])
    z = Z + 0.05
    return np.stack([(u - INTR.cx) * z / INTR.fx + 0 * rows, (rows - INTR.cy) * z / INTR.fy,
                     np.full(3, z)], 1)  # fmt: skip


@pytest.mark.parametrize("true_lag", [0, 2])
def test_the_lag_the_skeleton_runs_ahead_is_found(true_lag):
    depth = [_bar_depth(t) for t in range(T)]
    # Skeleton k shows the bar as depth frame k + true_lag does.
    reference = np.stack([_skeleton(k + true_lag) for k in range(T)])
    lags = [-1, 0, 1, 2, 3]
    counts = refuted_by_lag(depth, reference, INTR, lags)
    assert counts[lags.index(true_lag)] == 0
    # A frame off is 8 px off a 6-px bar, beyond the 3-px slack: every joint refuted.
    others = [c for lag, c in zip(lags, counts) if lag != true_lag]
    assert min(others) > 0 and counts.argmin() == lags.index(true_lag)


def test_lag_vertex_golden():
    lags = [0, 1, 2, 3, 4]
    counts = 10 * (np.array(lags) - 1.3) ** 2 + 5
    assert lag_vertex(lags, counts) == pytest.approx(1.3)
    # The 192 shared UTD-MHAD takes, lags 0..3 (docs/real_data.md): 4283, 1783, 1370, 3495.
    assert lag_vertex([0, 1, 2, 3], [4283, 1783, 1370, 3495]) == pytest.approx(1.66, abs=0.01)
    assert lag_vertex(lags, [1, 2, 3, 4, 5]) == 0.0  # best at the end of the range
    assert lag_vertex(lags, [5, 0, 0, 0, 5]) == 2.0  # a flat minimum: its middle


def _write(path, true_lag: int) -> None:
    with RecordingWriter(path, INTR, 30.0, "test") as w:
        for t in range(T):
            w.write_frame(np.round(_bar_depth(t) * 1000).astype(np.uint16))
        names = ["a", "b", "c"]
        joints = np.stack([_skeleton(k + true_lag) for k in range(T)])
        w.write_reference(joints, names, "test", [(n, n) for n in names])


def test_command_prints_the_table_and_the_best_lag(tmp_path, capsys):
    _write(tmp_path / "a05_s1_t1", 2)
    _write(tmp_path / "a22_s1_t1", 2)
    assert main(["--data", str(tmp_path), "--lags", "0", "1", "2", "3"]) == 0
    out = capsys.readouterr().out
    assert "| a05 | " in out and "| a22 | " in out and "| all | " in out
    assert out.strip().endswith("best lag 2, vertex 2.00 frames")
    assert main(["--data", str(tmp_path), "--select", "a22*", "--lags", "1", "2", "3"]) == 0
    assert "| a05 |" not in capsys.readouterr().out


def test_command_errors(tmp_path, capsys):
    assert main(["--data", str(tmp_path / "none")]) == 2
    assert "no recording with a reference.npz" in capsys.readouterr().err
    _write(tmp_path / "a05_s1_t1", 0)
    assert main(["--data", str(tmp_path), "--lags", "0", "2"]) == 2
    assert "consecutive" in capsys.readouterr().err
    assert main(["--data", str(tmp_path), "--lags", *map(str, range(-5, 6))]) == 2
    assert "shorter than 11 frames" in capsys.readouterr().err
