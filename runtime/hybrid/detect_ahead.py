"""A frame's detection started on a worker thread beside its own tracker fit.

Why: about a fifth of the broad protocol's frames run the detector (~30 ms: RANSAC, IK, the
refinement of four limb swaps) after their own fit and arm search (~18 ms), and those frames
are most of the ones over the 50 ms that issue 38 allows a frame. A detection needs only the
frame, the last pose (its IK hint), the body and the RANSAC's random state, all known before
the fit. Three times in four a frame after one that ran the detector runs it too, so the
hybrid starts such a frame's detection on a worker thread first (the other core, which the
stream's reader leaves idle two thirds of the time) and takes it when the fit asks for it.

Nothing changes but the time: the worker detects with a copy of the detector whose random
generator starts from the live one's state. A detection taken hands its generator's end state
to the live detector, as if it had run inline; one not taken is dropped and leaves the live
state as it was. A dropped detection stops at its next checkpoint (before its refinement),
so it seldom costs more than its RANSAC.
"""

from __future__ import annotations

import copy
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import torch
from depthmocap.runtime.detector import DetectionResult, Detector

__all__ = ["DetectionAhead", "DetectionDropped", "detector_copy"]

# ``run(detector, checkpoint)``: the frame's detection with ``detector``, calling
# ``checkpoint()`` before each costly stage (it raises DetectionDropped once dropped).
DetectionJob = Callable[[Detector, Callable[[], None]], DetectionResult]


class DetectionDropped(Exception):
    """Raised inside a dropped detection at its next checkpoint: nobody wants its result."""


def detector_copy(detector: Detector) -> Detector:
    """``detector`` with a random generator of its own, started at the live one's state (the
    settings, body and intrinsics are shared: nothing writes them)."""
    twin = copy.copy(detector)
    twin.generator = torch.Generator(device=detector.generator.device)
    twin.generator.set_state(detector.generator.get_state())
    return twin


@dataclass
class _Pending:
    index: int
    detector: Detector
    future: Future
    dropped: threading.Event


class DetectionAhead:
    """At most one detection ahead of the frame being estimated, on one worker thread
    (created on first use)."""

    def __init__(self) -> None:
        self._pool: ThreadPoolExecutor | None = None
        self._pending: _Pending | None = None

    def start(self, index: int, detector: Detector, run: DetectionJob) -> None:
        """Detect frame ``index`` with a :func:`detector_copy` of ``detector`` on the worker
        (any detection still pending is dropped first)."""
        self.drop()
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="detect-ahead")
        twin, dropped = detector_copy(detector), threading.Event()

        def checkpoint() -> None:
            if dropped.is_set():
                raise DetectionDropped

        def job() -> DetectionResult:
            checkpoint()
            return run(twin, checkpoint)

        self._pending = _Pending(index, twin, self._pool.submit(job), dropped)

    def take(self, index: int, detector: Detector) -> DetectionResult | None:
        """The detection of frame ``index`` if one was started (waiting for it), its random
        generator's end state now ``detector``'s; None if none was (any other is dropped).
        Re-raises what the detection raised."""
        pending, self._pending = self._pending, None
        if pending is None:
            return None
        if pending.index != index:
            self._drop(pending)
            return None
        result = pending.future.result()
        detector.generator.set_state(pending.detector.generator.get_state())
        return result

    def drop(self) -> None:
        """Forget the pending detection, if any; it stops at its next checkpoint."""
        pending, self._pending = self._pending, None
        if pending is not None:
            self._drop(pending)

    @staticmethod
    def _drop(pending: _Pending) -> None:
        pending.dropped.set()
        pending.future.cancel()

    @property
    def pending(self) -> int | None:
        """The frame index of the detection pending, or None."""
        return None if self._pending is None else self._pending.index
