"""The real-data benchmark: pooling by action (golden values), the worst and typical frames, the
contact sheet, and the command end to end with tracking replaced by a written result."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch
from depthmocap.runtime.export import ResultWriter
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, rest_pose
from depthmocap.shared.recording import RecordingWriter
from depthmocap.train.evaluation import depth_refutation as dr
from depthmocap.train.evaluation import metrics as m
from depthmocap.train.evaluation import overlay_sheet as sheet
from depthmocap.train.evaluation import real_benchmark as rb

NAMES = ("head", "l_wrist")


def _scored(name: str, errors_cm: list[list[float]], status=None, fps=10.0) -> rb.Scored:
    norm = np.asarray(errors_cm, dtype=np.float64) / 100
    status = status or {"tracked": len(norm), "detected": 0, "lost": 0}
    report = {"status_counts": status, "fps": fps}
    frame_mm = m.per_frame_error_mm(norm) + 10  # raw: 1 cm more than normalized
    return rb.Scored(name, name.split("_")[0], report, norm, frame_mm, NAMES)


def test_pooling_over_joint_estimates_and_frames_golden():
    a = _scored("a05_s1_t1", [[2, 4], [2, 30]], fps=10.0)
    b = _scored("a05_s2_t1", [[6, 8], [np.nan, np.nan]], {"tracked": 1, "detected": 0, "lost": 1},
                fps=20.0)  # fmt: skip
    p = rb.pooled([a, b])
    assert p["recordings"] == 2 and p["frames"] == 4
    assert p["normalized_mean_mm"] == pytest.approx(
        1e3 * (0.02 + 0.04 + 0.02 + 0.3 + 0.06 + 0.08) / 6
    )
    assert p["within_10cm_pct"] == pytest.approx(100 * 5 / 6)
    # Frame 1 of a (30 cm) and the frame without a pose fail: 2 of 4 frames.
    assert p["frames_beyond_20cm_pct"] == pytest.approx(50.0)
    assert p["lost_pct"] == pytest.approx(25.0) and p["detected_pct"] == 0.0
    assert p["fps"] == pytest.approx(4 / (2 / 10 + 2 / 20))  # frames over seconds, not a mean
    j = rb.per_joint([a, b])
    assert j["l_wrist"]["beyond_20cm_pct"] == pytest.approx(100 / 3)
    assert j["head"]["within_10cm_pct"] == 100.0


def test_observed_flags_leave_out_only_the_joints_called_inferred():
    a = _scored("a05_s1_t1", [[2, 30], [2, 30], [2, 4]])
    a.observed = np.array([[1.0, 0.0], [1.0, 1.0], [np.nan, np.nan]])  # the 30 cm wrist inferred
    b = _scored("a05_s2_t1", [[2, 30]])  # no flags at all: every joint counts
    p = rb.pooled([a, b])
    assert p["observed_joints_pct"] == pytest.approx(75.0)  # 3 of the 4 flagged joints
    # a: frame 1 (an observed wrist 30 cm off); b: its frame, unflagged: 2 of 4 frames.
    assert p["frames_beyond_20cm_observed_pct"] == pytest.approx(50.0)
    assert p["frames_beyond_20cm_pct"] == pytest.approx(75.0)
    assert rb.pooled([b])["observed_joints_pct"] is None
    assert "| 75.0% | 50.0% |" in rb.format_row("all", p)


def test_worst_and_typical_frames():
    a = _scored("a05_s1_t1", [[2, 4], [2, 30], [1, 20]])
    b = _scored("a05_s2_t1", [[6, 8], [np.nan, np.nan]])
    c = _scored("a22_s1_t1", [[3, 3], [5, 1], [9, 9]])
    worst = rb.worst_frames([a, b, c], 2)
    assert worst == [
        {"recording": "a05_s1_t1", "frame": 1, "joint": "l_wrist", "distance_mm": 300.0},
        {"recording": "a22_s1_t1", "frame": 2, "joint": "head", "distance_mm": 90.0},
    ]
    typical = rb.typical_frames([a, b, c])
    # a05's frame maxima: 4, 30, 20, 8 cm (and a frame without a pose): median 14, nearest 20.
    assert typical[0] == {"recording": "a05_s1_t1", "frame": 2, "joint": "l_wrist",
                          "distance_mm": pytest.approx(200.0)}  # fmt: skip
    assert typical[1] == {"recording": "a22_s1_t1", "frame": 1, "joint": "head",
                          "distance_mm": pytest.approx(50.0)}  # fmt: skip


def test_sheet_pieces():
    intr = Intrinsics(320, 240, 285.63, 285.63, 159.0, 120.0)
    px = sheet.project(np.array([[0.0, 0.0, 2.0], [0.5, -0.25, 2.0], [0, 0, -1.0]]), intr)
    np.testing.assert_allclose(px[:2], [[159.0, 120.0], [159 + 71.4075, 120 - 35.70375]])
    assert np.isnan(px[2]).all()  # behind the camera
    image = np.zeros((240, 320, 3), np.uint8)
    drawn = sheet.draw_reference(image, px[:2], ("pelvis", "neck"), "neck", px[:2])
    assert tuple(drawn[120, 159]) == sheet.REFERENCE_BGR and not image.any()
    crop = sheet.crop_around(drawn, np.array([[310.0, 230.0]]), (150, 200))
    assert crop.shape == (200, 150, 3)  # kept inside the image near its corner
    tile = sheet.caption(crop, ["line one", "line two"], 2)
    assert tile.shape == (400 + 32, 300, 3)
    assert sheet.tile_sheet([tile] * 3, 2).shape == (2 * 432 + 2, 2 * 300 + 2, 3)


def test_depth_refutation():
    """Off the person (beyond the slack) or in the empty space in front of the surface the
    camera sees: refuted. Inside or just behind the surface, within the slack of a small
    near part, outside the image: not."""
    intr = Intrinsics(320, 240, 285.63, 285.63, 159.0, 120.0)
    depth = np.zeros((240, 320), np.float32)
    depth[100:140, 150:170] = 2.0  # columns 150-169 at 2 m
    depth[120, 150] = 1.7  # one pixel of a hand in front

    def at(u, v, z=2.05):
        return [(u - 159.0) * z / 285.63, (v - 120.0) * z / 285.63, z]

    joints = np.array([
        at(160, 110),  # inside the body
        at(172, 110),  # 3 px off the edge: within the slack
        at(173, 110),  # 4 px off
        at(160, 110, 1.85),  # 15 cm in front of the surface: empty space
        at(160, 110, 1.95),  # 5 cm in front: within the margin
        at(152, 121, 1.75),  # in front of the torso but at the hand (2 px away)
        at(171, 130, 1.5),  # in front, but at a pixel without depth: a hole proves nothing
        at(400, 110),  # outside the image: cannot be checked
        [0.0, 0.0, -1.0],  # behind the camera
        [np.nan, 0.0, 2.0],
    ])  # fmt: skip
    got = dr.refuted(depth, joints, intr)
    assert got.tolist() == [False, False, True, True, False, False, False, False, True, True]
    assert [dr.classify(r, o) for r, o in ((0, 0), (1, 0), (0, 1), (1, 1))] == list(dr.SIDES)


FRAMES = 6
CAM = Intrinsics(320, 240, 285.63, 285.63, 159.0, 120.0)


def _write_take(root, name: str, wrist_off: float):
    """A recording with a reference skeleton (our joints, the left wrist ``wrist_off`` m off
    in frame 3) and a tracked result with overlays, as runtime-track would leave them."""
    q = rest_pose(FRAMES, root_position=(0.0, 0.1, 2.8), dtype=torch.float64).numpy()
    joints = named_joint_positions(
        forward_kinematics(torch.as_tensor(q), BodyShape.default(torch.float64))
    ).numpy()
    reference = joints.copy()
    reference[3, sk.JOINT_NAMES.index("l_wrist"), 2] += wrist_off
    with RecordingWriter(root / "data" / name, CAM, fps=30.0, source="test") as w:
        for _ in range(FRAMES):
            w.write_frame(np.full((CAM.height, CAM.width), 2800, np.uint16))
        w.write_reference(reference, sk.JOINT_NAMES, "Test tracker (another tracker)",
                          [(n, n) for n in sk.JOINT_NAMES])  # fmt: skip
    result = root / "out" / "results" / name
    with ResultWriter(result, BodyShape.default(), 30.0, CAM, "hybrid", "test") as w:
        for i in range(FRAMES):
            w.write_frame(i, i / 30, "tracked", joints[i], q[i], {})
    (result / "overlays").mkdir()
    for i in range(FRAMES):
        cv2.imwrite(str(result / "overlays" / f"{i:06d}.png"), np.zeros((240, 320, 3), np.uint8))


def test_benchmark_end_to_end_without_tracking(tmp_path, monkeypatch, capsys):
    _write_take(tmp_path, "a05_s1_t1", -0.6)  # the reference's wrist in the empty space
    _write_take(tmp_path, "a22_s1_t1", 0.0)
    monkeypatch.setattr(rb, "_track", lambda *a: pytest.fail("complete results are reused"))
    args = ["--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"),
            "--typical-sheet", str(tmp_path / "typical.png")]  # fmt: skip
    assert rb.main(args) == 0
    printed = capsys.readouterr().out
    assert "not ground truth" in printed and "| a05 throw | 1 | 6 |" in printed
    assert "| a22 jog in place | 1 | 6 |" in printed and "| **all** | 2 | 12 |" in printed
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["all"]["frames_beyond_20cm_pct"] == pytest.approx(100 / 12)
    # The whole image is "body" at 2.8 m: the reference's wrist 60 cm in front of it is in
    # the space the camera sees to be empty; left out, no frame fails.
    everything = report["all"]
    assert everything["beyond_20cm_frames_by_side"]["reference_refuted"] == 1
    assert everything["reference_refuted_joints_pct"] == pytest.approx(100 / (12 * 16))
    assert everything["ours_refuted_joints_pct"] == 0.0
    assert everything["frames_beyond_20cm_pct_reference_not_refuted"] == 0.0
    assert everything["normalized_mean_mm_reference_not_refuted"] < everything["normalized_mean_mm"]
    assert "| **all** | 1 | 100.0% | 0.0% | 0.0% | 0.0% | 0.5% | 0.0% |" in printed
    worst = report["worst_frames"][0]
    assert (worst["recording"], worst["frame"], worst["joint"]) == ("a05_s1_t1", 3, "l_wrist")
    assert worst["distance_mm"] == pytest.approx(500.0)
    assert set(report["per_recording"]) == {"a05_s1_t1", "a22_s1_t1"}
    image = cv2.imread(str(tmp_path / "out" / "worst_frames.png"))
    assert image is not None and image.shape[1] == 6 * 300 + 5 * 2
    assert cv2.imread(str(tmp_path / "typical.png")) is not None


def test_no_recordings_is_an_error(tmp_path, capsys):
    assert rb.main(["--data", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.startswith("error: ")


def test_track_passes_settings_to_runtime_track(tmp_path, monkeypatch):
    """``--config`` reaches runtime-track (an A/B of settings on real data); without it the
    shipped preset runs untouched."""
    seen = []
    monkeypatch.setattr(rb, "run_command", seen.append)
    rb._track(tmp_path / "rec", tmp_path / "res", 1, None)
    rb._track(tmp_path / "rec", tmp_path / "res", 1, "cpu", tmp_path / "ab.yaml")
    assert "--config" not in seen[0]
    cmd = seen[1]
    assert cmd[cmd.index("--config") + 1] == str(tmp_path / "ab.yaml")
    assert cmd[cmd.index("--device") + 1] == "cpu"
    assert "--model" not in cmd
    rb._track(tmp_path / "rec", tmp_path / "res", 1, None, None, tmp_path / "f.npz")
    assert seen[2][seen[2].index("--model") + 1] == str(tmp_path / "f.npz")


def test_another_forest_is_recorded_by_its_hash(tmp_path, capsys):
    """Results tracked with another forest are not reused for the shipped one, nor for a forest
    rewritten under the same name."""
    out, data = tmp_path / "out", tmp_path / "data"
    args = ["--data", str(data), "--out", str(out)]
    assert rb.main([*args, "--model", str(tmp_path / "none.npz")]) == 2
    assert "--model: no such file" in capsys.readouterr().err
    forest = tmp_path / "f.npz"
    forest.write_bytes(b"one")
    assert rb.main([*args, "--model", str(forest)]) == 2  # no recordings; settings recorded
    assert "sha256" in (out / "settings.yaml").read_text()
    (out / "results").mkdir()
    assert rb.main([*args, "--model", str(forest)]) == 2
    assert "no recording" in capsys.readouterr().err  # the same forest: reused
    forest.write_bytes(b"two")
    assert rb.main([*args, "--model", str(forest)]) == 2
    assert "other settings" in capsys.readouterr().err
    assert rb.main(args) == 2
    assert "other settings" in capsys.readouterr().err


def test_settings_are_recorded_and_never_mixed(tmp_path, capsys):
    """A missing --config is a clear error before anything runs; results tracked with other
    settings in the same --out are not reused silently (an A/B would mix them)."""
    out, data = tmp_path / "out", tmp_path / "data"
    args = ["--data", str(data), "--out", str(out)]
    assert rb.main([*args, "--config", str(tmp_path / "none.yaml")]) == 2
    assert "no such file" in capsys.readouterr().err
    (out / "results").mkdir(parents=True)  # results of the shipped preset
    ab = tmp_path / "ab.yaml"
    ab.write_text("tracker:\n  iterations: 3\n")
    assert rb.main([*args, "--config", str(ab)]) == 2
    assert "other settings" in capsys.readouterr().err
    assert not (out / "settings.yaml").exists()
    # --retrack tracks afresh with the new settings and records them (no recordings here)
    assert rb.main([*args, "--config", str(ab), "--retrack"]) == 2
    assert "no recording" in capsys.readouterr().err
    assert (out / "settings.yaml").read_text() == ab.read_text()
    assert rb.main(args) == 2  # back to the shipped preset: refused again
    assert "other settings" in capsys.readouterr().err


def test_sides_and_refuted_frames_read_the_worst_joint():
    a = _scored("a05_s1_t1", [[2, 4], [2, 30], [1, 25], [np.nan, np.nan]])
    a.reference_refuted = np.array([[0, 1], [0, 1], [1, 0], [0, 0]], bool)
    b = _scored("a05_s2_t1", [[40, 1], [3, 3]])
    b.reference_refuted = np.array([[1, 0], [0, 0]], bool)
    b.ours_refuted = np.array([[1, 0], [0, 0]], bool)
    # a: frame 1's worst joint (the wrist) is the reference's refuted one; frame 2's is not
    # (its head is); the frame without a pose has no worst joint. b: both refuted.
    assert a.sides(0.2) == {"neither_refuted": 1, "reference_refuted": 1, "ours_refuted": 0,
                            "both_refuted": 0}  # fmt: skip
    assert b.sides(0.2)["both_refuted"] == 1
    assert rb.refuted_frames([a, b], 5, 0.2) == [
        {"recording": "a05_s1_t1", "frame": 1, "joint": "l_wrist", "distance_mm": 300.0}
    ]
    p = rb.pooled([a, b])
    assert p["reference_refuted_joints_pct"] == pytest.approx(100 * 4 / 10)
    assert p["ours_refuted_joints_pct"] == pytest.approx(100 * 1 / 10)
    # Left out: a's frames 0-2 lose one joint each (frame 2 its head, so its 25 cm wrist
    # still fails), b's frame 0 its head; a's frame without a pose still fails: 2 of 6.
    assert p["frames_beyond_20cm_pct_reference_not_refuted"] == pytest.approx(100 * 2 / 6)
    kept_cm = (2 + 2 + 25 + 1 + 3 + 3) / 6
    assert p["normalized_mean_mm_reference_not_refuted"] == pytest.approx(10 * kept_cm)
