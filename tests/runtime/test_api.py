"""The Python API (``from depthmocap import Tracker, open_stream, read_poses``): the same poses
as ``runtime-track``, raw arrays, reset, clear errors, and results read back into arrays."""

from __future__ import annotations

import json
import subprocess
import sys

import depthmocap.runtime.track_cli as cli
import numpy as np
import pytest
import torch
from depthmocap.runtime.estimator_setup import POPULATION_BODY
from depthmocap.runtime.streams import FrameRange
from depthmocap.shared.poses_format import PosesFileError

import depthmocap
from depthmocap import Intrinsics, Tracker, TrackError, open_stream, read_poses

FRAMES = 8


@pytest.fixture(scope="module")
def demo_frames():
    with open_stream("demo", frame_range=FrameRange(0, FRAMES)) as stream:
        return list(stream)


@pytest.fixture(scope="module")
def cli_result(tmp_path_factory):
    """``runtime-track --input demo`` with nothing else, first FRAMES frames (1 thread)."""
    out = tmp_path_factory.mktemp("api") / "result"
    before = torch.get_num_threads()
    assert cli.main(["-i", "demo", "-o", str(out), "--stop", str(FRAMES), "-q"]) == 0
    torch.set_num_threads(before)
    return out


@pytest.fixture(scope="module")
def cli_unsmoothed(tmp_path_factory):
    """The same with ``--fixed-lag 0 --look-back 0``: every pose as fitted."""
    out = tmp_path_factory.mktemp("api") / "result"
    before = torch.get_num_threads()
    argv = ["-i", "demo", "-o", str(out), "--stop", str(FRAMES), "-q", "--fixed-lag", "0",
            "--look-back", "0"]  # fmt: skip
    assert cli.main(argv) == 0
    torch.set_num_threads(before)
    return out


def _track_all(tracker, frames, raw=False):
    if raw:
        return [tracker.track(f.depth_mm, intrinsics=f.intrinsics, time=f.time) for f in frames]
    return [tracker.track(f) for f in frames]


class _Collect:
    """A writer that keeps what it is given."""

    def __init__(self):
        self.extra, self.rows = {}, []

    def write_frame(self, index, time, status, joints, q, errors, observed=None):
        self.rows.append((status, joints, q))

    def close(self):
        return {}


@pytest.mark.slow
def test_runtime_track_smooths_a_file_as_the_fixed_lag_smoother_does(
    one_thread, demo_frames, cli_result
):
    from depthmocap.runtime.export.fixed_lag import FILE_FIXED_LAG, FixedLagSmoother

    poses = read_poses(cli_result)
    sink = _Collect()
    smoother = FixedLagSmoother(sink, FILE_FIXED_LAG)
    with open_stream("demo", frame_range=FrameRange(0, FRAMES)) as stream:
        looked_back = list(Tracker().track_stream(stream, fixed_lag=0))  # as runtime-track
    for f, e in looked_back:
        smoother.write_frame(f.index, f.time, e.status, e.joints, e.q, e.errors, e.observed)
    smoother.close()
    assert list(poses.status) == [s for s, _, _ in sink.rows]
    np.testing.assert_allclose(poses.joints, np.stack([j for _, j, _ in sink.rows]), atol=1e-6)
    np.testing.assert_allclose(poses.q, np.stack([q for _, _, q in sink.rows]), atol=1e-6)
    summary = json.loads((cli_result / "summary.json").read_text())
    assert summary["extra"]["fixed_lag_frames"] == FILE_FIXED_LAG


@pytest.mark.slow
def test_the_same_poses_as_runtime_track(one_thread, demo_frames, cli_unsmoothed):
    poses = read_poses(cli_unsmoothed)
    estimates = _track_all(Tracker(), demo_frames)
    assert list(poses.status) == [e.status for e in estimates]
    joints = np.stack([e.joints for e in estimates])
    # poses.jsonl rounds to micrometres.
    np.testing.assert_allclose(poses.joints, joints, atol=1e-6)
    np.testing.assert_allclose(poses.q, np.stack([e.q for e in estimates]), atol=1e-6)
    observed = np.stack([e.observed for e in estimates]).astype(float)
    np.testing.assert_array_equal(poses.observed, observed)


@pytest.mark.slow
def test_raw_uint16_arrays_and_reset(one_thread, demo_frames):
    from_stream = _track_all(Tracker(), demo_frames[:4])
    tracker = Tracker()
    from_arrays = _track_all(tracker, demo_frames[:4], raw=True)
    for a, b in zip(from_stream, from_arrays):
        assert a.status == b.status
        np.testing.assert_array_equal(a.joints, b.joints)
    # reset(): the next frame is found from scratch, as by a new tracker.
    tracker.reset()
    after_reset = tracker.track(demo_frames[5])
    fresh = Tracker().track(demo_frames[5])
    assert after_reset.status == fresh.status
    np.testing.assert_array_equal(after_reset.joints, fresh.joints)


