"""The synthetic training set and sequence mode (train.synth.trainset_builder,
train.synth.sequence): tiny runs with the procedural motions, checked for consistency,
determinism, resuming and read-back."""

from __future__ import annotations

import json
import math
import os
from dataclasses import replace

import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics, points_to_pixels
from depthmocap.shared.config import load_config
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
from depthmocap.shared.recording import Recording
from depthmocap.shared.sensor_noise import floor_depth, level_from_camera
from depthmocap.train.mocap.clip import axis_rotation
from depthmocap.train.mocap.motion_library import heading_normalized_joints
from depthmocap.train.mocap.pose_selection import furthest_point_sample
from depthmocap.train.synth.trainset import TrainSet, TrainSetError
from depthmocap.train.synth.trainset_builder import SynthConfig, frame_plan, synthesize_set
from depthmocap.train.synth.viewpoints import look_at

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def _need_egl():
    pytest.importorskip("pyrender")
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    from depthmocap.train.synth.render import DepthLabelRenderer

    try:
        DepthLabelRenderer(Intrinsics.kinect_v1(320)).close()
    except RuntimeError as err:
        pytest.skip(f"EGL rendering unavailable: {err}")


def tiny_config(**kw) -> SynthConfig:
    cfg = load_config(SynthConfig, os.path.join(REPO, "configs", "synth_tiny.yaml"))
    return replace(cfg, frames=6, shard_frames=3, **kw)


@pytest.fixture(scope="module")
def tiny_set(tmp_path_factory):
    _need_egl()
    out = tmp_path_factory.mktemp("tiny_set")
    synthesize_set(tiny_config(), out, progress=False, log=lambda *_: None)
    return out


def test_tiny_set_is_consistent(tiny_set):
    ts = TrainSet(tiny_set, verify=True)
    assert ts.frames == 6 and ts.num_shards == 2
    s = ts.load_frames()
    intr = ts.intrinsics
    assert s.depth.shape == (6, 240, 320) and s.depth.dtype == np.uint16
    # Every labelled pixel has a reading, every frame shows a person of several parts.
    assert not np.any((s.labels > 0) & (s.depth == 0))
    assert all(len(np.unique(lab)) > 8 for lab in s.labels)
    # The pelvis joint projects onto the person, at a depth a little in front of the surface
    # behind it (the pelvis is inside the body).
    uv = points_to_pixels(torch.as_tensor(s.joints), intr).numpy()
    pel = sk.JOINT_NAMES.index("pelvis")
    for f in range(6):
        u, v = np.round(uv[f, pel]).astype(int)
        assert 0 <= u < 320 and 0 <= v < 240
        win = s.labels[f, v - 3 : v + 4, u - 3 : u + 4]
        assert (win > 0).any()
    # Ground-truth q reproduces the joints up to the skeleton/mesh difference (a few cm).
    m = json.loads((tiny_set / "manifest.json").read_text())
    assert m["complete"] and sum(m["class_pixel_counts"]) == 6 * 240 * 320


def test_tiny_set_deterministic_and_resumable(tiny_set, tmp_path):
    cfg = tiny_config()
    out = tmp_path / "again"
    synthesize_set(cfg, out, progress=False, log=lambda *_: None)
    a = json.loads((tiny_set / "manifest.json").read_text())
    b = json.loads((out / "manifest.json").read_text())
    assert a["content_hash"] == b["content_hash"]
    # Lose one shard (as if interrupted): only it is rendered again, with the same bytes.
    (out / "shard_00001.npz").unlink()
    logs = []
    synthesize_set(cfg, out, progress=False, log=logs.append)
    assert any("1 of 2 shards already done" in line for line in logs)
    c = json.loads((out / "manifest.json").read_text())
    assert c["content_hash"] == a["content_hash"]
    # Another config in the same folder is refused rather than mixed in.
    with pytest.raises(TrainSetError, match="another config"):
        synthesize_set(replace(cfg, seed=5), out, progress=False, log=lambda *_: None)


def test_sequence_mode_recording_reads_back(tmp_path):
    _need_egl()
    from depthmocap.train.synth.sequence import render_sequence

    out = render_sequence("wave", tmp_path / "rec", frames=4, seed=2)
    rec = Recording(out)
    assert len(rec) == 4 and rec.has_labels and rec.has_groundtruth
    gt = rec.groundtruth()
    assert gt["joints"].shape == (4, len(sk.JOINT_NAMES), 3)
    assert list(gt["joint_names"]) == list(sk.JOINT_NAMES)
    assert gt["q"].shape == (4, sk.NUM_DOFS)
    body = BodyShape.load(out / "body.json")
    # FK of the ground-truth q with the ground-truth body lands near the anatomical joints.
    fk = named_joint_positions(forward_kinematics(torch.as_tensor(gt["q"]), body)).numpy()
    err = np.linalg.norm(fk - gt["joints"], axis=-1)
    assert np.median(err) < 0.03, err
    d = rec.read_depth_mm(0)
    assert d.shape == (240, 320) and (rec.read_labels(0) > 0).sum() > 500


