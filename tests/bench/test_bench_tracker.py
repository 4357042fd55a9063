"""The tracker benchmarks (bench.tracker, bench.tracker_terms): a recording with ground truth
is timed and one without is refused; the term costs are ratios against a step."""

from __future__ import annotations

import numpy as np
import pytest
from depthmocap.bench.scenes import camera_motion
from depthmocap.bench.tracker import benchmark_recording, benchmark_tracker, recording_rows
from depthmocap.bench.tracker_terms import collision_cost, joint_support_cost
from depthmocap.runtime.raycast import render_body
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
from depthmocap.shared.recording import RecordingError, RecordingWriter

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


def test_tracker_is_timed_on_the_cylinder_walk():
    r = benchmark_tracker(frames=3)
    assert r["ms_per_frame"] > 0 and r["frames_per_s"] == pytest.approx(1e3 / r["ms_per_frame"])
    assert r["raycast_ms"] > 0 and 1 <= r["iterations_mean"] <= 5
    assert r["joint_error_mm"] < 30 and r["working_pixels"] > 500


def test_tracker_is_timed_on_a_recording(tmp_path):
    rec = _recording(tmp_path / "walk")
    r = benchmark_recording(rec, frames=3)
    assert r["frames"] == 3 and r["ms_per_frame"] > 0
    assert 1 <= r["iterations_mean"] <= 5 and r["working_pixels"] > 500
    rows = recording_rows(tmp_path, "cpu")
    assert len(rows) == 1 and rows[0][0].endswith("walk") and "frames/s" in rows[0][2]


def test_a_recording_without_ground_truth_is_refused(tmp_path):
    rec = _recording(tmp_path / "bare", truth=False)
    with pytest.raises(RecordingError, match="groundtruth"):
        benchmark_recording(rec, frames=2)
    assert recording_rows(tmp_path, "cpu") == []  # skipped by the folder scan


def test_collision_cost_is_a_ratio_against_the_step_without_it():
    what, ms, note = collision_cost("cpu", rounds=1, frames=3)
    assert "collision" in what and ms > 0
    ratio = float(note.split(" of the step")[0])
    assert 0.2 < ratio < 5.0 and "alternated" in note


def test_joint_support_cost_is_a_ratio_against_a_tracker_step():
    what, ms, note = joint_support_cost("cpu", repeats=2)
    assert "observed-joint" in what and ms > 0
    ratio = float(note.split(" of a tracker step")[0])
    assert 0.0 < ratio < 1.0  # the step computes the flags once, among much else
