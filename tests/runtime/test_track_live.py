"""``runtime-track --vmc / --osc / --smooth`` end to end: a real python-osc UDP server on
127.0.0.1 receives a short run, checked against the run's poses.jsonl; sending failures are
counted and never stop tracking; smoothing changes motion.bvh but never poses.jsonl."""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import depthmocap.runtime.track_cli as cli
import numpy as np
import pytest
from depthmocap.runtime.estimator import PoseEstimate
from depthmocap.runtime.export.vmc import VMC_BONE_NAMES, vmc_bone_transforms
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.recording import RecordingWriter

pytest.importorskip("pythonosc")
from pythonosc.dispatcher import Dispatcher  # noqa: E402
from pythonosc.osc_bundle import OscBundle  # noqa: E402
from pythonosc.osc_server import BlockingOSCUDPServer  # noqa: E402

INTR = Intrinsics.kinect_v1(160)
FRAMES = 6
LOST = 2  # the empty frame of the recording


def person_frame(intr: Intrinsics = INTR, z_mm: int = 2500) -> np.ndarray:
    """uint16 depth: a 0.5 m x 1.7 m slab at ``z_mm`` (0 = no reading around it)."""
    u, v = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    z = z_mm / 1000
    x, y = (u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z
    inside = (np.abs(x) < 0.25) & (y > -0.8) & (y < 0.9)
    return np.where(inside, z_mm, 0).astype(np.uint16)


class MovingEstimator:
    """A pose that changes every frame (root, root orientation, arm angles), with joints and
    observed flags that vary too."""

    def reset(self) -> None:
        pass

    def estimate(self, frame) -> PoseEstimate:
        i = frame.index
        q = np.zeros(sk.NUM_DOFS)
        q[0:3] = [0.05 * np.sin(i), 0.1 - 0.01 * i, 2.5 + 0.02 * i]
        q[3:6] = [np.pi - 0.05 * i, 0.1 * np.cos(i), 0.02 * i]
        q[sk.DOF_NAMES.index("l_humerus_abd")] = 0.3 + 0.2 * i
        q[sk.DOF_NAMES.index("r_radius_flex")] = 0.5 + 0.1 * (i % 3)
        joints = np.linspace([-0.3, -0.8, 2.4], [0.3, 0.9, 2.6], 16) + 0.0123456789 * i
        observed = (np.arange(16) + i) % 3 != 0
        return PoseEstimate(q, joints, "tracked", {"depth_m": 0.01}, observed=observed)


@pytest.fixture
def moving(monkeypatch) -> MovingEstimator:
    est = MovingEstimator()
    monkeypatch.setattr(cli, "make_estimator", lambda *a, **k: est)
    return est


@pytest.fixture
def recording(tmp_path) -> Path:
    path = tmp_path / "rec"
    with RecordingWriter(path, INTR, fps=30.0, source="test") as w:
        for i in range(FRAMES):
            w.write_frame(np.zeros_like(person_frame()) if i == LOST else person_frame())
    return path


class Server:
    """A python-osc BlockingOSCUDPServer on 127.0.0.1, ephemeral port, in a thread: messages
    in arrival order (one thread, so bundles stay in order)."""

    def __init__(self) -> None:
        self.messages: list[tuple[str, list]] = []
        d = Dispatcher()
        d.set_default_handler(lambda address, *args: self.messages.append((address, list(args))))
        self.server = BlockingOSCUDPServer(("127.0.0.1", 0), d)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, args=(0.02,))
        self.thread.start()

    def wait_for(self, address: str, count: int, timeout: float = 5.0) -> list[tuple[str, list]]:
        end = time.monotonic() + timeout
        while sum(a == address for a, _ in self.messages) < count and time.monotonic() < end:
            time.sleep(0.01)
        return list(self.messages)

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        self.thread.join()


@pytest.fixture
def server():
    s = Server()
    yield s
    s.close()


def unused_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def track(recording: Path, out: Path, *extra, capsys) -> tuple[int, str, list[dict], dict]:
    argv = ["--input", recording, "--output", out, "--mode", "tracker", "--quiet", *extra]
    code = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    records = [json.loads(line) for line in (out / "poses.jsonl").read_text().splitlines()]
    summary = json.loads((out / "summary.json").read_text())
    return code, err, records, summary


def split_frames(messages, last_address: str) -> list[list[tuple[str, list]]]:
    """Messages cut into frames, each ending with ``last_address``."""
    frames, current = [], []
    for m in messages:
        current.append(m)
        if m[0] == last_address:
            frames.append(current)
            current = []
    assert not current, "a frame's messages were cut off"
    return frames


def f32(v) -> float:
    return float(np.float32(v))


# ---- OSC ------------------------------------------------------------------------------------


