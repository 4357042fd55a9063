"""The warm-up before a live stream: a throwaway estimator over the demo's first frames at the
stream's resolution, and the hybrid's close() that it relies on."""

from __future__ import annotations

import numpy as np
from depthmocap.runtime.estimator import lost
from depthmocap.runtime.segmentation import PersonSegmenter, SegmentationConfig
from depthmocap.runtime.warm_up import WARM_UP_FRAMES, try_warm_up, warm_up
from depthmocap.shared.camera import Intrinsics


class CountingEstimator:
    """Records what the warm-up asks of it."""

    def __init__(self) -> None:
        self.shapes: list[tuple[int, int]] = []
        self.closed = False

    def reset(self) -> None:
        pass

    def estimate(self, frame):
        self.shapes.append(tuple(frame.depth_m.shape[-2:]))
        return lost()

    def close(self) -> None:
        self.closed = True


def test_warm_up_runs_a_throwaway_estimator_over_the_demo_at_the_stream_s_size():
    made: list[CountingEstimator] = []

    def make() -> CountingEstimator:
        made.append(CountingEstimator())
        return made[-1]

    intr = Intrinsics.kinect_v1(160)
    seconds = warm_up(make, intr, PersonSegmenter(SegmentationConfig()))
    assert len(made) == 1 and seconds > 0
    est = made[0]
    assert est.shapes == [(intr.height, intr.width)] * WARM_UP_FRAMES  # a person in every one
    assert est.closed  # its threads are released before the stream starts


def test_a_failed_warm_up_is_reported_not_raised():
    """The warm-up is an optimization: its failure is returned, never the capture's end."""

    def broken():
        raise RuntimeError("no forest here")

    intr = Intrinsics.kinect_v1(160)
    seconds, error = try_warm_up(broken, intr, PersonSegmenter(SegmentationConfig()))
    assert seconds is None and error == "no forest here"
    seconds, error = try_warm_up(CountingEstimator, intr, PersonSegmenter(SegmentationConfig()))
    assert error is None and seconds > 0


def test_the_hybrid_s_close_waits_for_the_size_search_then_goes_on_inline(one_thread):
    from depthmocap.runtime.estimator import estimate_frame, make_estimator, prepare_frame
    from depthmocap.runtime.estimator_setup import load_body
    from depthmocap.runtime.forest.inference import DEFAULT_MODEL
    from depthmocap.runtime.streams import open_stream

    segment = PersonSegmenter(SegmentationConfig())
    with open_stream("demo") as stream:
        est = make_estimator("hybrid", DEFAULT_MODEL, load_body(None), stream.intrinsics)
        frames = iter(stream)
        for _ in range(2):  # detected, then tracked: the first size sample goes to the worker
            estimate_frame(est, prepare_frame(est, next(frames), segment))
        pending = est.scale_search._pending
        assert est._worker is not None and pending is not None
        est.close()
        assert est._worker is None and pending.done()
        est.close()  # twice is harmless
        statuses = [
            estimate_frame(est, prepare_frame(est, next(frames), segment)).status for _ in range(3)
        ]
    assert est.scale_search.samples == 2  # the next sample (tracked frame 4) refitted inline
    assert np.isin(statuses, ["tracked", "detected"]).all()
