"""``make bench`` helpers: the tracker timed on a recording with ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.bench import bench_recordings
from runtime.raycast import render_body
from runtime.tracker.benchmark import benchmark_recording, camera_motion
from shared import skeleton as sk
from shared.body import BodyShape
from shared.camera import Intrinsics
from shared.kinematics import forward_kinematics, named_joint_positions
from shared.recording import RecordingError, RecordingWriter

INTR = Intrinsics.kinect_v1(320)


pytestmark = pytest.mark.usefixtures("one_thread")


def _recording(path, frames=4, truth=True):
    body = BodyShape.default()
    q = camera_motion("walk", frames).float()
    depth = render_body(q, body, INTR).depth
    with RecordingWriter(path, INTR, source="synthetic:walk") as rec:
        for d in depth:
            rec.write_frame((d.numpy() * 1000).round().astype(np.uint16))
        if truth:
            joints = named_joint_positions(forward_kinematics(q, body)).numpy()
            rec.write_groundtruth(joints, sk.JOINT_NAMES, q=q.double().numpy())
    body.save(path / "body.json")
    return path


def test_tracker_is_timed_on_a_recording(tmp_path):
    rec = _recording(tmp_path / "walk")
    r = benchmark_recording(rec, frames=3)
    assert r["frames"] == 3 and r["ms_per_frame"] > 0
    assert 1 <= r["iterations_mean"] <= 5 and r["working_pixels"] > 500
    rows = bench_recordings(tmp_path, "cpu")
    assert len(rows) == 1 and rows[0][0].endswith("walk") and "frames/s" in rows[0][2]


def test_a_recording_without_ground_truth_is_refused(tmp_path):
    rec = _recording(tmp_path / "bare", truth=False)
    with pytest.raises(RecordingError, match="groundtruth"):
        benchmark_recording(rec, frames=2)
    assert bench_recordings(tmp_path, "cpu") == []  # skipped by the folder scan


def test_bench_refuses_a_missing_recordings_folder(tmp_path, capsys):
    from runtime.bench import main

    with pytest.raises(SystemExit) as exit_info:
        main(["--recordings", str(tmp_path / "nowhere")])
    assert exit_info.value.code == 2
    assert "no such folder" in capsys.readouterr().err


def test_collision_cost_is_a_ratio_against_the_step_without_it():
    from runtime.bench import collision_cost

    what, ms, note = collision_cost("cpu", rounds=1, frames=3)
    assert "collision" in what and ms > 0
    ratio = float(note.split(" of the step")[0])
    assert 0.2 < ratio < 5.0 and "alternated" in note


def test_joint_support_cost_is_a_ratio_against_a_tracker_step():
    from runtime.bench import joint_support_cost

    what, ms, note = joint_support_cost("cpu", repeats=2)
    assert "observed-joint" in what and ms > 0
    ratio = float(note.split(" of a tracker step")[0])
    assert 0.0 < ratio < 1.0  # the step computes the flags once, among much else