def test_an_empty_frame_is_lost_and_the_default_camera_is_a_kinect():
    tracker = Tracker()
    pose = tracker.track(np.zeros((240, 320), np.uint16))
    assert pose.status == "lost" and pose.joints is None and pose.q is None
    assert tracker._intrinsics == Intrinsics.kinect_v1(320)
    nan_frame = np.full((240, 320), np.nan, np.float32)  # float frames: NaN = no reading
    assert tracker.track(nan_frame).status == "lost"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"preset": "nope"}, "shipped"),
        ({"model": "no/such/forest.npz"}, "model file not found: no/such/forest.npz"),
        ({"body": "no/such/body.json"}, "body file not found"),
        ({"config": "no/such.yaml"}, "config file not found"),
        ({"mode": "detector", "preset": "wei2012"}, "--preset names hybrid settings"),
    ],
)
def test_bad_set_up_is_one_clear_error(kwargs, match):
    with pytest.raises(TrackError, match=match):
        Tracker(**kwargs)


def test_bad_frames_are_clear_errors():
    tracker = Tracker()
    with pytest.raises(TrackError, match=r"\(H, W\) array"):
        tracker.track(np.zeros((2, 240, 320), np.uint16))
    with pytest.raises(TrackError, match="320x240 but the intrinsics are 640x480"):
        tracker.track(np.zeros((240, 320), np.uint16), intrinsics=Intrinsics.kinect_v1(640))


def test_settings_follow_preset_and_config(tmp_path):
    shipped = Tracker()
    wei = Tracker(preset="wei2012")
    assert shipped.settings != wei.settings
    over = Tracker(config={"failure": {"epsilon1_cm": 4.5}})
    assert over.settings["failure"]["epsilon1_cm"] == 4.5
    assert over.settings["arm_search"] == shipped.settings["arm_search"]
    path = tmp_path / "c.yaml"
    path.write_text("failure:\n  epsilon1_cm: 4.5\n")
    assert Tracker(config=str(path)).settings == over.settings
    with pytest.raises(TrackError):  # an unknown key fails when the estimator is built
        Tracker(config={"no_such_key": 1}).track(np.zeros((240, 320), np.uint16))


def test_read_poses(cli_result, tmp_path):
    poses = read_poses(cli_result)
    assert len(poses) == FRAMES and poses.joints.shape == (FRAMES, 16, 3)
    assert poses.q.shape == (FRAMES, 34) and poses.observed.shape == (FRAMES, 16)
    assert list(poses.frame) == list(range(FRAMES)) and not poses.truncated
    np.testing.assert_array_equal(poses.joint("head"), poses.joints[:, 0])
    assert poses.summary["frames"] == FRAMES and poses.summary["complete"]
    again = read_poses(cli_result / "poses.jsonl")
    np.testing.assert_array_equal(again.joints, poses.joints)
    # An interrupted write: the unfinished last line is dropped and reported.
    cut = tmp_path / "cut"
    cut.mkdir()
    text = (cli_result / "poses.jsonl").read_text()
    (cut / "poses.jsonl").write_text(text[: text.rindex("\n", 0, -1) + 20])
    part = read_poses(cut)
    assert part.truncated and len(part) == FRAMES - 1 and part.summary is None
    (cut / "summary.json").write_text("{not json")
    with pytest.raises(PosesFileError, match="summary.json"):
        read_poses(cut)
    with pytest.raises(PosesFileError, match="no such file"):
        read_poses(tmp_path / "nowhere")


def test_lost_frames_read_as_nan(tmp_path):
    out = tmp_path / "r"
    rec = {"frame": 0, "time": 0.0, "status": "lost", "joints": None, "q": None, "errors": {}}
    out.mkdir()
    (out / "poses.jsonl").write_text(json.dumps(rec) + "\n")
    poses = read_poses(out)
    assert poses.status[0] == "lost" and np.isnan(poses.joints).all() and np.isnan(poses.q).all()


def test_the_package_exports_resolve_and_import_lazily():
    for name in depthmocap.__all__:
        assert getattr(depthmocap, name) is not None
    with pytest.raises(AttributeError):
        depthmocap.no_such_name  # noqa: B018
    code = "import sys, depthmocap; print('torch' in sys.modules, depthmocap.__version__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", depthmocap.__version__]


def test_all_lists_exactly_the_lazy_exports():
    assert set(depthmocap.__all__) == {*depthmocap._EXPORTS, "__version__"}


def test_the_body_in_use():
    tracker = Tracker()
    # No body given: the population's average adult, not the built-in textbook one.
    population = depthmocap.BodyShape.load(POPULATION_BODY)
    assert torch.equal(tracker.body.lengths, population.lengths)
    assert float(tracker.body.chest_tilt) > 0.1  # anny's chest leans on the abdomen
    assert not torch.equal(tracker.body.lengths, depthmocap.BodyShape.default().lengths)
    tracker.track(np.zeros((240, 320), np.uint16))  # builds the estimator
    assert tracker.body is tracker._estimator.body


def test_a_missing_population_body_says_so(tmp_path, monkeypatch):
    """A broken install (the shipped body template gone) is one clear error, not a bare
    'body file not found' for a file the user never named."""
    import depthmocap.runtime.estimator_setup as setup

    monkeypatch.setattr(setup, "POPULATION_BODY", tmp_path / "gone.json")
    with pytest.raises(TrackError, match="shipped population body is missing"):
        Tracker()


