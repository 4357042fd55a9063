"""Result files of runtime-track: BVH round trip through the project's reader, poses.jsonl
round trip and interruption tolerance, and the ResultWriter's directory and summary."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from depthmocap.runtime.export import ResultDirError, ResultWriter
from depthmocap.runtime.export.bvh import CAMERA_TO_WORLD, BvhWriter, matrix_to_euler, write_bvh
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import (
    forward_kinematics,
    named_joint_positions,
    rest_pose,
    transform_pose,
)
from depthmocap.shared.poses_format import (
    PosesFileError,
    PosesJsonlWriter,
    pose_record,
    poses_to_arrays,
    read_poses_jsonl,
)
from depthmocap.shared.procedural_motion import motion_poses
from depthmocap.train.mocap.bvh import read_bvh
from depthmocap.train.mocap.clip import euler_to_matrix


def _body() -> BodyShape:
    """A non-default body: smaller overall, long left humerus, wide hips, leaning chest,
    lowered clavicles."""
    body = BodyShape.default(torch.float64).scaled(0.92)
    body.lengths[7] *= 1.15
    body.lengths[13] *= 1.05
    body.hip_half_width = body.hip_half_width * 1.2
    body.chest_tilt = torch.tensor(0.15, dtype=torch.float64)
    body.clavicle_rest = torch.tensor([-0.35, 0.1], dtype=torch.float64)
    return body


def _camera_poses(frames: int = 24) -> np.ndarray:
    """Procedural motion (world frame) seen from a camera 3 m in front, 1 m up: (F, 34)."""
    rng = np.random.default_rng(3)
    world = np.concatenate(
        [motion_poses(n, frames, 30.0, rng) for n in ("kick", "turn", "arm_cross", "wave")]
    )
    rot = torch.as_tensor(CAMERA_TO_WORLD)  # world y up -> camera y down, facing the camera
    q = transform_pose(torch.as_tensor(world), rot, torch.tensor([0.1, 0.05, 3.0]).double())
    return q.numpy()


def _bvh_positions(path, scale=0.01):
    """Segment origins and named joints (camera frame) re-computed from a BVH file."""
    clip = read_bvh(path, scale=scale, include_end_sites=True)
    pos = clip.positions @ CAMERA_TO_WORLD.T  # the world frame is the camera's turned by pi
    rot = CAMERA_TO_WORLD @ clip.rotations
    idx = {n: clip.joint_names.index(n) for n in clip.joint_names}
    origins = pos[:, [idx[n] for n in sk.SEGMENT_NAMES]]
    return clip, origins, pos, rot, idx


def test_euler_decomposition_inverts_composition_including_gimbal_lock():
    rng = np.random.default_rng(0)
    for order in ("xyz", "xzy", "yxz", "yzx", "zxy", "zyx"):
        ang = rng.uniform(-3.0, 3.0, (200, 3))
        ang[:, 1] = rng.uniform(-1.5, 1.5, 200)
        ang[:4, 1] = np.pi / 2
        ang[4:8, 1] = -np.pi / 2
        rot = euler_to_matrix(ang, order)
        back = euler_to_matrix(matrix_to_euler(rot, order), order)
        np.testing.assert_allclose(back, rot, atol=1e-12)
        np.testing.assert_allclose(matrix_to_euler(rot[8:], order), ang[8:], atol=1e-9)


def test_bvh_round_trip_reproduces_segment_origins_and_named_joints(tmp_path):
    q, body = _camera_poses(), _body()
    write_bvh(tmp_path / "m.bvh", q, body, fps=30.0)
    clip, origins, pos, rot, idx = _bvh_positions(tmp_path / "m.bvh")
    assert clip.fps == 30.0 and len(clip.positions) == len(q)

    kin = forward_kinematics(torch.as_tensor(q), body)
    np.testing.assert_allclose(origins, kin.origins.numpy(), atol=1e-3)
    # Named joints: segment origins, the leaf End Sites, and the head centre on the head axis.
    named = named_joint_positions(kin).numpy()
    head = idx["head"]
    head_centre = pos[:, head] + rot[:, head] @ (
        sk.JOINT_FRACTION[0] * float(body.lengths[4]) * sk.SEGMENT_AXIS[4]
    )
    from_bvh = {
        "head": head_centre,
        "l_wrist": pos[:, idx["l_forearm_end"]],
        "r_wrist": pos[:, idx["r_forearm_end"]],
        "l_ankle": pos[:, idx["l_shank_end"]],
        "r_ankle": pos[:, idx["r_shank_end"]],
    }
    for j, name in enumerate(sk.JOINT_NAMES):
        seg = sk.SEGMENT_NAMES[sk.JOINT_SEGMENT[j]]
        got = from_bvh.get(name, pos[:, idx[seg]])
        err = np.linalg.norm(got - named[:, j], axis=-1).max()
        assert err < 1e-3, f"{name}: {err * 1e3:.3f} mm"
    # Rotations too (the file carries the full segment frames, not only positions).
    seg_idx = [idx[n] for n in sk.SEGMENT_NAMES]
    np.testing.assert_allclose(rot[:, seg_idx], kin.rotations.numpy(), atol=1e-5)


def test_bvh_in_metres_and_upright_facing_plus_z(tmp_path):
    q = rest_pose(1, root_position=(0.0, 0.0, 2.0), dtype=torch.float64).numpy()
    write_bvh(tmp_path / "m.bvh", q, _body(), fps=25.0, units="m")
    clip = read_bvh(tmp_path / "m.bvh", scale=1.0)
    np.testing.assert_allclose(clip.fps, 25.0)
    # Facing the camera, upright: identity root rotation in the y-up world, root at z = -2.
    np.testing.assert_allclose(clip.rotations[0, 0], np.eye(3), atol=1e-9)
    np.testing.assert_allclose(clip.positions[0, 0], [0.0, 0.0, -2.0], atol=1e-9)
    head = clip.joint_names.index("head")
    assert clip.positions[0, head, 1] > 0.4  # head above the hips: y is up


def test_bvh_valid_between_frames_and_after_interruption(tmp_path):
    q, body = _camera_poses(6), _body()
    path = tmp_path / "m.bvh"
    writer = BvhWriter(path, body, fps=30.0)
    assert len(read_bvh(path).positions) == 0  # valid with zero frames
    for k in range(5):
        writer.write_pose(q[k])
        assert len(read_bvh(path).positions) == k + 1  # valid while still open
    # An interrupt inside a write: half a line reached the file but the count was not updated.
    writer._file.seek(0, 2)
    writer._file.write(b"1.0 2.0 3")
    writer._file.flush()
    with pytest.raises(ValueError):
        read_bvh(path)
    writer.close()
    writer.close()  # idempotent
    clip = read_bvh(path)
    kin = forward_kinematics(torch.as_tensor(q[:5]), body)
    np.testing.assert_allclose(
        (clip.positions @ CAMERA_TO_WORLD.T)[:, 0], kin.origins[:, 0].numpy(), atol=1e-5
    )


def test_bvh_missing_poses_repeat_last_or_rest(tmp_path):
    q, body = _camera_poses(4), _body()
    path = tmp_path / "m.bvh"
    with BvhWriter(path, body, fps=30.0) as writer:
        writer.write_pose(None)  # before any pose: rest pose facing the camera at 2.5 m
        writer.write_pose(q[1])
        writer.write_pose(None, repeat=2)
    clip = read_bvh(path)
    root = clip.positions[:, 0] @ CAMERA_TO_WORLD.T
    np.testing.assert_allclose(root[0], [0.0, 0.0, 2.5], atol=1e-6)
    np.testing.assert_allclose(root[1:], np.repeat(q[1:2, :3], 3, 0), atol=1e-6)


def test_poses_jsonl_round_trip(tmp_path):
    path = tmp_path / "poses.jsonl"
    joints = np.arange(48, dtype=np.float64).reshape(16, 3) / 10
    joints[3] = np.nan
    q = np.linspace(-1, 1, 34)
    with PosesJsonlWriter(path) as w:
        w.write(pose_record(0, 0.0, "detected", joints, q, {"depth_mm": 12.5, "x": np.nan}))
        w.write(pose_record(2, 0.0667, "lost", None, None, {}))
    data = read_poses_jsonl(path)
    assert not data.truncated and [r["frame"] for r in data.records] == [0, 2]
    rec = data.records[0]
    assert rec["status"] == "detected" and rec["errors"] == {"depth_mm": 12.5, "x": None}
    assert rec["joints"][sk.JOINT_NAMES[3]] is None
    arrays = poses_to_arrays(data.records)
    np.testing.assert_allclose(arrays["joints"][0], joints, atol=1e-6)  # NaN row kept as NaN
    np.testing.assert_allclose(arrays["q"][0], q, atol=1e-7)
    assert np.isnan(arrays["joints"][1]).all() and list(arrays["status"]) == ["detected", "lost"]
    with pytest.raises(ValueError, match="status"):
        pose_record(0, 0.0, "fine", None, None)


def test_poses_jsonl_observed_flags_round_trip_and_older_files_read_as_unknown(tmp_path):
    path = tmp_path / "poses.jsonl"
    flags = np.ones(16, dtype=bool)
    flags[[sk.JOINT_NAMES.index("r_elbow"), sk.JOINT_NAMES.index("r_wrist")]] = False
    with PosesJsonlWriter(path) as w:
        w.write(pose_record(0, 0.0, "tracked", None, None, {}, observed=flags))
        w.write(pose_record(1, 0.033, "tracked", None, None, {}))
    data = read_poses_jsonl(path)
    assert data.records[0]["observed"]["r_wrist"] is False
    assert data.records[0]["observed"]["head"] is True and data.records[1]["observed"] is None
    arrays = poses_to_arrays(data.records)
    np.testing.assert_array_equal(arrays["observed"][0], flags.astype(float))
    assert np.isnan(arrays["observed"][1]).all()
    old = path.read_text().replace(',"observed":null', "")  # a file from before the flags
    assert '"observed"' in old.splitlines()[0] and '"observed"' not in old.splitlines()[1]
    path.write_text(old)
    assert np.isnan(poses_to_arrays(read_poses_jsonl(path).records)["observed"][1]).all()
    with pytest.raises(ValueError, match="observed"):
        pose_record(0, 0.0, "tracked", None, None, {}, observed=np.ones(15, dtype=bool))
    path.write_text(old.splitlines()[0].replace("true", "1", 1) + "\n")
    with pytest.raises(PosesFileError, match="'observed' must be"):
        read_poses_jsonl(path)


def test_poses_jsonl_truncated_last_line_is_dropped_other_damage_is_an_error(tmp_path):
    path = tmp_path / "poses.jsonl"
    with PosesJsonlWriter(path) as w:
        for i in range(3):
            w.write(pose_record(i, i / 30, "tracked", None, None, {}))
    text = path.read_text()
    path.write_text(text + '{"frame": 3, "time": 0.1, "sta')
    data = read_poses_jsonl(path)
    assert data.truncated and len(data.records) == 3

    lines = text.splitlines(keepends=True)
    path.write_text(lines[0] + '{"frame": 1, "sta\n' + lines[2])
    with pytest.raises(PosesFileError, match=r"poses\.jsonl:2: not valid JSON"):
        read_poses_jsonl(path)
    path.write_text(lines[1] + lines[0])
    with pytest.raises(PosesFileError, match="does not follow"):
        read_poses_jsonl(path)
    with pytest.raises(PosesFileError, match="no such file"):
        read_poses_jsonl(tmp_path / "absent.jsonl")


def _write_result(out, q, body, statuses, close=True, start=0):
    writer = ResultWriter(out, body, 30.0, Intrinsics.kinect_v1(160), "hybrid", "test")
    joints = named_joint_positions(forward_kinematics(torch.as_tensor(q), body)).numpy()
    for k, status in enumerate(statuses):
        lost = status == "lost"
        writer.write_frame(
            start + k,
            (start + k) / 30.0,
            status,
            None if lost else joints[k],
            None if lost else q[k],
            {"surface_error_q97_mm": 20.0 + k},
        )
    return writer.close() if close else writer


def test_result_writer_files_summary_and_reimport(tmp_path):
    q, body = _camera_poses(3), _body()
    statuses = ["detected"] + ["tracked"] * 8 + ["lost"] * 2 + ["tracked"]
    out = tmp_path / "res"
    summary = _write_result(out, q, body, statuses)
    assert {p.name for p in out.iterdir()} == {
        "poses.jsonl",
        "motion.bvh",
        "summary.json",
        "body.json",
    }
    assert summary == json.loads((out / "summary.json").read_text())
    assert summary["complete"] and summary["frames"] == 12 and summary["stream_fps"] == 30.0
    assert summary["status_counts"] == {"tracked": 9, "detected": 1, "lost": 2}
    assert summary["first_frame"] == 0 and summary["last_frame"] == 11
    assert summary["fps"] is None or summary["fps"] > 0
    reloaded = BodyShape.load(out / "body.json", torch.float64)
    torch.testing.assert_close(reloaded.lengths, body.lengths)
    # Lost frames repeat the last pose in the BVH, which re-imports frame by frame.
    expect = q[: len(statuses)].copy()
    expect[9:11] = expect[8]
    _, origins, *_ = _bvh_positions(out / "motion.bvh")
    expect_origins = forward_kinematics(torch.as_tensor(expect), body).origins.numpy()
    np.testing.assert_allclose(origins, expect_origins, atol=1e-5)


def test_result_writer_interrupted_run_leaves_valid_files(tmp_path):
    q, body = _camera_poses(2), _body()
    out = tmp_path / "res"
    writer = _write_result(out, q, body, ["tracked"] * 5, close=False)  # no close: "Ctrl-C"
    assert len(read_poses_jsonl(out / "poses.jsonl").records) == 5
    assert len(read_bvh(out / "motion.bvh").positions) == 5
    assert json.loads((out / "summary.json").read_text())["complete"] is False
    with writer:  # context manager closes
        pass
    assert json.loads((out / "summary.json").read_text())["complete"] is True
    assert writer.close()["frames"] == 5  # idempotent


def test_result_writer_gaps_order_and_directory_policy(tmp_path):
    q, body = _camera_poses(2), _body()
    out = tmp_path / "res"
    with ResultWriter(out, body, 30.0, Intrinsics.kinect_v1(160), "tracker", "t") as writer:
        writer.write_frame(5, 0.0, "tracked", None, q[0], {})
        writer.write_frame(8, 0.1, "tracked", None, q[1], {})  # stream frames 6, 7 dropped
        with pytest.raises(ValueError, match="does not follow"):
            writer.write_frame(8, 0.1, "tracked", None, q[1], {})
    assert len(read_bvh(out / "motion.bvh").positions) == 4  # 5, 6, 7 (repeats), 8
    # A previous result is overwritten; a foreign non-empty directory is refused.
    summary = _write_result(out, q, body, ["tracked"] * 2)
    assert summary["frames"] == 2
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(ResultDirError, match="not empty"):
        ResultWriter(other, body, 30.0, Intrinsics.kinect_v1(160), "tracker", "t")


def test_bvh_set_body_rewrites_as_if_known_from_the_start(tmp_path):
    """A body found while tracking (the person's size): the file, its past frames included,
    equals one written with that body from the first frame, and writing goes on."""
    from depthmocap.runtime.export.bvh import BvhWriter
    from depthmocap.shared.kinematics import rest_pose

    body, bigger = BodyShape.default(), BodyShape.default().scaled(1.1)
    q = rest_pose(3, dtype=torch.float64).numpy()
    q[1, 3:6] = [3.0, 0.2, 0.1]
    moved = tmp_path / "moved"
    moved.mkdir()
    with BvhWriter(tmp_path / "a.bvh", body, 30.0, keep_poses=True) as w:
        w.write_pose(q[0])
        w.write_pose(None, 2)
        w.write_poses(q[1:2])
        (tmp_path / "a.bvh").rename(moved / "a.bvh")  # the staging folder moved into place
        w.set_body(bigger, moved / "a.bvh")
        w.write_pose(q[2])
        w.write_pose(None)
    with BvhWriter(tmp_path / "b.bvh", bigger, 30.0) as w:
        w.write_pose(q[0])
        w.write_pose(None, 2)
        w.write_poses(q[1:2])
        w.write_pose(q[2])
        w.write_pose(None)
    assert (moved / "a.bvh").read_bytes() == (tmp_path / "b.bvh").read_bytes()
    assert not (moved / "a.bvh.tmp").exists()


def test_bvh_set_body_failure_keeps_the_file(tmp_path):
    from depthmocap.runtime.export.bvh import BvhWriter
    from depthmocap.shared.kinematics import rest_pose

    q = rest_pose(1, dtype=torch.float64).numpy()
    with BvhWriter(tmp_path / "a.bvh", BodyShape.default(), 30.0, keep_poses=True) as w:
        w.write_pose(q[0])
        before = (tmp_path / "a.bvh").read_bytes()
        with pytest.raises(OSError):
            w.set_body(BodyShape.default().scaled(1.1), tmp_path / "gone" / "a.bvh")
        assert (tmp_path / "a.bvh").read_bytes() == before
        w.write_pose(q[0])  # still writing to the old file
    assert (tmp_path / "a.bvh").read_text().count("\n") == before.decode().count("\n") + 1


def test_bvh_set_body_needs_the_poses_kept(tmp_path):
    """Without keep_poses the writer holds no history (a long live capture stays small), so a
    new body after the first frame is refused rather than written inconsistently."""
    from depthmocap.shared.kinematics import rest_pose

    q = rest_pose(1, dtype=torch.float64).numpy()
    with BvhWriter(tmp_path / "a.bvh", BodyShape.default(), 30.0) as w:
        w.set_body(BodyShape.default().scaled(1.1))  # before any frame: nothing to rewrite
        w.write_pose(q[0])
        assert w._poses == []
        with pytest.raises(ValueError, match="keep_poses"):
            w.set_body(BodyShape.default())


def test_result_writer_update_body_rewrites_body_and_bvh(tmp_path):
    from depthmocap.shared.kinematics import rest_pose

    intr = Intrinsics.kinect_v1(160)
    q = rest_pose(2, dtype=torch.float64).numpy()
    bigger = BodyShape.default().scaled(1.1)
    out = tmp_path / "res"
    with ResultWriter(out, BodyShape.default(), 30.0, intr, "hybrid", "test",
                      body_may_change=True) as w:  # fmt: skip
        w.write_frame(0, 0.0, "tracked", None, q[0], {})
        w.update_body(bigger)
        w.write_frame(1, 1 / 30, "tracked", None, q[1], {})
    assert torch.allclose(BodyShape.load(out / "body.json").lengths, bigger.lengths)
    ref = tmp_path / "ref.bvh"
    write_bvh(ref, q, bigger, 30.0)
    assert (out / "motion.bvh").read_text() == ref.read_text()


def test_the_processing_rate_counts_estimates_not_held_writes(tmp_path, monkeypatch):
    """Frames estimated 100 ms apart but written in a burst at the end (a look-back's hold):
    ``fps`` is the estimates' rate, 10 frames/s; without the notes it is the writes'."""
    import depthmocap.runtime.export.results as results

    clock = {"t": 0.0}
    monkeypatch.setattr(results, "_clock", lambda: clock["t"])
    q, body = _camera_poses(1), _body()
    rates = {}
    for noted in (True, False):
        writer = ResultWriter(
            tmp_path / f"r{noted}", body, 30.0, Intrinsics.kinect_v1(160), "hybrid", "test"
        )
        for _ in range(5):
            clock["t"] += 0.1
            if noted:
                writer.note_estimated()
        for i in range(5):
            clock["t"] += 0.001
            writer.write_frame(i, i / 30, "tracked", None, q[0], {})
        rates[noted] = writer.close()["fps"]
    assert rates[True] == pytest.approx(10.0)
    assert rates[False] == pytest.approx(1000.0)
