"""Reading a depth stream apart from estimation: the camera is never blocked, the newest frame
wins.

A live camera delivers 30 frames/s whether or not the estimator keeps up. Reading on the
estimator's thread would let the driver's queue fill and the poses fall further and further
behind the person. :class:`LatestFrameReader` reads on its own thread into a one-frame
mailbox; a frame the estimator has not taken when the next one arrives is replaced and counted
as skipped, so the estimator always works on the newest frame and latency stays bounded.

A file source can be paced to its frame rate (``runtime-track --realtime``): the reader thread
then plays it back like a camera would deliver it.

The reader thread can also prepare each frame (``prepare``: the person mask, the forest's
labels), so that work overlaps the estimator's on the previous frame: the tracker's small
torch ops leave the second core mostly idle (issue 38).

A file read as fast as possible keeps every frame (``skip=False``): the reader then prepares
one frame ahead and waits for the consumer to take it, so a recording is processed as a
two-stage pipeline (mask and labels beside the previous frame's estimate) with nothing lost.
It reads the next frame only once the consumer has taken the one prepared: reading on into a
second frame while the first waited took the second core from the estimator's slowest
frames (a detection's split refits; the first frame's detection beside two preparations),
the 95th-percentile frame x0.92-0.97 and the first frame 47 -> 40 ms on the broad protocol
(thirty-fifth session, ``docs/experiments.md``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from .base import DepthFrame, DepthStream

__all__ = ["LatestFrameReader", "timed_frames"]


def timed_frames(stream: DepthStream) -> Iterator[tuple[DepthFrame, float]]:
    """Every frame of ``stream`` in order, with the ``time.perf_counter()`` it was read at."""
    for frame in stream:
        yield frame, time.perf_counter()


class LatestFrameReader:
    """Reads ``stream`` on a daemon thread; iterating yields ``(frame, arrival)`` pairs, each
    the newest frame read since the previous pair (``arrival``: its ``time.perf_counter()``).

    Args:
        stream: the source; its iteration runs on the reader thread.
        pace: deliver a file source at its frame rate, as a camera would (its first frame at
            once, frame ``k`` at ``time_k - time_0`` seconds after it).
        prepare: run on the reader thread on every frame read; iterating then yields
            ``(prepare(frame), arrival)`` (``arrival``: when the frame was read, before its
            preparation). Its errors reach the consumer like the stream's.
        skip: the newest frame wins (a camera). False: every frame is delivered in order;
            the reader reads a frame once the one before has been taken, so it holds at most
            one frame, finished or in preparation, beside the consumer's.
    Attributes:
        skipped: frames replaced by a newer one before the consumer took them (0 with
            ``skip=False``).
    Errors the stream raises on the reader thread (a disconnected camera, a corrupt file) are
    raised by the consumer's iteration after the frames read before them.
    """

    def __init__(
        self,
        stream: DepthStream,
        pace: bool = False,
        prepare: Callable[[DepthFrame], Any] | None = None,
        skip: bool = True,
    ) -> None:
        self.stream, self.pace, self.prepare, self.skip = stream, pace, prepare, skip
        self.skipped = 0
        self._slot: tuple[Any, float] | None = None
        self._ended = False
        self._error: BaseException | None = None
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None

    def _read(self) -> None:
        start: tuple[float, float] | None = None
        try:
            for frame in self._frames():
                if self._stop.is_set():
                    break
                if self.pace:
                    if start is None:
                        start = (frame.time, time.perf_counter())
                    due = start[1] + (frame.time - start[0]) - time.perf_counter()
                    if due > 0 and self._stop.wait(due):
                        break
                arrival = time.perf_counter()
                item = frame if self.prepare is None else self.prepare(frame)
                with self._cond:
                    if self._stop.is_set():
                        break
                    if self._slot is not None:
                        self.skipped += 1
                    self._slot = (item, arrival)
                    self._cond.notify()
        except BaseException as err:  # handed to the consumer, which reports it
            self._error = err
        finally:
            with self._cond:
                self._ended = True
                self._cond.notify()

    def _frames(self) -> Iterator[DepthFrame]:
        """The stream's frames; keeping every frame, each read only once the slot is empty
        (the consumer has taken the frame before)."""
        frames = iter(self.stream)
        while True:
            if not self.skip:
                with self._cond:
                    while self._slot is not None and not self._stop.is_set():
                        self._cond.wait(0.1)
                if self._stop.is_set():
                    return
            frame = next(frames, None)
            if frame is None:
                return
            yield frame

    def __iter__(self) -> Iterator[tuple[Any, float]]:
        if self._thread is None:
            self._thread = threading.Thread(target=self._read, name="depth-reader", daemon=True)
            self._thread.start()
        while True:
            with self._cond:
                # A timeout, so that a signal handler on this thread gets to run promptly.
                while self._slot is None and not self._ended:
                    self._cond.wait(0.1)
                item, self._slot = self._slot, None
                ended, error = self._ended, self._error
                self._cond.notify()  # a reader keeping every frame waits for the slot
            if item is not None:
                yield item
            elif ended:
                if error is not None:
                    raise error
                return

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop reading (after the frame being read) and wait for the reader thread."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout_s)
