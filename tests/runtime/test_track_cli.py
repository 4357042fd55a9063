"""``runtime-track``: the pipeline with a fake estimator, every kind of bad input, interrupts
and dropped cameras (outputs stay valid up to the last frame), and no tracebacks."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from types import SimpleNamespace

import depthmocap.runtime.track_cli as cli
import numpy as np
import pytest
import torch
from depthmocap.runtime.estimator import (
    EstimatorUnavailable,
    PoseEstimate,
    PoseEstimator,
    make_estimator,
)
from depthmocap.runtime.frame import Frame, depth_mm_to_metres
from depthmocap.runtime.look_back import LookBackConfig
from depthmocap.runtime.streams import DepthFrame, DepthStream, SensorDisconnected, StreamError
from depthmocap.shared import forest_format as ff
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.recording import RecordingWriter, write_png16

REPO = Path(__file__).resolve().parents[2]
INTR = Intrinsics.kinect_v1(160)


def person_frame(intr: Intrinsics = INTR, z_mm: int = 2500) -> np.ndarray:
    """uint16 depth: a 0.5 m x 1.7 m slab at ``z_mm`` in front of nothing (0 = no reading)."""
    u, v = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    z = z_mm / 1000
    x, y = (u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z
    inside = (np.abs(x) < 0.25) & (y > -0.8) & (y < 0.9)
    return np.where(inside, z_mm, 0).astype(np.uint16)


class FakeEstimator:
    """Says "tracked" with a fixed pose; records what it was given."""

    def __init__(self, delay_s: float = 0.0):
        self.calls: list[int] = []
        self.resets = 0
        self.delay_s = delay_s

    def reset(self) -> None:
        self.resets += 1

    def estimate(self, frame: Frame) -> PoseEstimate:
        assert frame.mask.shape == frame.depth_m.shape and frame.has_person
        self.calls.append(frame.index)
        time.sleep(self.delay_s)
        q = np.zeros(34)
        q[2], q[3] = 2.5, np.pi
        joints = np.tile([0.0, 0.0, 2.5], (16, 1)) + np.linspace(-0.8, 0.8, 16)[:, None] * [0, 1, 0]
        return PoseEstimate(q, joints, "tracked", {"depth_m": 0.01})


class ListStream(DepthStream):
    """Frames from a list; raises ``fail`` (an exception instance) after them if given."""

    def __init__(self, depths, fail: BaseException | None = None, fps: float = 30.0):
        self.depths, self.fail, self._fps = depths, fail, fps
        self.closed = False
        self.source = "test:list"

    @property
    def intrinsics(self):
        return INTR

    @property
    def fps(self):
        return self._fps

    @property
    def frame_count(self):
        return len(self.depths)

    def __iter__(self):
        for i, d in enumerate(self.depths):
            yield DepthFrame(i, i / self._fps, d, INTR)
        if self.fail is not None:
            raise self.fail

    def close(self):
        self.closed = True


@pytest.fixture
def fake(monkeypatch) -> FakeEstimator:
    est = FakeEstimator()
    monkeypatch.setattr(cli, "make_estimator", lambda *a, **k: est)
    return est


@pytest.fixture
def recording(tmp_path) -> Path:
    path = tmp_path / "rec"
    with RecordingWriter(path, INTR, fps=30.0, source="test") as w:
        for i in range(5):
            w.write_frame(np.zeros_like(person_frame()) if i == 2 else person_frame())
    return path


def read_result(out: Path) -> tuple[list[dict], dict, int]:
    """(poses.jsonl records, summary.json, BVH frame count) after checking they agree."""
    lines = (out / "poses.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    summary = json.loads((out / "summary.json").read_text())
    bvh = (out / "motion.bvh").read_text().split("MOTION\n", 1)[1].splitlines()
    count = int(bvh[0].split(":")[1])
    assert bvh[1].startswith("Frame Time:")
    assert len(bvh) - 2 == count, "BVH frame count does not match its motion lines"
    assert summary["complete"] is True and summary["frames"] == len(records)
    return records, summary, count


def run(argv, capsys) -> tuple[int, str]:
    code = cli.main([str(a) for a in argv])
    return code, capsys.readouterr().err


def assert_one_line_error(err: str, *fragments: str) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for f in fragments:
        assert f in lines[0], (f, lines[0])


# ---- the pipeline ----------------------------------------------------------------------------


def test_recording_end_to_end(fake, recording, tmp_path, capsys):
    out = tmp_path / "out"
    code, err = run(["--input", recording, "--output", out, "--mode", "tracker"], capsys)
    assert code == 0, err
    records, summary, bvh_frames = read_result(out)
    assert [r["frame"] for r in records] == [0, 1, 2, 3, 4]
    assert [r["status"] for r in records] == ["tracked"] * 2 + ["lost"] + ["tracked"] * 2
    assert records[2]["q"] is None and records[0]["joints"]["head"] is not None
    assert fake.calls == [0, 1, 3, 4] and fake.resets == 1  # reset after the empty frame
    assert summary["status_counts"] == {"tracked": 4, "detected": 0, "lost": 1}
    assert summary["source"].startswith("recording:") and summary["mode"] == "tracker"
    assert bvh_frames == 5
    assert "5 frames" in err and str(out) in err


def test_frame_range_overlays_and_intrinsics_override(fake, tmp_path, capsys):
    folder = tmp_path / "pngs"
    folder.mkdir()
    for i in range(4):
        write_png16(folder / f"{i}.png", person_frame())
    out = tmp_path / "out"
    argv = ["-i", folder, "-o", out, "--mode", "tracker", "--start", 1, "--stop", 3]
    argv += ["--width", 160, "--height", 120, "--fx", 140, "--save-overlays", "--quiet"]
    code, err = run(argv, capsys)
    assert code == 0 and err == ""
    records, summary, _ = read_result(out)
    assert [r["frame"] for r in records] == [1, 2]
    assert summary["intrinsics"]["fx"] == 140 and summary["intrinsics"]["fy"] == 140
    overlays = sorted(p.name for p in (out / "overlays").iterdir())
    assert overlays == ["000001.png", "000002.png"]


def test_zero_and_nan_frames_are_lost_and_tracking_goes_on(fake, monkeypatch, tmp_path, capsys):
    nan = np.full(person_frame().shape, np.nan, dtype=np.float32)  # a misbehaving source
    depths = [person_frame(), np.zeros_like(person_frame()), nan, person_frame()]
    monkeypatch.setattr(cli, "open_stream", lambda *a, **k: ListStream(depths))
    out = tmp_path / "out"
    code, err = run(["-i", "x", "-o", out, "--mode", "tracker"], capsys)
    assert code == 0, err
    records, _, bvh_frames = read_result(out)
    assert [r["status"] for r in records] == ["tracked", "lost", "lost", "tracked"]
    assert fake.calls == [0, 3] and bvh_frames == 4


@pytest.mark.parametrize(
    "fail, code, message",
    [
        (KeyboardInterrupt(), 0, "interrupted; results up to frame 2"),
        (SensorDisconnected("cable pulled"), 1, "camera disconnected: cable pulled"),
        (StreamError("frame 3 unreadable"), 2, "error: frame 3 unreadable"),
    ],
    ids=["ctrl-c", "disconnect", "bad-frame"],
)
def test_stream_ending_badly_leaves_valid_outputs(
    fake, monkeypatch, tmp_path, capsys, fail, code, message
):
    stream = ListStream([person_frame()] * 3, fail=fail)
    monkeypatch.setattr(cli, "open_stream", lambda *a, **k: stream)
    out = tmp_path / "out"
    got, err = run(["-i", "x", "-o", out, "--mode", "tracker"], capsys)
    assert got == code
    assert message in err and "Traceback" not in err
    records, summary, bvh_frames = read_result(out)
    assert [r["frame"] for r in records] == [0, 1, 2] and bvh_frames == 3
    assert summary["extra"]["stopped"] is not None
    assert stream.closed


def test_track_function_directly():
    """track() with a plain writer double: the loop's contract without files."""

    class Writer:
        def __init__(self):
            self.rows = []

        def write_frame(self, index, time, status, joints, q, errors, observed=None):
            self.rows.append((index, status))

    w, est = Writer(), FakeEstimator()
    stats = cli.track(ListStream([person_frame(), np.zeros_like(person_frame())]), est, w)
    assert w.rows == [(0, "tracked"), (1, "lost")]
    assert stats.frames == 2 and stats.status_counts["lost"] == 1 and stats.last_index == 1


