"""``runtime-track --mode tracker``: the tracker alone, started from the input's ground truth."""

from __future__ import annotations

import numpy as np
from depthmocap.runtime.streams.demo import open_demo_stream
from depthmocap.runtime.track_cli import main
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.poses_format import poses_to_arrays, read_poses_jsonl
from depthmocap.shared.recording import RecordingWriter


def test_tracker_mode_follows_the_demo(tmp_path, capsys):
    out = tmp_path / "res"
    # The demo person is the built-in body; without a file the tracker would fit the
    # population's average adult, another body.
    body = tmp_path / "body.json"
    BodyShape.default().save(body)
    assert main(["--input", "demo", "--mode", "tracker", "--output", str(out), "--stop", "6",
                 "--device", "cpu", "--body", str(body), "-q"]) == 0  # fmt: skip
    arrays = poses_to_arrays(read_poses_jsonl(out / "poses.jsonl").records)
    assert list(arrays["status"]) == ["tracked"] * 6
    gt = open_demo_stream().groundtruth["joints"][:6]
    err = np.linalg.norm(arrays["joints"] - gt, axis=-1)
    assert np.nanmean(err) < 0.03, err.mean(1)
    # The demo faces the camera: the tracker calls (almost) every joint observed.
    assert np.isfinite(arrays["observed"]).all() and arrays["observed"].mean() > 0.9


def test_tracker_mode_needs_ground_truth(tmp_path, capsys):
    rec = tmp_path / "rec"
    with RecordingWriter(rec, Intrinsics.kinect_v1(320)) as w:
        w.write_frame(np.zeros((240, 320), np.uint16))
    code = main(["--input", str(rec), "--mode", "tracker", "--output", str(tmp_path / "o"), "-q"])
    assert code == 2
    err = capsys.readouterr().err
    assert "ground truth" in err and "Traceback" not in err
