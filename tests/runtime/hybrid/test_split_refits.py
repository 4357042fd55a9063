"""Batched refits split over two threads: the same fits, in order, on the caller's terms."""

from __future__ import annotations

import threading

import pytest
import torch
from depthmocap.runtime.hybrid.split_refits import MIN_SPLIT_STARTS, SplitRefits
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker import Tracker, TrackerConfig
from depthmocap.runtime.tracker.observation import observe
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import rest_pose

INTR = Intrinsics.kinect_v1(320)


class RecordingTracker:
    """Stands in for a tracker: records each ``fit_starts`` call's thread, starts and mode,
    and returns one tag per start (its row's first value)."""

    def __init__(self, fail_on_caller: bool = False) -> None:
        self.calls: list[tuple[int, int, bool]] = []
        self.fail_on_caller = fail_on_caller
        self.caller = threading.get_ident()
        self.lock = threading.Lock()

    def fit_starts(self, obs, starts, iterations=None):
        with self.lock:
            self.calls.append(
                (threading.get_ident(), starts.shape[0], torch.is_inference_mode_enabled())
            )
        if self.fail_on_caller and threading.get_ident() == self.caller:
            raise RuntimeError("the caller's half failed")
        return [float(s[0]) for s in starts]


def test_the_same_fits_as_one_batch():
    """A real tracker on a rendered frame (float32, the CPU path): each start's fit is the
    same to the bit whichever thread fitted it, and the results keep the starts' order."""
    body = BodyShape.default(torch.float32)
    truth = rest_pose(1, root_position=(0.05, 0.1, 2.4), dtype=torch.float32)
    truth[0, 3:6] = torch.tensor([3.0, 0.2, -0.1])
    depth = render_body(truth, body, INTR).depth
    obs = observe(depth, depth > 0, INTR, 2, 12.0)
    tracker = Tracker(body, INTR, TrackerConfig(iterations=3))
    gen = torch.Generator().manual_seed(0)
    starts = truth + 0.08 * torch.randn(7, 34, generator=gen)
    want = tracker.fit_starts(obs, starts)
    with torch.inference_mode():
        got = SplitRefits().fit_starts(tracker, obs, starts)
    assert len(got) == len(want) == 7
    for g, w in zip(got, want, strict=True):
        assert torch.equal(g.q, w.q)
        assert (g.overlap, g.depth_error_cm, g.iterations) == (
            w.overlap,
            w.depth_error_cm,
            w.iterations,
        )


@pytest.mark.parametrize("inference", [True, False])
def test_half_on_a_helper_thread_in_the_callers_mode(inference):
    tracker = RecordingTracker()
    starts = torch.arange(9.0)[:, None].expand(9, 34)
    with torch.inference_mode(inference):
        tags = SplitRefits().fit_starts(tracker, None, starts)
    assert tags == list(range(9))  # in the starts' order
    (first, n1, mode1), (second, n2, mode2) = sorted(tracker.calls, key=lambda c: c[1])
    assert {n1, n2} == {4, 5} and (mode1, mode2) == (inference, inference)
    threads = {c[0] for c in tracker.calls}
    assert len(threads) == 2 and tracker.caller in threads


@pytest.mark.parametrize(
    "count, enabled, device",
    [(MIN_SPLIT_STARTS - 1, True, "cpu"), (8, False, "cpu"), (8, True, "meta")],
)
def test_small_batches_switched_off_and_other_devices_stay_whole(count, enabled, device):
    """Too few starts to pay two fits' fixed cost, the helper off, or starts not on the CPU
    (a GPU fits a batch at once): one call on the caller's thread."""
    tracker = RecordingTracker()
    tracker.fit_starts = lambda obs, starts, iterations=None: (
        tracker.calls.append((threading.get_ident(), starts.shape[0], False)) or []
    )
    SplitRefits(enabled).fit_starts(tracker, None, torch.zeros(count, 34, device=device))
    assert tracker.calls == [(tracker.caller, count, False)]


def test_an_error_goes_up_after_the_helper_is_done():
    tracker = RecordingTracker(fail_on_caller=True)
    with pytest.raises(RuntimeError, match="caller's half"):
        SplitRefits().fit_starts(tracker, None, torch.zeros(6, 34))
    assert len(tracker.calls) == 2  # the helper's half ran to its end first