def test_depth_to_metres_handles_nan_and_uint16():
    m = depth_mm_to_metres(np.array([[1500, 0]], np.uint16))
    assert m.dtype == torch.float32
    np.testing.assert_allclose(m.numpy(), [[1.5, 0.0]])
    m = depth_mm_to_metres(np.array([[np.nan, 2000.0, -5.0, np.inf]], np.float32))
    np.testing.assert_allclose(m.numpy(), [[0.0, 2.0, 0.0, 0.0]])


# ---- bad input -------------------------------------------------------------------------------


def test_missing_model(recording, tmp_path, capsys):
    code, err = run(
        ["-i", recording, "-o", tmp_path / "o", "--model", tmp_path / "none.npz"], capsys
    )
    assert code == 2
    assert_one_line_error(err, "model file not found", "none.npz")
    assert not (tmp_path / "o").exists()


def test_corrupt_and_version_mismatched_model(recording, tmp_path, capsys):
    bad = tmp_path / "corrupt.npz"
    bad.write_bytes(b"PK\x03\x04" + os.urandom(200))
    code, err = run(["-i", recording, "-o", tmp_path / "o", "--model", bad], capsys)
    assert code == 2
    assert_one_line_error(err, "corrupt.npz")
    newer = tmp_path / "newer.npz"
    meta = json.dumps({"format": ff.FOREST_FORMAT, "version": ff.FOREST_VERSION + 1})
    np.savez(newer, meta=np.array(meta), checksum=np.array(ff.forest_checksum({}, meta)))
    code, err = run(["-i", recording, "-o", tmp_path / "o", "--model", newer], capsys)
    assert code == 2
    assert_one_line_error(err, "version")


