"""A batched refit's starts split over two threads on the CPU.

The hybrid's recoveries refit one frame from K starts in one batched fit
(:meth:`runtime.tracker.tracker.Tracker.fit_starts`). The arm search's (8 arm poses of 5
iterations) is the slowest frames' work, and while it runs the stream's reader thread has long
finished preparing the next frame, so the second core idles. A fit's starts do not interact
(each is fitted as it would be alone), and its time is spent in compiled loops that release
the interpreter's lock, so half the starts of a large enough batch go to a helper thread: the
same results, in the same order.

Idle host, one torch thread, 8 starts of 5 iterations on a broad recording's frame: 54 -> 38
ms (kick 023 b0), 39 -> 29 (squat 037 b0), 46 -> 33 (throw 010 b0); ``docs/experiments.md``,
twenty-second session, for the whole hybrid.
"""

from __future__ import annotations

import weakref
from concurrent.futures import ThreadPoolExecutor

import torch
from depthmocap.runtime.tracker.observation import Observation
from depthmocap.runtime.tracker.tracker import Tracker, TrackResult

__all__ = ["MIN_SPLIT_STARTS", "SplitRefits"]

# Fewer starts than this are fitted in one piece: a fit's fixed cost (its observed candidates
# and final signals, ~5 ms) is paid by each half, and the helper takes the reader thread's
# core. The detector refinement's 4 limb swaps of 3 iterations came out slower split (the
# frames that ran the detector: median 42.8 -> 46.2 ms); the arm search's 8 starts of 5
# iterations faster (59.2 -> 50.8 ms).
MIN_SPLIT_STARTS = 6


def _fit_half(
    tracker: Tracker,
    obs: Observation,
    starts: torch.Tensor,
    iterations: int | None,
    inference: bool,
) -> list[TrackResult]:
    """``tracker.fit_starts`` on a helper thread, in the caller's inference mode (it is
    per thread)."""
    with torch.inference_mode(inference):
        return tracker.fit_starts(obs, starts, iterations)


class SplitRefits:
    """Batched refits with half their starts on one helper thread (module docstring).

    Args:
        enabled: False fits every batch on the calling thread (the same results).
    """

    def __init__(self, enabled: bool = True) -> None:
        self._pool: ThreadPoolExecutor | None = None
        if enabled:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="refit")
            # The helper goes with its owner: a benchmark makes an estimator per recording.
            weakref.finalize(self, self._pool.shutdown, wait=False)

    def fit_starts(
        self,
        tracker: Tracker,
        obs: Observation,
        starts: torch.Tensor,
        iterations: int | None = None,
    ) -> list[TrackResult]:
        """``tracker.fit_starts(obs, starts, iterations)``: the (K, 34) ``starts`` split in two
        on the CPU when K >= :data:`MIN_SPLIT_STARTS` (a GPU fits a batch at once)."""
        K = starts.shape[0]
        if self._pool is None or K < MIN_SPLIT_STARTS or starts.device.type != "cpu":
            return tracker.fit_starts(obs, starts, iterations)
        half = K // 2
        rest = self._pool.submit(
            _fit_half, tracker, obs, starts[half:], iterations, torch.is_inference_mode_enabled()
        )
        try:
            first = tracker.fit_starts(obs, starts[:half], iterations)
        except BaseException:
            rest.exception()  # the helper is done with the frame before the error goes up
            raise
        return first + rest.result()