def test_osc_stream_matches_poses_jsonl(moving, recording, tmp_path, server, capsys):
    code, err, records, summary = track(
        recording, tmp_path / "out", "--osc", f"127.0.0.1:{server.port}", capsys=capsys
    )
    assert code == 0, err
    msgs = server.wait_for("/depthmocap/frame", FRAMES)
    frames = [[]]
    for m in msgs:  # a frame: its /depthmocap/frame message and the joints after it
        if m[0] == "/depthmocap/frame":
            frames.append([])
        frames[-1].append(m)
    frames = frames[1:]
    assert len(frames) == len(records) == FRAMES
    for rec, frame in zip(records, frames):
        (_, (index, t, status)), joints = frame[0], frame[1:]
        assert (index, t, status) == (rec["frame"], f32(rec["time"]), rec["status"])
        if rec["status"] == "lost":
            assert joints == []
            continue
        assert [a for a, _ in joints] == [f"/depthmocap/joint/{n}" for n in sk.JOINT_NAMES]
        for (_, args), name in zip(joints, sk.JOINT_NAMES):
            # Exactly the file's values, as float32.
            assert args[:3] == [f32(v) for v in rec["joints"][name]], name
            assert args[3] == int(rec["observed"][name])
    assert summary["extra"]["stream_errors"] == {"osc": 0}
    assert summary["extra"]["stream_sent"] == {"osc": FRAMES}
    assert summary["extra"]["stream"]["osc"] == f"127.0.0.1:{server.port}"


# ---- VMC ------------------------------------------------------------------------------------


def test_vmc_stream_bones_flags_time_and_root(moving, recording, tmp_path, server, capsys):
    code, err, records, summary = track(
        recording, tmp_path / "out", "--vmc", f"127.0.0.1:{server.port}", capsys=capsys
    )
    assert code == 0, err
    frames = split_frames(server.wait_for("/VMC/Ext/T", FRAMES), "/VMC/Ext/T")
    assert len(frames) == len(records) == FRAMES
    body = BodyShape.load(tmp_path / "out" / "body.json")
    for rec, frame in zip(records, frames):
        by_address: dict[str, list] = {}
        for a, args in frame:
            by_address.setdefault(a, []).append(args)
        assert by_address["/VMC/Ext/T"] == [[f32(rec["time"])]]
        if rec["status"] == "lost":
            assert set(by_address) == {"/VMC/Ext/OK", "/VMC/Ext/T"}
            assert by_address["/VMC/Ext/OK"] == [[0]]
            continue
        assert by_address["/VMC/Ext/OK"] == [[1]]
        bones = {args[0]: args[1:] for args in by_address["/VMC/Ext/Bone/Pos"]}
        assert set(bones) == set(VMC_BONE_NAMES) and len(by_address["/VMC/Ext/Bone/Pos"]) == 19
        ((name, *root),) = by_address["/VMC/Ext/Root/Pos"]
        q = np.array(rec["q"])
        # The documented conversion: Unity position = (-x, -y, -z) of camera metres.
        assert name == "root"
        np.testing.assert_allclose(root[:3], -q[0:3], rtol=0, atol=1e-6)
        np.testing.assert_allclose(root[3:], [0, 0, 0, 1])
        expected = {n: np.r_[p, r] for n, p, r in vmc_bone_transforms(q, body)}
        for n, args in bones.items():
            np.testing.assert_allclose(args, expected[n], rtol=0, atol=1e-6, err_msg=n)
    assert summary["extra"]["stream_errors"] == {"vmc": 0}


def test_each_frame_is_one_bundle(moving, recording, tmp_path, capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(5.0)
        port = sock.getsockname()[1]
        code, err, records, _ = track(
            recording, tmp_path / "out", "--vmc", f"127.0.0.1:{port}", capsys=capsys
        )
        assert code == 0, err
        datagrams = [sock.recv(65536) for _ in range(FRAMES)]
    for rec, data in zip(records, datagrams):
        assert OscBundle.dgram_is_bundle(data)
        addresses = [m.address for m in OscBundle(data)]
        assert addresses[-2:] == ["/VMC/Ext/OK", "/VMC/Ext/T"]
        assert len(addresses) == (2 if rec["status"] == "lost" else 22)


# ---- failures never stop tracking -----------------------------------------------------------


def test_nobody_listening_is_no_error(moving, recording, tmp_path, capsys):
    port = unused_udp_port()
    code, err, records, summary = track(
        recording, tmp_path / "out", "--vmc", f"127.0.0.1:{port}", "--osc",
        f"localhost:{port}", capsys=capsys,
    )  # fmt: skip
    assert code == 0, err
    assert len(records) == FRAMES and summary["complete"]
    assert summary["extra"]["stream_sent"] == {"vmc": FRAMES, "osc": FRAMES}


def test_send_errors_are_counted_and_reported(moving, recording, tmp_path, monkeypatch, capsys):
    from pythonosc.udp_client import UDPClient

    def fail(self, content):
        raise OSError(101, "Network is unreachable")

    monkeypatch.setattr(UDPClient, "send", fail)
    code, err, records, summary = track(
        recording, tmp_path / "out", "--vmc", "127.0.0.1:39539", capsys=capsys
    )
    assert code == 0, err
    assert len(records) == FRAMES
    assert summary["extra"]["stream_errors"] == {"vmc": FRAMES}
    assert summary["extra"]["stream_sent"] == {"vmc": 0}
    assert "Network is unreachable" in summary["extra"]["stream_last_error"]["vmc"]
    warnings = [line for line in err.splitlines() if line.startswith("warning: --vmc")]
    assert len(warnings) == 1  # once, not per frame


def test_a_real_send_error_broadcast_without_permission(moving, recording, tmp_path, capsys):
    # Sending to the broadcast address without SO_BROADCAST fails in sendto (EACCES on Linux).
    code, err, records, summary = track(
        recording, tmp_path / "out", "--osc", "255.255.255.255:9000", capsys=capsys
    )
    assert code == 0, err
    assert len(records) == FRAMES
    assert summary["extra"]["stream_errors"]["osc"] == FRAMES


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--vmc", "localhost"], "HOST:PORT"),
        (["--osc", "127.0.0.1:0"], "HOST:PORT"),
        (["--vmc", ":9000"], "HOST:PORT"),
        (["--smooth-beta", "0.5"], "needs --smooth"),
        (["--smooth", "--smooth-min-cutoff", "0"], "min_cutoff"),
        (["--smooth", "--smooth-beta", "-1"], "beta"),
    ],
)
def test_bad_live_options(moving, recording, tmp_path, capsys, argv, fragment):
    out = tmp_path / "out"
    argv = ["--input", recording, "--output", out, "--mode", "tracker", *argv]
    code = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: ") and fragment in err
    assert not out.exists()


