"""``train-import --utd-mhad`` on tiny synthetic .mat files written here with scipy: mirroring,
axes and intrinsics against golden pixels, the round trip, the streams put in step, filters, and
malformed input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from depthmocap.shared.camera import points_to_pixels
from depthmocap.shared.recording import Recording, mapped_reference
from depthmocap.shared.skeleton import JOINT_NAMES
from depthmocap.train.importers import utd_mhad as utd
from depthmocap.train.importers.cli import main

scipy_io = pytest.importorskip("scipy.io")

T = 5
F = utd.FOCAL_PX
# A left wrist 70 px left of the mirrored image's centre column 160 and 40 px above row 120:
# f x / z = -70 and f y / z = 40 exactly at z = f / 100 metres.
Z = F / 100
WRIST = np.array([-0.7, 0.4, Z])
WRIST_MIRRORED_PIXEL = (90, 80)  # (u, v) = (160 - 70, 120 - 40), the SDK's own mapping
WRIST_PIXEL = (229, 80)  # un-mirrored: u = 319 - 90; a person's left is on the image's right
WRIST_MM = 2856


def _skeleton(frames: int = T) -> np.ndarray:
    """(20, 3, T) Kinect skeleton space, as the files store it: a body 2.9 m away, the left
    wrist at :data:`WRIST`, moving 1 cm to the (mirrored) right per frame."""
    rng = np.random.default_rng(0)
    skel = np.stack([rng.uniform(-0.3, 0.3, 20), rng.uniform(-0.9, 0.6, 20), np.full(20, 2.9)], 1)
    skel[utd.KINECT_JOINTS.index("left_wrist")] = WRIST
    out = np.repeat(skel[:, :, None], frames, 2)
    out[:, 0, :] += 0.01 * np.arange(frames)
    return out


def _depth(frames: int = T) -> np.ndarray:
    """(240, 320, T) uint16 mirrored frames: a blob at the wrist's mirrored pixel and a bar
    on the mirrored image's left edge, so that a missing or doubled flip shows."""
    depth = np.zeros((240, 320, frames), np.uint16)
    u, v = WRIST_MIRRORED_PIXEL
    depth[v, u, :] = WRIST_MM
    depth[100:140, 0:5, :] = 3000
    depth[0, 0, :] = np.arange(frames) + 1  # tells the frames apart
    return depth


def write_take(root: Path, a: int = 5, s: int = 1, t: int = 1, depth=None, skel=None) -> None:
    (root / "Depth").mkdir(parents=True, exist_ok=True)
    (root / "Skeleton").mkdir(parents=True, exist_ok=True)
    depth = _depth() if depth is None else depth
    skel = _skeleton(depth.shape[2]) if skel is None else skel
    scipy_io.savemat(root / "Depth" / f"a{a}_s{s}_t{t}_depth.mat", {"d_depth": depth})
    scipy_io.savemat(root / "Skeleton" / f"a{a}_s{s}_t{t}_skeleton.mat", {"d_skel": skel})


@pytest.fixture
def take(tmp_path) -> Path:
    write_take(tmp_path / "utd")
    return tmp_path / "utd"


def _import(src: Path, out: Path, *extra: str) -> int:
    return main(["--utd-mhad", str(src), "--out", str(out), "-q", *extra])


def test_intrinsics_golden():
    intr = utd.utd_intrinsics()
    assert (intr.width, intr.height, intr.fx, intr.fy) == (320, 240, 285.63, 285.63)
    # u = 319 - u_mirrored = 319 - (160 + f x / z) = 159 + f (-x) / z: cx is 159, not 160.
    assert (intr.cx, intr.cy) == (159.0, 120.0)