def test_unreadable_recording(fake, recording, tmp_path, capsys):
    (recording / "meta.json").write_text('{"format": "depthmocap-recording"}')
    code, err = run(["-i", recording, "-o", tmp_path / "o", "--mode", "tracker"], capsys)
    assert code == 2
    assert_one_line_error(err, "meta.json", "missing key")


def test_frame_size_contradicting_intrinsics(fake, tmp_path, capsys):
    folder = tmp_path / "raw"
    folder.mkdir()
    person_frame().tofile(folder / "0.raw")
    argv = [
        "-i",
        folder,
        "-o",
        tmp_path / "o",
        "--mode",
        "tracker",
        "--width",
        320,
        "--height",
        240,
    ]
    code, err = run(argv, capsys)
    assert code == 2
    assert_one_line_error(err, "0.raw", "do not make a 320x240")


def test_no_camera_attached(fake, tmp_path, capsys):
    pytest.importorskip("openni", reason="the 'openni' package is not installed")
    from depthmocap.runtime.streams.openni import load_openni2

    try:
        openni2 = load_openni2()
    except StreamError as err:
        pytest.skip(str(err))
    if openni2.Device.enumerate_uris():
        pytest.skip("a real camera is attached")
    code, err = run(["-i", "device", "-o", tmp_path / "o", "--mode", "tracker"], capsys)
    assert code == 2
    assert_one_line_error(err, "no depth camera found")


