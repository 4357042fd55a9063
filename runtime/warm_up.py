"""Warm a process up before a live stream starts, so that its first frames are not dropped.

A fresh process pays about 1.8 s on its first frame and 60-130 ms on each of the next few
(numba's cached kernels loaded and type-checked, torch's first calls, the forest's tables
brought into memory): measured on this project's 2-core host, against 15 ms for a plain
tracked frame once warm. A live camera, and ``runtime-track --realtime`` on a file, keep
only the newest frame, so every frame that arrives meanwhile is dropped: some 55 frames at 30
frames/s, most of a short take, and the first pose is of a stale frame. Since the compiled
code and caches are the process's, not the estimator's, a throwaway estimator built the
same way and run over a few frames of the built-in demo (rendered at the stream's own
resolution) leaves them warm for the real one, which then starts from a clean state.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from depthmocap.shared.camera import Intrinsics

from .estimator import PoseEstimator, estimate_frame, prepare_frame

__all__ = ["WARM_UP_FRAMES", "try_warm_up", "warm_up"]

# The demo's first frames: a detection, then tracked frames, the first of which takes a size
# sample (the batched refits) when no body is given: each kind of work a stream starts with.
WARM_UP_FRAMES = 4


def warm_up(
    make_estimator: Callable[[], PoseEstimator],
    intrinsics: Intrinsics,
    segment: Callable,
    device: str = "cpu",
    frames: int = WARM_UP_FRAMES,
) -> float:
    """Run a throwaway estimator from ``make_estimator`` over the first ``frames`` frames of the
    built-in demo at ``intrinsics``, each prepared with ``segment`` (a person segmenter) as a
    stream's would be; returns the seconds it took. Nothing of it is kept but the process's
    warm caches."""
    from .streams import FrameRange
    from .streams.demo import DemoStream

    start = time.perf_counter()
    estimator = make_estimator()
    with DemoStream(intrinsics, frame_range=FrameRange(0, frames)) as demo:
        for frame in demo:
            estimate_frame(estimator, prepare_frame(estimator, frame, segment, device))
    close = getattr(estimator, "close", None)
    if callable(close):
        close()
    return time.perf_counter() - start


def try_warm_up(
    make_estimator: Callable[[], PoseEstimator],
    intrinsics: Intrinsics,
    segment: Callable,
    device: str = "cpu",
) -> tuple[float | None, str | None]:
    """:func:`warm_up`, which is an optimization only: ``(seconds, None)``, or ``(None, the
    error)`` when it failed, so that a capture never fails because of it (the stream's own
    first frames then warm the process up, and some are dropped)."""
    try:
        return warm_up(make_estimator, intrinsics, segment, device), None
    except Exception as err:
        return None, str(err)
