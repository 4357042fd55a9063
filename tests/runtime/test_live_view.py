"""``runtime-track --view``: the optional rerun live view."""

from __future__ import annotations

import sys

import pytest
from depthmocap.runtime.track_cli import main


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


def test_inferred_joints_are_logged_grey(monkeypatch):
    """With a stand-in for rerun: observed joints take the status colour, inferred ones grey."""
    import types

    import numpy as np
    from depthmocap.runtime.estimator import PoseEstimate
    from depthmocap.runtime.frame import Frame
    from depthmocap.runtime.live_view import LiveView
    from depthmocap.runtime.streams.base import DepthFrame
    from depthmocap.shared.camera import Intrinsics

    logged = {}
    fake = types.SimpleNamespace(
        init=lambda *a, **k: None,
        save=lambda *a, **k: None,
        log=lambda path, item, **k: logged.__setitem__(path, item),
        set_time=lambda *a, **k: None,
        ViewCoordinates=types.SimpleNamespace(RIGHT_HAND_Y_DOWN=None),
        Points3D=lambda points, colors=None, radii=None: (np.asarray(points), colors),
        LineStrips3D=lambda strips, colors=None, radii=None: strips,
        TextLog=lambda text: text,
        Clear=lambda recursive: None,
    )
    monkeypatch.setitem(sys.modules, "rerun", fake)
    view = LiveView("unused.rrd")
    depth = np.full((120, 160), 2000, np.uint16)
    observed = np.ones(16, bool)
    observed[9] = False  # r_wrist
    est = PoseEstimate(None, np.zeros((16, 3)), "tracked", observed=observed)
    raw = DepthFrame(0, 0.0, depth, Intrinsics.kinect_v1(160))
    view.log_frame(Frame.from_depth(raw, depth > 0), est)
    _, colours = logged["world/joints"]
    assert tuple(colours[9]) == (128, 128, 128) and tuple(colours[0]) == (60, 220, 60)
    assert logged["status"] == "tracked"