@pytest.mark.parametrize(
    "argv, fragments",
    [
        (["--body", "nope.json"], ["body file not found"]),
        (["--fx", "100"], ["need --width and --height"]),
        (["--start", "5", "--stop", "2"], ["frame range is empty"]),
        (["--min-depth-m", "0.5", "--segmentation-config", "nope.yaml"], ["config file not found"]),
    ],
    ids=["body", "intrinsics", "range", "seg-config"],
)
def test_bad_options(fake, recording, tmp_path, capsys, argv, fragments):
    code, err = run(["-i", recording, "-o", tmp_path / "o", "--mode", "tracker", *argv], capsys)
    assert code == 2
    assert_one_line_error(err, *fragments)


def test_output_directory_with_unrelated_files(fake, recording, tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "precious.txt").write_text("keep")
    code, err = run(["-i", recording, "-o", out, "--mode", "tracker"], capsys)
    assert code == 2
    assert_one_line_error(err, "not empty")


def test_body_file_is_used(fake, recording, tmp_path, capsys):
    body = BodyShape.default().scaled(1.1)
    body.save(tmp_path / "body.json")
    out = tmp_path / "o"
    code, _ = run(
        ["-i", recording, "-o", out, "--mode", "tracker", "--body", tmp_path / "body.json"], capsys
    )
    assert code == 0
    saved = BodyShape.load(out / "body.json")
    assert torch.allclose(saved.lengths, body.lengths)


# ---- estimator registry ----------------------------------------------------------------------


def test_registry_unknown_missing_and_factory(monkeypatch):
    import types

    import depthmocap.runtime.estimator as reg

    args = (None, BodyShape.default(), INTR)
    with pytest.raises(EstimatorUnavailable, match="unknown mode"):
        make_estimator("magic", *args)
    monkeypatch.setitem(reg.MODE_MODULES, "hybrid", "depthmocap.runtime.no_such_module")
    with pytest.raises(EstimatorUnavailable, match="not available in this build"):
        make_estimator("hybrid", *args)
    monkeypatch.setitem(
        reg.MODE_MODULES, "hybrid", "depthmocap.runtime.raycast"
    )  # no create_estimator
    with pytest.raises(EstimatorUnavailable, match="has no create_estimator"):
        make_estimator("hybrid", *args)
    module = types.ModuleType("fake_mode")
    module.create_estimator = lambda **kw: (FakeEstimator(), kw)
    monkeypatch.setitem(sys.modules, "fake_mode", module)
    monkeypatch.setitem(reg.MODE_MODULES, "hybrid", "fake_mode")
    est, kw = make_estimator("hybrid", "m.npz", *args[1:], device="cpu")
    assert isinstance(est, PoseEstimator)
    assert kw["model_path"] == Path("m.npz") and kw["intrinsics"] == INTR and kw["device"] == "cpu"


def test_pose_estimate_checks_shapes():
    with pytest.raises(ValueError, match="status"):
        PoseEstimate(None, None, "maybe")
    with pytest.raises(ValueError, match=r"\(34,\)"):
        PoseEstimate(np.zeros(33), None, "tracked")
    with pytest.raises(ValueError, match=r"\(16, 3\)"):
        PoseEstimate(None, np.zeros((15, 3)), "tracked")
    with pytest.raises(ValueError, match=r"joint_support_cm2 must be \(16,\)"):
        PoseEstimate(None, None, "tracked", joint_support_cm2=np.zeros(15))
    with pytest.raises(ValueError, match=r"limb_visibility must be \(4,\)"):
        PoseEstimate(None, None, "tracked", limb_visibility=np.zeros(3))
    kept = PoseEstimate(
        None, None, "tracked", joint_support_cm2=[1] * 16, limb_visibility=[0.5] * 4
    )
    assert kept.joint_support_cm2.dtype == np.float64 and kept.limb_visibility.shape == (4,)


# ---- as a separate process -------------------------------------------------------------------


def python(code: str, *args: str, **kw) -> subprocess.Popen:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    return subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code), *args],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