# ---- smoothing ------------------------------------------------------------------------------


def bvh_motion(out: Path) -> list[str]:
    return (out / "motion.bvh").read_text().split("MOTION\n", 1)[1].splitlines()[2:]


def test_smooth_leaves_poses_jsonl_raw_and_smooths_the_bvh(moving, recording, tmp_path, capsys):
    raw_out, smooth_out = tmp_path / "raw", tmp_path / "smooth"
    code, err, raw, _ = track(recording, raw_out, capsys=capsys)
    assert code == 0, err
    code, err, smoothed, summary = track(
        recording, smooth_out, "--smooth", "--smooth-min-cutoff", "0.5", "--smooth-beta", "0.2",
        capsys=capsys,
    )  # fmt: skip
    assert code == 0, err
    assert (smooth_out / "poses.jsonl").read_bytes() == (raw_out / "poses.jsonl").read_bytes()
    raw_bvh, smooth_bvh = bvh_motion(raw_out), bvh_motion(smooth_out)
    assert len(raw_bvh) == len(smooth_bvh) == FRAMES
    # The first pose and the first after the lost frame pass through (the filter restarts);
    # the lost frame repeats the pose before it; the others are smoothed.
    assert smooth_bvh[0] == raw_bvh[0] and smooth_bvh[LOST + 1] == raw_bvh[LOST + 1]
    assert smooth_bvh[LOST] == smooth_bvh[LOST - 1]
    assert smooth_bvh[1] != raw_bvh[1] and smooth_bvh[-1] != raw_bvh[-1]
    assert summary["extra"]["stream"]["smoothing"] == {
        "min_cutoff": 0.5,
        "beta": 0.2,
        "d_cutoff": 1.0,
    }


def test_smooth_vmc_sends_the_filtered_pose(moving, recording, tmp_path, server, capsys):
    from depthmocap.runtime.export.one_euro import PoseSmoother, SmoothingConfig

    code, err, records, _ = track(
        recording, tmp_path / "out", "--vmc", f"127.0.0.1:{server.port}", "--smooth",
        capsys=capsys,
    )  # fmt: skip
    assert code == 0, err
    frames = split_frames(server.wait_for("/VMC/Ext/T", FRAMES), "/VMC/Ext/T")
    smoother = PoseSmoother(SmoothingConfig(), fps=30.0)
    roots = []
    for rec in records:
        if rec["q"] is None:
            smoother.reset()
            roots.append(None)
        else:
            roots.append(-smoother.pose(rec["time"], np.array(rec["q"]))[0:3])
    for expected, frame in zip(roots, frames):
        root = [args for a, args in frame if a == "/VMC/Ext/Root/Pos"]
        if expected is None:
            assert root == []
        else:
            np.testing.assert_allclose(root[0][1:4], expected, rtol=0, atol=1e-6)


def test_missing_python_osc_is_a_one_line_error(moving, recording, tmp_path, monkeypatch, capsys):
    import sys

    monkeypatch.setitem(sys.modules, "pythonosc.udp_client", None)  # import fails
    out = tmp_path / "out"
    argv = ["--input", recording, "--output", out, "--mode", "tracker", "--vmc", "127.0.0.1:9"]
    code = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: --vmc needs the python-osc package"), err
    assert "depthmocap[stream]" in err and not out.exists()
    # Smoothing alone needs no python-osc.
    code, err, records, summary = track(recording, out, "--smooth", capsys=capsys)
    assert code == 0 and len(records) == FRAMES, err
    assert summary["extra"]["stream"] == {
        "vmc": None,
        "osc": None,
        "smoothing": {"min_cutoff": 1.0, "beta": 1.0, "d_cutoff": 1.0},
    }
