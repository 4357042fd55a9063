"""Detections started ahead on a worker thread: the same poses and random draws as inline."""

from __future__ import annotations

import dataclasses
import math
import threading

import numpy as np
import pytest
import torch
from depthmocap.runtime.detector import Detector, DetectorConfig
from depthmocap.runtime.estimator import estimate_frame
from depthmocap.runtime.frame import Frame
from depthmocap.runtime.hybrid import FailureThresholds, HybridConfig, HybridEstimator
from depthmocap.runtime.hybrid.detect_ahead import DetectionAhead, DetectionDropped
from depthmocap.runtime.raycast import part_labels, render_body
from depthmocap.runtime.streams.base import DepthFrame
from depthmocap.runtime.tracker import Tracker, TrackerConfig
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import rest_pose

INTR = Intrinsics.kinect_v1(160)
BODY = BodyShape.default()


def _detector() -> Detector:
    return Detector(BODY, INTR, DetectorConfig(refine_iterations=2))


def _draws(detector: Detector, checkpoint) -> torch.Tensor:
    """A stand-in detection: three random draws from the detector's generator."""
    checkpoint()
    return torch.rand(3, generator=detector.generator)


def test_a_taken_detection_hands_over_its_random_state():
    inline, live = _detector(), _detector()
    expected = [_draws(inline, lambda: None) for _ in range(2)]
    ahead = DetectionAhead()
    for index, want in enumerate(expected):
        ahead.start(index, live, _draws)
        assert ahead.pending == index
        assert torch.equal(ahead.take(index, live), want)
    # The live generator now stands where two inline detections leave it.
    assert torch.equal(live.generator.get_state(), inline.generator.get_state())
    assert ahead.pending is None and ahead.take(2, live) is None


def test_a_detection_not_taken_leaves_the_random_state_alone():
    live, before = _detector(), _detector().generator.get_state()
    ahead = DetectionAhead()
    ahead.start(5, live, _draws)
    assert ahead.take(6, live) is None  # another frame's: dropped, not waited for
    ahead.start(7, live, _draws)
    ahead.drop()
    assert ahead.pending is None
    assert torch.equal(live.generator.get_state(), before)


def test_a_dropped_detection_stops_at_its_checkpoint():
    started, release, reached = threading.Event(), threading.Event(), []

    def slow(detector, checkpoint):
        started.set()
        release.wait(5)
        reached.append("before")
        checkpoint()  # dropped by now: raises
        reached.append("after")

    ahead = DetectionAhead()
    ahead.start(0, _detector(), slow)
    started.wait(5)
    future = ahead._pending.future
    ahead.drop()
    release.set()
    with pytest.raises(DetectionDropped):
        future.result(5)
    assert reached == ["before"]


def test_take_reraises_what_the_detection_raised():
    def broken(detector, checkpoint):
        raise ValueError("bad frame")

    ahead = DetectionAhead()
    ahead.start(0, _detector(), broken)
    with pytest.raises(ValueError, match="bad frame"):
        ahead.take(0, _detector())


class FailingOn(Tracker):
    """A real tracker whose own fits of the listed frames report a failing depth error (its
    refits, the detector's refinement and the arm search's, are left as they are)."""

    def __init__(self, fail_frames: set[int]) -> None:
        super().__init__(BODY, INTR, TrackerConfig(use_labels=True))
        self.fail_frames, self.frame = fail_frames, 0

    def fit(self, obs, q_prev, q_prev2=None, iterations=None):
        res = super().fit(obs, q_prev, q_prev2, iterations)
        if iterations is None and self.frame in self.fail_frames:
            res = dataclasses.replace(res, depth_error_cm=9.0)
        return res


def _frames(count: int) -> list[Frame]:
    """A person lowering the left arm, one frame rendered per pose (with its part labels)."""
    out = []
    for i in range(count):
        q = rest_pose(1, (0.0, 0.1, 2.5))[0]
        q[sk.DOF_NAMES.index("l_humerus_abd")] = math.radians(50 - 4 * i)
        r = render_body(q[None], BODY, INTR)
        depth_mm = (r.depth[0].numpy() * 1000).round().astype(np.uint16)
        frame = Frame.from_depth(DepthFrame(i, i / 30, depth_mm, INTR), r.mask[0])
        frame.part_labels = part_labels(r, BODY)[0]
        out.append(frame)
    return out


def _run(frames: list[Frame], ahead: bool, fail_frames: set[int]):
    tracker = FailingOn(fail_frames)
    cfg = HybridConfig(
        failure=FailureThresholds(epsilon1_cm=3.0, epsilon2=0.0),
        keep_better=None, arm_search=None, body_scale=None, joint_offsets=None,
        detect_ahead=ahead,
    )  # fmt: skip
    est = HybridEstimator(lambda f: f.part_labels * f.mask, _detector(), tracker, cfg)
    taken = []
    if est._ahead is not None:
        take = est._ahead.take

        def counted(index, detector):
            got = take(index, detector)
            taken.append(index) if got is not None else None
            return got

        est._ahead.take = counted
    results = []
    for frame in frames:
        tracker.frame = frame.index
        results.append(estimate_frame(est, frame))
    return results, est.detector.generator.get_state(), taken


def test_detections_ahead_give_the_inline_poses():
    """Frames 2-4 and 6 fail: 3 and 4 take the detection started ahead, 5 and 7 drop theirs,
    6 detects inline; poses, statuses and the RANSAC's random state match the inline run."""
    frames, fail = _frames(8), {2, 3, 4, 6}
    inline, inline_state, _ = _run(frames, False, fail)
    ahead, ahead_state, taken = _run(frames, True, fail)
    d, t = "detected", "tracked"
    assert [e.status for e in inline] == [d, t, d, d, d, t, d, t]
    assert taken == [3, 4]
    assert [e.status for e in ahead] == [e.status for e in inline]
    for a, b in zip(ahead, inline, strict=True):
        np.testing.assert_array_equal(a.q, b.q)
        np.testing.assert_array_equal(a.joints, b.joints)
    assert torch.equal(ahead_state, inline_state)
