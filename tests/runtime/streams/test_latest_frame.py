"""LatestFrameReader: reading apart from estimation, the newest frame wins, errors reach the
consumer, paced playback never delivers a frame early."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from depthmocap.runtime.streams import DepthFrame, DepthStream, SensorDisconnected
from depthmocap.runtime.streams.latest_frame import LatestFrameReader, timed_frames
from depthmocap.shared.camera import Intrinsics

INTR = Intrinsics.kinect_v1(160)


class CountingStream(DepthStream):
    """``n`` blank frames at ``fps``; optionally a pause before each frame (a camera's rate)
    and an error after the last."""

    def __init__(self, n: int, fps: float = 30.0, period_s: float = 0.0, fail=None):
        self.n, self._fps, self.period_s, self.fail = n, fps, period_s, fail
        self.source = "test:counting"
        self.reader_threads: set[str] = set()

    @property
    def intrinsics(self):
        return INTR

    @property
    def fps(self):
        return self._fps

    @property
    def frame_count(self):
        return self.n

    def __iter__(self):
        for i in range(self.n):
            self.reader_threads.add(threading.current_thread().name)
            time.sleep(self.period_s)
            yield DepthFrame(i, i / self._fps, np.zeros((INTR.height, INTR.width), np.uint16), INTR)
        if self.fail is not None:
            raise self.fail


def test_a_slow_consumer_gets_the_newest_frames_and_the_last():
    stream = CountingStream(40, period_s=0.002)
    reader = LatestFrameReader(stream)
    got = []
    for frame, arrival in reader:
        got.append(frame.index)
        assert arrival <= time.perf_counter()
        time.sleep(0.01)  # five frames arrive while one is processed
    assert got == sorted(set(got)) and got[-1] == 39
    assert reader.skipped == 40 - len(got) and reader.skipped > 0
    assert stream.reader_threads == {"depth-reader"}  # the stream never runs on the consumer


def test_a_fast_consumer_skips_nothing_when_paced():
    stream = CountingStream(12, fps=50.0)
    reader = LatestFrameReader(stream, pace=True)
    got = [(f.index, f.time, arrival) for f, arrival in reader]
    assert [i for i, _, _ in got] == list(range(12)) and reader.skipped == 0
    # Pacing never delivers a frame before its time relative to the first.
    t0, a0 = got[0][1], got[0][2]
    assert all(a - a0 >= (t - t0) - 1e-3 for _, t, a in got)


def test_stream_errors_reach_the_consumer_after_the_frames_before_them():
    reader = LatestFrameReader(CountingStream(3, fail=SensorDisconnected("cable pulled")))
    got = []
    with pytest.raises(SensorDisconnected, match="cable pulled"):
        for frame, _ in reader:
            got.append(frame.index)
    assert got[-1] == 2


def test_close_stops_the_reader_thread():
    reader = LatestFrameReader(CountingStream(10_000, period_s=0.001))
    frames = iter(reader)
    next(frames)
    reader.close()
    assert not reader._thread.is_alive()


def test_timed_frames_are_every_frame_in_order():
    got = [(f.index, a) for f, a in timed_frames(CountingStream(5))]
    assert [i for i, _ in got] == list(range(5))
    assert all(a1 <= a2 for (_, a1), (_, a2) in zip(got, got[1:]))


def test_frames_are_prepared_on_the_reader_thread():
    """``prepare`` runs on the reader thread, on every frame read (skipped ones too); the
    consumer gets its results with the frame's arrival before the preparation."""
    prepared_on, read_at = [], {}

    def prepare(frame):
        prepared_on.append(threading.current_thread().name)
        read_at[frame.index] = time.perf_counter()
        time.sleep(0.002)  # the mask and the forest take a while
        return ("prepared", frame.index)

    reader = LatestFrameReader(CountingStream(8, fps=50.0), pace=True, prepare=prepare)
    got = [(item, arrival) for item, arrival in reader]
    assert [item for item, _ in got] == [("prepared", i) for i in range(8)]
    assert set(prepared_on) == {"depth-reader"} and len(prepared_on) == 8
    assert all(arrival <= read_at[index] for (_, index), arrival in got)


def test_preparation_errors_reach_the_consumer():
    def prepare(frame):
        if frame.index == 2:
            raise ValueError("frame 2 is corrupt")
        return frame.index

    got = []
    with pytest.raises(ValueError, match="corrupt"):
        for index, _ in LatestFrameReader(CountingStream(5), prepare=prepare):
            got.append(index)
            time.sleep(0.005)
    assert got and got[-1] < 2


def test_keeping_every_frame_delivers_all_in_order_and_reads_one_ahead():
    """``skip=False`` (a file read as fast as possible): a slow consumer still gets every
    frame in order, and the reader reads a frame only once the consumer has taken the one
    before: beside the consumer's frame it holds one, prepared or being prepared, never two."""
    slot_empty_at_read = []

    class Watched(CountingStream):
        def __iter__(self):
            for frame in super().__iter__():
                with reader._cond:
                    slot_empty_at_read.append(reader._slot is None)
                yield frame

    reader = LatestFrameReader(Watched(15), prepare=lambda f: f.index, skip=False)
    got = []
    for index, _ in reader:
        got.append(index)
        time.sleep(0.003)  # the reader would have read on into the next frame by now
    assert got == list(range(15)) and reader.skipped == 0
    assert len(slot_empty_at_read) == 15 and all(slot_empty_at_read)


def test_close_stops_a_reader_waiting_for_the_consumer():
    reader = LatestFrameReader(CountingStream(100), skip=False)
    frames = iter(reader)
    next(frames)
    time.sleep(0.05)  # the reader fills the slot and waits
    reader.close()
    assert not reader._thread.is_alive()