def test_subprocess_bad_input_has_no_traceback(tmp_path):
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "depthmocap.runtime.track_cli",
            "-i",
            str(tmp_path / "nothing"),
            "-o",
            str(tmp_path / "o"),
            "--mode",
            "tracker",
        ],
        cwd=REPO,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2
    assert_one_line_error(r.stderr, "no such file or directory")


# A fake "tracker" module for the child process: the real estimators are not needed to test
# the tool's plumbing.
_CHILD = """
    import sys, time, numpy as np
    import depthmocap.runtime.track_cli as cli
    from depthmocap.runtime.estimator import PoseEstimate

    class Slow:
        def reset(self):
            pass
        def estimate(self, frame):
            time.sleep(0.02)
            q = np.zeros(34); q[2] = 2.5; q[3] = np.pi
            return PoseEstimate(q, np.tile([0.0, 0.0, 2.5], (16, 1)), "tracked", {})

    cli.make_estimator = lambda *a, **k: Slow()
    sys.exit(cli.main(sys.argv[1:]))
"""


@pytest.mark.parametrize(
    "signum, said",
    [(signal.SIGINT, "interrupted"), (signal.SIGTERM, "terminated"), (signal.SIGHUP, "terminated")],
)
def test_subprocess_stop_signals_leave_valid_outputs(tmp_path, signum, said):
    """Ctrl-C, ``kill`` / ``timeout`` / ``docker stop`` (SIGTERM) and a closed terminal (SIGHUP)
    all finish the frame in flight and leave a complete result saying why it stopped."""
    rec = tmp_path / "rec"
    with RecordingWriter(rec, INTR, fps=30.0) as w:
        for _ in range(300):
            w.write_frame(person_frame())
    out = tmp_path / "out"
    p = python(_CHILD, "-i", str(rec), "-o", str(out), "--mode", "tracker", "--realtime")
    poses = out / "poses.jsonl"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and p.poll() is None:
        if poses.exists() and len(poses.read_text().splitlines()) >= 3:
            break
        time.sleep(0.05)
    assert p.poll() is None, p.communicate()
    p.send_signal(signum)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    assert f"{said}; results up to frame" in err and "Traceback" not in err
    records, summary, bvh_frames = read_result(out)
    assert 3 <= len(records) < 300
    # Real-time pacing may drop frames; the BVH still has one frame per stream frame.
    assert records[0]["frame"] == 0
    assert bvh_frames == records[-1]["frame"] + 1
    assert summary["extra"]["stopped"] == said
    assert summary["extra"]["warm_up_s"] > 0  # a live stream is warmed up before it starts


def test_subprocess_openni_dummy_device(tmp_path):
    pytest.importorskip("openni", reason="the 'openni' package is not installed")
    out = tmp_path / "out"
    p = python(_CHILD, "-i", "device:Dummy", "-o", str(out), "--mode", "tracker", "--stop", "4")
    _, err = p.communicate(timeout=120)
    if p.returncode == 2 and "OpenNI2 library not found" in err:
        pytest.skip("libOpenNI2 is not installed")
    assert p.returncode == 0, err
    records, summary, _ = read_result(out)
    # A camera is read on its own thread and the newest frame wins: frames the estimator had
    # no time for are skipped and counted, the last one is always tracked.
    frames = [r["frame"] for r in records]
    assert frames == sorted(set(frames)) and frames[-1] == 3
    assert len(frames) + summary["extra"]["dropped_frames"] == 4
    assert summary["extra"]["latency_ms"]["p95"] >= summary["extra"]["frame_time_ms"]["p50"]
    # The Dummy device shows no person: every frame is lost, and nothing breaks.
    assert summary["status_counts"]["lost"] == len(frames)
    assert summary["source"] == "openni:Dummy"