@pytest.mark.slow
def test_track_stream_gives_the_poses_of_track(one_thread, demo_frames):
    """track_stream prepares the next frame on a reader thread: every frame, in order, with
    the poses frame-by-frame track() gives; break stops the reader."""
    one_by_one = _track_all(Tracker(), demo_frames)
    tracker = Tracker()
    with open_stream("demo", frame_range=FrameRange(0, FRAMES)) as stream:
        got = list(tracker.track_stream(stream, fixed_lag=0, look_back=0))
    assert [f.index for f, _ in got] == [f.index for f in demo_frames] and tracker.skipped == 0
    for (_, a), b in zip(got, one_by_one, strict=True):
        assert a.status == b.status
        np.testing.assert_array_equal(a.joints, b.joints)
        np.testing.assert_array_equal(a.observed, b.observed)
    import threading

    with open_stream("demo") as stream:
        first = next(iter(Tracker().track_stream(stream)))
    assert first[0].index == 0
    assert not any(t.name == "depth-reader" and t.is_alive() for t in threading.enumerate())


@pytest.mark.slow
def test_track_stream_smooths_a_file_as_runtime_track_does(one_thread, cli_result):
    """By default a file's poses come smoothed and late, as runtime-track writes them; the
    frames held are yielded when the stream ends."""
    poses = read_poses(cli_result)
    with open_stream("demo", frame_range=FrameRange(0, FRAMES)) as stream:
        got = list(Tracker().track_stream(stream))
    assert [f.index for f, _ in got] == list(range(FRAMES))
    np.testing.assert_allclose(np.stack([p.joints for _, p in got]), poses.joints, atol=1e-6)
    np.testing.assert_allclose(np.stack([p.q for _, p in got]), poses.q, atol=1e-6)
    with pytest.raises(TrackError, match="fixed_lag"):
        Tracker().track_stream(stream, fixed_lag=-1)
    with pytest.raises(TrackError, match="look_back must be 0-60"):
        Tracker().track_stream(stream, look_back=61)


def test_track_stream_reports_stream_errors_after_the_frames_before(one_thread, demo_frames):
    from depthmocap.runtime.streams import DepthStream, StreamError

    class Broken(DepthStream):
        source, is_live = "test:broken", False
        intrinsics, fps, frame_count = demo_frames[0].intrinsics, 30.0, None

        def __iter__(self):
            yield from demo_frames[:2]
            raise StreamError("frame 2 is corrupt")

    got = []
    with pytest.raises(StreamError, match="corrupt"):
        for frame, pose in Tracker().track_stream(Broken()):
            got.append((frame.index, pose.status))
    assert [i for i, _ in got] == [0, 1]


def _live(frames):
    """A camera-like stream (``is_live``: the newest frame wins) of ``frames``."""
    from depthmocap.runtime.streams import DepthStream

    class Live(DepthStream):
        source, is_live = "test:live", True
        intrinsics, fps, frame_count = frames[0].intrinsics, 30.0, None

        def __iter__(self):
            yield from frames

    return Live()


def test_a_live_stream_is_warmed_up_once_before_its_first_frame(one_thread, demo_frames):
    """A camera's newest frame wins, so the process is warmed up before its first frame (a
    file is not: it keeps every frame); the warm-up's estimator is not the one tracking."""
    tracker = Tracker()
    got = [pose.status for _, pose in tracker.track_stream(_live(demo_frames[:2]))]
    assert tracker.warm_up_s is not None and tracker.warm_up_s > 0
    assert got[0] == "detected"  # the real estimator starts afresh on the camera's frame 0
    warmed = tracker.warm_up_s
    list(tracker.track_stream(_live(demo_frames[:2])))
    assert tracker.warm_up_s == warmed  # once per tracker
    assert Tracker().warm_up_s is None


def test_a_failed_warm_up_warns_and_the_live_stream_is_tracked(
    one_thread, demo_frames, monkeypatch
):
    import math

    import depthmocap.runtime.warm_up as warm_up_module

    def broken(*args, **kwargs):
        raise RuntimeError("cannot render the demo")

    monkeypatch.setattr(warm_up_module, "warm_up", broken)

    tracker = Tracker()
    with pytest.warns(UserWarning, match="warm-up failed"):
        got = [pose.status for _, pose in tracker.track_stream(_live(demo_frames[:2]))]
    assert got[0] == "detected" and len(got) == 2 and math.isnan(tracker.warm_up_s)


def test_auto_device_is_the_measured_faster_cpu_even_with_a_gpu(monkeypatch):
    # "auto" must not follow torch.cuda.is_available(): the GPU path is measured slower.
    from depthmocap.runtime.estimator_setup import AUTO_DEVICE, pick_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert pick_device("auto") == AUTO_DEVICE == "cpu"
    assert pick_device("cuda") == "cuda"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert pick_device("cpu") == "cpu"
    with pytest.raises(TrackError, match="no CUDA device"):
        pick_device("cuda")