def test_a_joint_projects_onto_its_pixel_in_the_unmirrored_image(take, tmp_path):
    assert _import(take, tmp_path / "out") == 0
    rec = Recording(tmp_path / "out" / "a05_s1_t1")
    ref = rec.reference()
    wrist = ref["joints"][0, list(ref["joint_names"]).index("left_wrist")]
    np.testing.assert_allclose(wrist, [0.7, -0.4, Z], atol=1e-6)  # x, y negated; z kept
    uv = points_to_pixels(torch.as_tensor(wrist, dtype=torch.float64), rec.intrinsics)
    np.testing.assert_allclose(uv.numpy(), WRIST_PIXEL, atol=1e-3)
    depth = rec.read_depth_mm(0)
    u, v = WRIST_PIXEL
    assert depth[v, u] == WRIST_MM  # the blob drawn at the mirrored pixel is under the joint
    assert depth[v, u - 1] == 0 and depth[v, u + 1] == 0  # exactly there, not a pixel off
    assert (depth[100:140, 315:320] == 3000).all() and not depth[100:140, :5].any()


def test_round_trip(take, tmp_path):
    assert _import(take, tmp_path / "out", "--skeleton-lag", "0") == 0
    rec = Recording(tmp_path / "out" / "a05_s1_t1")
    assert len(rec) == T and rec.fps == 30.0 and not rec.has_groundtruth
    assert rec.meta["source"].startswith("UTD-MHAD a5_s1_t1")
    mirrored = _depth()
    for i in range(T):
        np.testing.assert_array_equal(rec.read_depth_mm(i), mirrored[:, ::-1, i])
    ref = rec.reference()
    assert str(ref["source"]).startswith("Kinect SDK v1 skeleton (another tracker); paired")
    assert tuple(ref["joint_names"]) == utd.KINECT_JOINTS
    expected = np.moveaxis(_skeleton(), 2, 0) * [-1, -1, 1]
    np.testing.assert_allclose(ref["joints"], expected, atol=1e-6)
    # The 1 cm/frame move to the mirrored image's right is a move to the camera's left.
    assert np.allclose(np.diff(ref["joints"][:, :, 0], axis=0), -0.01, atol=1e-6)
    joints, names = mapped_reference(ref)
    assert names == JOINT_NAMES  # every joint of ours has a counterpart
    np.testing.assert_allclose(joints[:, names.index("l_wrist")], expected[:, 6], atol=1e-6)
    unmapped = set(utd.KINECT_JOINTS) - {theirs for _, theirs in utd.JOINT_MAP}
    assert unmapped == {"left_hand", "right_hand", "left_foot", "right_foot"}


@pytest.mark.parametrize("lag", [1, utd.SKELETON_LAG_FRAMES])
def test_each_skeleton_meets_the_depth_frame_lag_later(take, tmp_path, lag):
    extra = () if lag == utd.SKELETON_LAG_FRAMES else ("--skeleton-lag", str(lag))
    assert _import(take, tmp_path / "out", *extra) == 0
    rec = Recording(tmp_path / "out" / "a05_s1_t1")
    assert len(rec) == T - lag  # the first `lag` depth frames have no skeleton of theirs
    stored = np.moveaxis(_skeleton(), 2, 0) * [-1, -1, 1]
    ref = rec.reference()
    for i in range(T - lag):
        assert rec.read_depth_mm(i)[0, -1] == i + lag + 1  # the stored frame i + lag (un-mirrored)
        np.testing.assert_allclose(ref["joints"][i], stored[i], atol=1e-6)
    assert f"depth frame {lag} later" in str(ref["source"])


def test_an_import_paired_otherwise_is_replaced(take, tmp_path, capsys):
    out = tmp_path / "out"
    assert _import(take, out, "--skeleton-lag", "0") == 0
    assert len(Recording(out / "a05_s1_t1")) == T
    capsys.readouterr()
    assert _import(take, out) == 0  # the default lag: the stale pairing is not kept
    assert len(Recording(out / "a05_s1_t1")) == T - utd.SKELETON_LAG_FRAMES
    assert "1 of them replaced an import paired otherwise" in capsys.readouterr().out
    assert _import(take, out) == 0  # the same pairing again: skipped
    assert "1 already there" in capsys.readouterr().out


def test_align_streams_golden_and_errors():
    depth, skel = np.arange(4)[:, None, None], np.arange(4)[:, None, None] * 10.0
    d, s = utd.align_streams(depth, skel, 1)
    assert d[:, 0, 0].tolist() == [1, 2, 3] and s[:, 0, 0].tolist() == [0.0, 10.0, 20.0]
    assert len(utd.align_streams(depth, skel, 0)[0]) == 4
    with pytest.raises(utd.UtdError, match="0 or more"):
        utd.align_streams(depth, skel, -1)
    with pytest.raises(utd.UtdError, match="none left"):
        utd.align_streams(depth, skel, 4)
    with pytest.raises(utd.UtdError, match="4 depth frames but 3"):
        utd.align_streams(depth, skel[:3], 1)


