"""Depth streams: recordings, image folders, OpenNI2 (through its Dummy device), dispatch."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from depthmocap.runtime.streams import (
    DepthFrame,
    FrameRange,
    SensorDisconnected,
    StreamError,
    open_stream,
)
from depthmocap.runtime.streams.image_folder import ImageFolderStream
from depthmocap.runtime.streams.recording import RecordingStream
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.recording import RecordingError, RecordingWriter, write_png16

REPO = Path(__file__).resolve().parents[3]
INTR = Intrinsics.kinect_v1(640).resized(32, 24)


def frames(n: int, intr: Intrinsics = INTR) -> list[np.ndarray]:
    """Distinct uint16 frames: frame i is filled with 1000 + i mm."""
    return [np.full((intr.height, intr.width), 1000 + i, np.uint16) for i in range(n)]


@pytest.fixture
def recording(tmp_path) -> Path:
    path = tmp_path / "rec"
    with RecordingWriter(path, INTR, fps=15.0, source="test") as w:
        for f in frames(5):
            w.write_frame(f)
    return path


# ---- frame ranges ----------------------------------------------------------------------------


def test_frame_range_checks_and_clipping():
    assert list(FrameRange(1, 3).clip(5)) == [1, 2]
    assert list(FrameRange(2).clip(5)) == [2, 3, 4]
    assert list(FrameRange(0, 99).clip(5)) == [0, 1, 2, 3, 4]
    with pytest.raises(StreamError, match="start must be"):
        FrameRange(-1)
    with pytest.raises(StreamError, match="empty"):
        FrameRange(3, 3)
    with pytest.raises(StreamError, match="has 5 frames"):
        FrameRange(5).clip(5)


# ---- recordings ------------------------------------------------------------------------------


def test_recording_stream_reads_frames_with_their_own_indices(recording):
    with open_stream(str(recording), frame_range=FrameRange(1, 4)) as s:
        assert isinstance(s, RecordingStream)
        assert s.intrinsics == INTR and s.fps == 15.0 and s.frame_count == 3
        got = list(s)
    assert [f.index for f in got] == [1, 2, 3]
    assert [f.time for f in got] == pytest.approx([1 / 15, 2 / 15, 3 / 15])
    assert all(isinstance(f, DepthFrame) and f.depth_mm.dtype == np.uint16 for f in got)
    assert [int(f.depth_mm[0, 0]) for f in got] == [1001, 1002, 1003]
    assert s.source.startswith("recording:")


def test_recording_intrinsics_override(recording):
    other = Intrinsics(32, 24, 30.0, 30.0, 16.0, 12.0)
    assert RecordingStream(recording, other).intrinsics == other
    with pytest.raises(StreamError, match="32x24 but the given intrinsics are for 64x48"):
        RecordingStream(recording, INTR.resized(64, 48))


def test_unreadable_recording(recording):
    meta = json.loads((recording / "meta.json").read_text())
    (recording / "meta.json").write_text(json.dumps({**meta, "version": 99}))
    with pytest.raises(RecordingError, match="version 99"):
        open_stream(str(recording))
    (recording / "meta.json").write_text("{not json")
    with pytest.raises(RecordingError, match="not valid JSON"):
        open_stream(str(recording))


def test_recording_with_a_corrupt_frame_fails_on_that_frame(recording):
    (recording / "depth" / "000002.png").write_bytes(b"garbage")
    stream = open_stream(str(recording))
    it = iter(stream)
    next(it), next(it)
    with pytest.raises(RecordingError, match="000002.png"):
        next(it)


# ---- image folders ---------------------------------------------------------------------------


def test_png_folder_natural_order_and_default_intrinsics(tmp_path):
    for i, f in zip([1, 2, 10], frames(3)):
        write_png16(tmp_path / f"f{i}.png", f)
    s = open_stream(str(tmp_path), fps=10.0)
    assert isinstance(s, ImageFolderStream)
    assert s.intrinsics == Intrinsics.kinect_v1(640).resized(32, 24)
    got = list(s)
    assert [int(f.depth_mm[0, 0]) for f in got] == [1000, 1001, 1002]  # f2 before f10
    assert [f.time for f in got] == pytest.approx([0.0, 0.1, 0.2])


def test_png_folder_size_contradicting_intrinsics(tmp_path):
    write_png16(tmp_path / "0.png", frames(1)[0])
    with pytest.raises(StreamError, match="frame is 32x24 but the intrinsics are for 64x48"):
        open_stream(str(tmp_path), intrinsics=INTR.resized(64, 48))


def test_png_folder_later_frame_of_other_size(tmp_path):
    write_png16(tmp_path / "0.png", frames(1)[0])
    write_png16(tmp_path / "1.png", frames(1, INTR.resized(64, 48))[0])
    it = iter(open_stream(str(tmp_path)))
    next(it)
    with pytest.raises(StreamError, match="1.png: frame is 64x48"):
        next(it)


def test_png_folder_rejects_8bit_mixed_and_empty(tmp_path):
    (tmp_path / "a").mkdir()
    write_png16(tmp_path / "a" / "0.png", np.zeros((24, 32), np.uint8))
    with pytest.raises(StreamError, match="16-bit PNG"):
        open_stream(str(tmp_path / "a"))
    (tmp_path / "b").mkdir()
    write_png16(tmp_path / "b" / "0.png", frames(1)[0])
    frames(1)[0].tofile(tmp_path / "b" / "1.raw")
    with pytest.raises(StreamError, match="both PNG and raw"):
        open_stream(str(tmp_path / "b"))
    (tmp_path / "c").mkdir()
    with pytest.raises(StreamError, match="no depth frames found"):
        open_stream(str(tmp_path / "c"))


def test_raw_folder_with_given_intrinsics(tmp_path):
    for i, f in enumerate(frames(3)):
        f.astype("<u2").tofile(tmp_path / f"{i:03d}.raw")
    s = open_stream(str(tmp_path), intrinsics=INTR, frame_range=FrameRange(1))
    assert [int(f.depth_mm[5, 5]) for f in s] == [1001, 1002]
    with pytest.raises(StreamError, match="bytes do not make a 64x48"):
        open_stream(str(tmp_path), intrinsics=INTR.resized(64, 48))


def test_raw_folder_size_guess(tmp_path):
    f = np.arange(640 * 480, dtype=np.uint16).reshape(480, 640)
    f.astype("<u2").tofile(tmp_path / "depth-data-1.u16")
    s = open_stream(str(tmp_path))
    assert s.intrinsics == Intrinsics.kinect_v1(640)
    assert np.array_equal(next(iter(s)).depth_mm, f)
    (tmp_path / "depth-data-2.u16").write_bytes(b"\0" * 1000)  # fits no frame
    with pytest.raises(StreamError, match="depth-data-2.u16: 1000 bytes"):
        list(open_stream(str(tmp_path)))
    odd = tmp_path / "odd"
    odd.mkdir()
    (odd / "x.raw").write_bytes(b"\0" * 1002)
    with pytest.raises(StreamError, match="give --width and --height"):
        open_stream(str(odd))


# ---- dispatch --------------------------------------------------------------------------------


def test_missing_source_and_invalid_intrinsics(tmp_path):
    with pytest.raises(StreamError, match="no such file or directory"):
        open_stream(str(tmp_path / "nope"))
    with pytest.raises(StreamError, match="no such .oni file"):
        open_stream(str(tmp_path / "nope.oni"))
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(StreamError, match="not a depth source"):
        open_stream(str(tmp_path / "file.txt"))
    with pytest.raises(StreamError, match="invalid intrinsics"):
        open_stream("demo", intrinsics=Intrinsics(32, 24, -1.0, 1.0, 0.0, 0.0))


def test_demo_dispatch():
    with open_stream("demo", frame_range=FrameRange(0, 2)) as s:
        got = list(s)
    assert len(got) == 2 and got[0].depth_mm.dtype == np.uint16
    assert got[0].depth_mm.shape == (s.intrinsics.height, s.intrinsics.width)


def test_demo_depth_has_the_kinect_sensor_model():
    """The demo's depth goes through shared.sensor_noise: readings on disparity steps, within the
    sensor's range, the floor below the person, missing readings where a clean render would have
    floor or body, and the same frames on every run."""
    from depthmocap.runtime.streams.demo import DemoStream
    from depthmocap.shared.sensor_noise import KinectNoiseConfig, quantize_depth

    first = list(DemoStream(frame_range=FrameRange(0, 2)))
    again = list(DemoStream(frame_range=FrameRange(0, 2)))
    assert all(np.array_equal(a.depth_mm, b.depth_mm) for a, b in zip(first, again))
    depth = first[0].depth_mm
    z = depth[depth > 0] / 1000.0
    # A reading re-quantized stays put (up to the millimetre rounding of the output).
    assert np.abs(quantize_depth(z) - z).max() <= 0.6e-3
    cfg = KinectNoiseConfig()
    assert cfg.min_depth_m <= z.min() and z.max() <= cfg.max_depth_m
    h, w = depth.shape
    # The person stands 2.6 m away in the image centre; the nearest floor fills the bottom row.
    centre = depth[h // 2 - 5 : h // 2 + 5, w // 2 - 3 : w // 2 + 3] / 1000.0
    assert np.all(np.abs(centre - 2.5) < 0.2)
    assert (depth[-1] > 0).mean() > 0.9
    # Below row 200 every clean pixel is floor or body within range: zeros there are the sensor
    # model's shadows, holes and ragged edges (the old noise-only model had none).
    assert (depth[200:] == 0).sum() > 0


def test_demo_missing_is_a_clean_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "depthmocap.runtime.streams.demo", None)  # import fails
    with pytest.raises(StreamError, match="demo sequence is not available"):
        open_stream("demo")


# ---- OpenNI2 ---------------------------------------------------------------------------------


def _openni_or_skip():
    pytest.importorskip("openni", reason="the 'openni' package is not installed")
    from depthmocap.runtime.streams.openni import load_openni2

    try:
        return load_openni2()
    except StreamError as err:
        pytest.skip(str(err))


def test_openni_no_camera_is_a_clean_error():
    openni2 = _openni_or_skip()
    if openni2.Device.enumerate_uris():
        pytest.skip("a real camera is attached")
    with pytest.raises(StreamError, match="no depth camera found via OpenNI2"):
        open_stream("device")
    with pytest.raises(StreamError, match="cannot open 'device-that-is-not-there'"):
        open_stream("device:device-that-is-not-there")


def run_python(code: str, timeout: float = 60) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter from the repo root (OpenNI2 drivers run threads
    and own process-wide state; a subprocess keeps them out of the test process)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_openni_dummy_device_streams_frames():
    _openni_or_skip()
    r = run_python(
        """
        from depthmocap.runtime.streams import open_stream, FrameRange
        with open_stream("device:Dummy", frame_range=FrameRange(1, 4)) as s:
            print(s.is_live, s.frame_count, s.fps, s.intrinsics.width, s.intrinsics.height)
            for f in s:
                print(f.index, f.depth_mm.dtype, f.depth_mm.shape, int(f.depth_mm.max()), f.time)
        print("done")
        """
    )
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "True None 30.0 320 240"
    rows = [ln.split() for ln in lines[1:-1]]
    assert [int(x[0]) for x in rows] == [1, 2, 3]
    assert all(x[1] == "uint16" and x[2:4] == ["(240,", "320)"] for x in rows)
    times = [float(x[-1]) for x in rows]
    # Seconds since the first frame the camera delivered (frame 0, skipped by the range).
    assert times == pytest.approx([1 / 30, 2 / 30, 3 / 30], abs=2e-3)
    assert lines[-1] == "done"


def test_openni_read_failure_is_a_disconnect():
    _openni_or_skip()
    r = run_python(
        """
        from depthmocap.runtime.streams import open_stream, SensorDisconnected
        s = open_stream("device:Dummy")
        it = iter(s)
        next(it)
        def broken():
            raise RuntimeError("USB gone")
        s._stream.read_frame = broken
        try:
            next(it)
        except SensorDisconnected as err:
            print("disconnected:", err)
        s.close()
        s.close()
        """
    )
    assert r.returncode == 0, r.stderr
    assert "disconnected: openni:Dummy: frame read failed" in r.stdout


def test_sensor_disconnected_is_not_a_stream_error():
    # The tool treats them differently: bad input (exit 2) vs frames so far are good (exit 1).
    assert not issubclass(SensorDisconnected, ValueError)
    assert issubclass(StreamError, ValueError)