def test_sequence_out_of_sensor_range_warns_and_still_renders(tmp_path):
    _need_egl()
    from depthmocap.train.synth.frame import SceneConfig
    from depthmocap.train.synth.sequence import render_sequence

    near = SceneConfig()
    near = replace(near, noise=replace(near.noise, max_depth_m=1.0))  # no camera fits 1 m
    with pytest.warns(UserWarning, match="within 1.0 m"):
        out = render_sequence("wave", tmp_path / "rec", frames=2, seed=2, cfg=near)
    assert len(Recording(out)) == 2


def test_sequence_out_of_sensor_range_raises_when_required(tmp_path):
    _need_egl()
    from depthmocap.train.synth.frame import SceneConfig
    from depthmocap.train.synth.sequence import OutOfRangeError, render_sequence

    near = SceneConfig()
    near = replace(near, noise=replace(near.noise, max_depth_m=1.0))
    with pytest.raises(OutOfRangeError, match="within 1.0 m"):
        render_sequence("wave", tmp_path / "rec", frames=2, seed=2, cfg=near, require_in_range=True)
    assert not (tmp_path / "rec").exists()


def test_all_dev_clips_keeps_tracked_classes_in_order(tmp_path):
    from depthmocap.train.evaluation.dev_recordings import all_dev_clips

    names = ["HDM_mm_squat1Reps_038_120.amc", "HDM_mm_lieDownFloor_015_120.amc",
             "HDM_mm_depositFloorR_019_120.amc", "HDM_mm.asf"]  # fmt: skip
    for n in names:
        (tmp_path / n).write_text("")
    assert all_dev_clips(tmp_path) == [
        "HDM_mm_depositFloorR_019_120.amc", "HDM_mm_squat1Reps_038_120.amc"
    ]  # fmt: skip


def test_sequence_mode_rejects_unknown_motion(tmp_path):
    from depthmocap.train.synth.cli import main

    assert main(["--sequence", "--motion", "no_such_clip.bvh", "--out", str(tmp_path / "r")]) == 2


def test_frame_plan_uses_every_pose_before_repeating():
    cfg = replace(SynthConfig(), frames=25, bodies=3)
    poses, bodies = frame_plan(cfg, 10)
    assert sorted(poses[:10]) == list(range(10)) and sorted(poses[10:20]) == list(range(10))
    assert bodies.min() >= 0 and bodies.max() < 3


def test_furthest_point_sampling_spacing():
    # Poses that differ by a pelvis-relative offset along a line, 1 cm apart.
    base = np.zeros((200, 16, 3))
    base[:, 0, 1] = np.arange(200) * 0.01
    idx = furthest_point_sample(base, 1000, 0.05)
    picked = np.sort(base[idx, 0, 1])
    assert np.diff(picked).min() >= 0.05 - 1e-9
    # Every candidate is within 5 cm of a pick, so 1.99 m need at least 20 picks.
    assert len(idx) >= 20
    assert len(furthest_point_sample(base, 3, 0.0)) == 3


def test_heading_normalization_removes_position_and_heading():
    rng = np.random.default_rng(0)
    j = rng.normal(size=(1, 16, 3))
    rot = axis_rotation("y", np.array([0.7]))[0]
    moved = j @ rot.T + np.array([1.0, 0.0, -2.0])
    a, b = heading_normalized_joints(j), heading_normalized_joints(moved)
    assert np.allclose(a, b, atol=1e-9)
    left = a[0, sk.JOINT_NAMES.index("l_hip")] - a[0, sk.JOINT_NAMES.index("r_hip")]
    assert abs(left[2]) < 1e-9 and left[0] > 0


def test_level_frame_matches_pitch_only_floor():
    intr = Intrinsics.kinect_v1(320)
    eye = np.array([[0.0, 1.2, 3.0]])
    cam = look_at(eye, np.array([0.0, 0.5, 0.0]))[0]
    pitch = math.atan2(0.7, 3.0)
    rot = level_from_camera(cam)
    assert np.allclose(floor_depth(intr, 1.2, pitch), floor_depth(intr, 1.2, 0.0, rot))
    # With roll the floor line tilts: its depth differs between the left and right edges.
    rolled = cam.copy()
    rolled[:3, :3] = axis_rotation("z", np.array([0.1]))[0] @ cam[:3, :3]
    d = floor_depth(intr, 1.2, 0.0, level_from_camera(rolled))
    assert abs(d[200, 10] - d[200, 310]) > 0.05