@pytest.mark.slow
def test_real_kinect_frames_end_to_end(shared_data, tmp_path, capsys):
    """Issue 6: real Kinect v1 frames are segmented and tracked without error (with the real
    default estimator and model). Skipped only without the frames in ../shared; a default
    estimator or model that fails to load is a failure, not a skip."""
    frames = shared_data / "kinect" / "skeltrack"
    if not frames.is_dir():
        pytest.skip("no Skeltrack frames")
    out = tmp_path / "out"
    code, err = run(["-i", frames, "-o", out, "--device", "cpu"], capsys)
    assert code == 0, err
    records, summary, _ = read_result(out)
    assert len(records) == 12
    found = [r for r in records if r["status"] != "lost"]
    assert found, "no skeleton on any real frame"
    for r in found:
        head = np.array(r["joints"]["head"])
        assert np.isfinite(head).all() and 0.5 < head[2] < 3.0


def test_realtime_newest_frame_wins_and_timing_is_reported():
    """A paced source with an estimator slower than the frame rate: frames the estimator had
    no time for are skipped and counted, never queued; latency and frame times are reported."""
    from depthmocap.runtime.track_loop import track

    class Writer:
        def __init__(self):
            self.indices = []

        def write_frame(self, index, *a, **k):
            self.indices.append(index)

    w, est = Writer(), FakeEstimator(delay_s=0.03)
    stats = track(ListStream([person_frame()] * 30, fps=100.0), est, w, realtime=True)
    assert w.indices == est.calls and w.indices == sorted(set(w.indices))
    # The last frame waits for the estimator; the first may be replaced by the second before
    # a loaded machine wakes the estimator (10 ms apart), as the newest frame wins.
    assert w.indices[-1] == 29
    assert stats.dropped == 30 - stats.frames and stats.dropped > 0
    timing = stats.timing()
    assert len(stats.latency_ms) == stats.frames == len(stats.frame_ms)
    assert timing["latency_ms"]["p95"] >= timing["frame_time_ms"]["p50"] >= 30.0 * 0.9
    assert set(timing["latency_ms"]) == {"mean", "p50", "p95", "max"}


def test_live_frames_are_prepared_beside_the_estimate():
    """Live (here a paced file), each frame's mask and the estimator's prefetch (the forest's
    labels) run on the reader thread, not the estimator's; frames without a person are not
    prefetched; the results are those of the plain loop."""
    import threading

    from depthmocap.runtime.track_loop import track

    class Writer:
        def __init__(self):
            self.rows = []

        def write_frame(self, index, time, status, *a, **k):
            self.rows.append((index, status))

    class Prefetching(FakeEstimator):
        def __init__(self):
            super().__init__()
            self.prefetched: list[tuple[int, str]] = []

        def prefetch(self, frame: Frame) -> None:
            self.prefetched.append((frame.index, threading.current_thread().name))

    frames = [person_frame(), np.zeros_like(person_frame()), person_frame()]
    live_w, live = Writer(), Prefetching()
    track(ListStream(frames, fps=10.0), live, live_w, realtime=True)
    file_w, from_file = Writer(), Prefetching()
    track(ListStream(frames, fps=50.0), from_file, file_w)
    plain_w, plain = Writer(), Prefetching()
    track(ListStream(frames, fps=50.0), plain, plain_w, pipelined=False)
    rows = [(0, "tracked"), (1, "lost"), (2, "tracked")]
    assert live_w.rows == file_w.rows == plain_w.rows == rows
    assert live.prefetched == from_file.prefetched == [(0, "depth-reader"), (2, "depth-reader")]
    assert [i for i, _ in plain.prefetched] == [0, 2]
    assert {name for _, name in plain.prefetched} == {threading.current_thread().name}


def test_a_file_keeps_every_frame_and_times_the_interval_between_poses():
    """A file read as fast as possible is prepared one frame ahead on the reader thread, but
    nothing is skipped however slow the estimator; a frame's time is the interval between
    poses written, so the preparation it waited for counts."""
    from depthmocap.runtime.track_loop import track

    class Writer:
        def __init__(self):
            self.indices = []

        def write_frame(self, index, *a, **k):
            self.indices.append(index)

    w, est = Writer(), FakeEstimator(delay_s=0.01)
    stats = track(ListStream([person_frame()] * 12, fps=100.0), est, w)
    assert w.indices == est.calls == list(range(12)) and stats.dropped == 0
    assert len(stats.frame_ms) == 12 and min(stats.frame_ms) >= 10.0 * 0.9
    assert sum(stats.frame_ms) <= stats.wall_s * 1e3 + 1e-6