def test_filters_max_frames_and_reruns(tmp_path, capsys):
    src = tmp_path / "utd"
    for a, s, t in ((5, 1, 1), (5, 2, 1), (22, 1, 2)):
        write_take(src, a, s, t)
    out = tmp_path / "out"
    assert _import(src, out, "--actions", "5", "--subjects", "2", "--max-frames", "2") == 0
    assert [p.name for p in out.iterdir()] == ["a05_s2_t1"] and len(
        Recording(out / "a05_s2_t1")
    ) == 2
    assert _import(src, out) == 0
    assert sorted(p.name for p in out.iterdir()) == ["a05_s1_t1", "a05_s2_t1", "a22_s1_t2"]
    assert "2 recordings" in capsys.readouterr().out.splitlines()[-1]  # one was there already
    assert len(Recording(out / "a05_s2_t1")) == 2
    assert _import(src, out, "--subjects", "2", "--overwrite") == 0
    assert len(Recording(out / "a05_s2_t1")) == T - utd.SKELETON_LAG_FRAMES


def _expect_error(capsys, src, out, pattern, *extra):
    assert _import(src, out, *extra) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("error: ") and captured.err.count("\n") == 1, captured.err
    assert pattern in captured.err, captured.err
    assert "Traceback" not in captured.err


@pytest.mark.parametrize(
    "damage, pattern",
    [
        (lambda r: (r / "Skeleton" / "a5_s1_t1_skeleton.mat").unlink(), "missing"),
        (lambda r: (r / "Depth" / "a5_s1_t1_depth.mat").write_bytes(b""), "not a readable"),
        (lambda r: (r / "Depth" / "a5_s1_t1_depth.mat").write_text("x" * 300), "not a readable"),
        (
            lambda r: (r / "Skeleton" / "a5_s1_t1_skeleton.mat").write_bytes(
                (r / "Skeleton" / "a5_s1_t1_skeleton.mat").read_bytes()[:300]
            ),
            "not a readable",
        ),
        (
            lambda r: scipy_io.savemat(r / "Depth" / "a5_s1_t1_depth.mat", {"depth": _depth()}),
            "no variable 'd_depth'",
        ),
        (
            lambda r: scipy_io.savemat(
                r / "Depth" / "a5_s1_t1_depth.mat", {"d_depth": _depth().astype(np.float32)}
            ),
            "d_depth must be uint16 (240, 320, T)",
        ),
        (
            lambda r: scipy_io.savemat(
                r / "Skeleton" / "a5_s1_t1_skeleton.mat", {"d_skel": _skeleton()[:15]}
            ),
            "d_skel must be float (20, 3, T)",
        ),
        (lambda r: write_take(r, skel=_skeleton(T + 1)), "5 depth frames but 6 skeleton frames"),
        (lambda r: write_take(r, skel=_skeleton() * np.array([1, 1, -1])[:, None]), "z > 0"),
    ],
)
def test_malformed_takes_are_one_error_line_and_write_nothing(
    take, tmp_path, capsys, damage, pattern
):
    damage(take)
    _expect_error(capsys, take, tmp_path / "out", pattern)
    assert not (tmp_path / "out" / "a05_s1_t1").exists()


def test_bad_folders_and_filters(take, tmp_path, capsys):
    _expect_error(capsys, tmp_path / "nothing", tmp_path / "out", "no Depth/ subfolder")
    _expect_error(capsys, take, tmp_path / "out", "no take matches", "--actions", "99")
    _expect_error(capsys, take, tmp_path / "out", "--max-frames must be", "--max-frames", "0")
    _expect_error(capsys, take, tmp_path / "out", "--skeleton-lag must be", "--skeleton-lag", "-1")
    _expect_error(capsys, take, tmp_path / "out", "none left", "--skeleton-lag", str(T))