def _thread_env(_):
    import os

    return [os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")]


def test_rendering_workers_run_native_libraries_single_threaded(monkeypatch):
    import os

    from depthmocap.train.synth.trainset_builder import _single_threaded_pool

    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    with _single_threaded_pool(2) as pool:
        seen = pool.map(_thread_env, range(2))
    assert seen == [["1", "1"], ["1", "1"]]
    # The caller's environment is left as it was.
    assert os.environ["OMP_NUM_THREADS"] == "7" and "OPENBLAS_NUM_THREADS" not in os.environ


def _facing_deg(q: np.ndarray) -> np.ndarray:
    """Heading of each pose's hip line normal (the person's forward) about +y, degrees."""
    j = named_joint_positions(forward_kinematics(torch.as_tensor(q), BodyShape.default()))
    left = j[:, sk.JOINT_NAMES.index("l_hip")] - j[:, sk.JOINT_NAMES.index("r_hip")]
    fwd = torch.linalg.cross(left, torch.tensor([0.0, 1.0, 0.0], dtype=left.dtype).expand_as(left))
    return np.degrees(np.arctan2(fwd[:, 0].numpy(), fwd[:, 2].numpy()))


def test_face_forward_turns_each_pose_or_the_whole_sequence():
    from depthmocap.shared.procedural_motion import motion_poses
    from depthmocap.train.synth.frame import face_forward

    rng = np.random.default_rng(0)
    q = np.asarray(motion_poses("walk", 12, 30.0, rng), dtype=np.float64)
    headings = np.radians(rng.uniform(-180, 180, len(q)))
    turned = []
    for k, a in enumerate(headings):  # every pose facing somewhere else, as mocap clips do
        c, s = math.cos(a), math.sin(a)
        rot = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=torch.float64)
        turned.append(transform_pose_np(q[k : k + 1], rot))
    scattered = np.concatenate(turned)
    assert np.abs(_facing_deg(scattered)).max() > 90
    each = face_forward(scattered, frames=None)
    assert np.abs(_facing_deg(each)).max() < 1e-6
    # Joint angles are untouched; only the root turns.
    assert np.allclose(each[:, 6:], scattered[:, 6:])
    # Sequence mode: one angle for the whole clip, so the person's own turning is kept.
    seq = face_forward(scattered, frames=1)
    rel = (_facing_deg(seq) - _facing_deg(scattered) + 180) % 360 - 180
    assert np.allclose(rel, rel[0], atol=1e-6) and abs(_facing_deg(seq)[0]) < 1e-6


def transform_pose_np(q: np.ndarray, rot: torch.Tensor) -> np.ndarray:
    from depthmocap.shared.kinematics import transform_pose

    return transform_pose(torch.as_tensor(q), rot, torch.zeros(3, dtype=torch.float64)).numpy()


def test_procedural_library_restricted_to_the_calibration_pose_with_jitter():
    from depthmocap.shared.kinematics import clamp_to_limits
    from depthmocap.train.mocap.motion_library import procedural_library

    plain = procedural_library(np.random.default_rng(0), 10.0, 0, motions=["t_pose"])
    assert {s.name.rsplit("_", 1)[0] for s in plain} == {"t_pose"} and len(plain) == 3
    jittered = procedural_library(
        np.random.default_rng(0), 10.0, 0, motions=["t_pose"], jitter_rad=0.1
    )
    # The first variation is drawn before any jitter, so the two differ by the jitter alone.
    diff = np.abs(jittered[0].q[:, 6:] - plain[0].q[:, 6:])
    assert 0.01 < diff.max() <= 0.1 + 1e-9
    for b in jittered:  # jittered angles stay inside the limits
        assert np.allclose(clamp_to_limits(torch.as_tensor(b.q)).numpy(), b.q)
    with pytest.raises(ValueError, match="unknown procedural motions"):
        procedural_library(np.random.default_rng(0), 10.0, 0, motions=["moonwalk"])


def test_rendered_props_stay_in_the_runtime_segmentation(tmp_path):
    """The person/clutter set: the prop flush with the person is what the segmentation keeps
    with them (what the clutter forest must undo)."""
    _need_egl()
    from depthmocap.runtime.segmentation import segment_person
    from depthmocap.shared.labels import CLUTTER_CLASSES
    from depthmocap.train.synth.props import PropConfig

    cfg = tiny_config()
    props = PropConfig(1.0, True, sitting=0.5)
    cfg = replace(cfg, frames=6, scene=replace(cfg.scene, props=props))
    synthesize_set(cfg, tmp_path, progress=False, log=lambda *_: None)
    ts = TrainSet(tmp_path)
    assert ts.class_names == list(CLUTTER_CLASSES)
    s = ts.load_frames()
    assert set(np.unique(s.labels)) <= {0, 1, 2}
    clutter = s.labels == 2
    assert (clutter.reshape(6, -1).sum(1) > 50).sum() >= 4  # most frames show their prop
    mask = segment_person(torch.as_tensor(s.depth.astype(np.float32) / 1000), ts.intrinsics)
    mask = mask.numpy()
    assert (mask & clutter).sum() >= 0.8 * clutter.sum()
    assert (mask & (s.labels == 1)).sum() >= 0.9 * (s.labels == 1).sum()