class LookingBackEstimator(FakeEstimator):
    """Detects frame 1 (badness 2), tracks the others (badness 1); a refit from later frames
    has q[0] = 9 and badness 0.5 (runtime.look_back's estimator protocol)."""

    def __init__(self, sweep_margin: float | None = None):
        super().__init__()
        self.refits: list[int] = []
        self.cfg = SimpleNamespace(look_back=LookBackConfig(sweep_margin=sweep_margin))

    def estimate(self, frame: Frame) -> PoseEstimate:
        est = super().estimate(frame)
        if frame.index == 1:
            return PoseEstimate(est.q, est.joints, "detected", {"depth_error_cm": 2.0})
        return PoseEstimate(est.q, est.joints, "tracked", {"depth_error_cm": 1.0})

    def refit_from_later(self, frame, later, later2, velocity_scale):
        self.refits.append(frame.index)
        q = later.q.copy()
        q[0] = 9.0
        return PoseEstimate(q, later.joints, "tracked", {"depth_error_cm": 0.5}), 0.5

    def badness_of(self, estimate):
        return estimate.errors["depth_error_cm"]


class RowsWriter:
    def __init__(self):
        self.rows = []

    def write_frame(self, index, time, status, joints, q, errors, observed=None):
        self.rows.append((index, status, q[0], "looked_back" in errors))


def test_a_look_back_revises_a_doubted_frame_and_writes_every_frame():
    w, est = RowsWriter(), LookingBackEstimator()
    stats = cli.track(ListStream([person_frame()] * 4), est, w, look_back=3)
    # Frame 2 is clean: frames 1 and 0 (the lead-in) are refitted from it, and fit better.
    assert w.rows == [(0, "tracked", 9.0, True), (1, "detected", 9.0, True),
                      (2, "tracked", 0.0, False), (3, "tracked", 0.0, False)]  # fmt: skip
    assert est.refits == [1, 0] and stats.looked_back == (2, 2) and stats.frames == 4


def test_the_shipped_look_back_also_sweeps_every_frame_but_the_last():
    w, est = RowsWriter(), LookingBackEstimator(sweep_margin=LookBackConfig().sweep_margin)
    stats = cli.track(ListStream([person_frame()] * 4), est, w, look_back=3)
    # The run refits (1, 0) when frame 3 arrives; at the end the sweep: 2, 1, 0 from 3.
    assert est.refits == [1, 0, 2, 1, 0] and stats.looked_back == (5, 3)
    assert [r[2] for r in w.rows] == [9.0, 9.0, 9.0, 0.0] and stats.frames == 4


def test_frames_held_by_a_look_back_are_written_when_the_camera_drops():
    w, est = RowsWriter(), LookingBackEstimator()
    stream = ListStream([person_frame()] * 2, fail=SensorDisconnected("unplugged"))
    with pytest.raises(SensorDisconnected):
        cli.track(stream, est, w, look_back=5)
    assert [r[0] for r in w.rows] == [0, 1] and est.refits == []  # as they stood


def test_look_back_option_range_and_summary(fake, recording, tmp_path, capsys):
    code, err = run(["-i", recording, "-o", tmp_path / "o", "--look-back", "61"], capsys)
    assert code == 2
    assert_one_line_error(err, "--look-back must be 0-60")
    out = tmp_path / "ok"
    code, err = run(["-i", recording, "-o", out, "--mode", "tracker", "--look-back", "4"], capsys)
    assert code == 0, err
    records, summary, _ = read_result(out)
    assert len(records) == 5  # the fake tracker cannot refit: written as estimated
    assert summary["extra"]["looked_back"] == {"frames": 4, "refits": 0, "revised": 0}
