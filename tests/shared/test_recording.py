import json

import numpy as np
import pytest
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.recording import (
    Recording,
    RecordingError,
    RecordingWriter,
    mapped_reference,
)


def make_recording(path, frames=3, labels=True, gt=True):
    intr = Intrinsics.kinect_v1(160)
    rng = np.random.default_rng(0)
    depth = rng.integers(0, 5000, size=(frames, 120, 160), dtype=np.uint16)
    lab = rng.integers(0, 20, size=(frames, 120, 160), dtype=np.uint8)
    with RecordingWriter(path, intr, fps=30.0, source="test") as w:
        for i in range(frames):
            w.write_frame(depth[i], lab[i] if labels else None)
        if gt:
            w.write_groundtruth(np.ones((frames, 2, 3)), ["a", "b"], q=np.zeros((frames, 34)))
    return depth, lab


def test_round_trip(tmp_path):
    depth, lab = make_recording(tmp_path / "rec")
    rec = Recording(tmp_path / "rec")
    assert len(rec) == 3 and rec.fps == 30.0 and rec.intrinsics == Intrinsics.kinect_v1(160)
    for i in range(3):
        np.testing.assert_array_equal(rec.read_depth_mm(i), depth[i])
        np.testing.assert_array_equal(rec.read_labels(i), lab[i])
        np.testing.assert_allclose(rec.read_depth(i), depth[i] / 1000.0, rtol=1e-6)
    gt = rec.groundtruth()
    assert gt["joints"].shape == (3, 2, 3) and list(gt["joint_names"]) == ["a", "b"]


def test_interrupted_writer_leaves_readable_prefix(tmp_path):
    intr = Intrinsics.kinect_v1(160)
    w = RecordingWriter(tmp_path / "rec", intr)
    w.write_frame(np.full((120, 160), 1000, np.uint16))
    w.write_frame(np.full((120, 160), 2000, np.uint16))
    # no close(): as if the process was killed
    rec = Recording(tmp_path / "rec")
    assert len(rec) == 2 and rec.read_depth_mm(1)[0, 0] == 2000


def _edit_meta(path, **changes):
    meta = json.loads((path / "meta.json").read_text())
    meta.update(changes)
    (path / "meta.json").write_text(json.dumps(meta))


@pytest.mark.parametrize(
    "change, message",
    [
        ({"format": "x"}, "not a recording"),
        ({"version": 7}, "version 7 is not supported"),
        ({"width": "wide"}, "'width' has the wrong type"),
        ({"fps": 0}, "must be positive"),
        ({"frame_count": 9}, "lists 9 frames but 000008.png is missing"),
        ({"fx": -3.0}, "focal lengths must be positive"),
    ],
)
def test_malformed_meta(tmp_path, change, message):
    make_recording(tmp_path / "rec", gt=False)
    _edit_meta(tmp_path / "rec", **change)
    with pytest.raises(RecordingError, match=message):
        Recording(tmp_path / "rec")


def test_missing_and_broken_files(tmp_path):
    with pytest.raises(RecordingError, match="no such recording"):
        Recording(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(RecordingError, match="no meta.json"):
        Recording(tmp_path / "empty")
    make_recording(tmp_path / "rec")
    (tmp_path / "rec" / "meta.json").write_text("{not json")
    with pytest.raises(RecordingError, match="not valid JSON"):
        Recording(tmp_path / "rec")


def test_corrupt_and_wrong_size_frames(tmp_path):
    make_recording(tmp_path / "rec")
    rec_path = tmp_path / "rec"
    (rec_path / "depth" / "000001.png").write_bytes(b"garbage")
    rec = Recording(rec_path)
    with pytest.raises(RecordingError, match="000001.png: not a readable PNG"):
        rec.read_depth(1)
    _edit_meta(rec_path, width=320, height=240, cx=159.5, cy=119.5, fx=287.9, fy=287.9)
    with pytest.raises(RecordingError, match="frame is 160x120 but meta.json says 320x240"):
        Recording(rec_path).read_depth(0)
    with pytest.raises(RecordingError, match="expected a single-channel uint16"):
        import cv2

        cv2.imwrite(str(rec_path / "depth" / "000002.png"), np.zeros((120, 160), np.uint8))
        Recording(rec_path).read_depth(2)


def test_groundtruth_errors(tmp_path):
    make_recording(tmp_path / "rec", gt=False)
    rec = Recording(tmp_path / "rec")
    with pytest.raises(RecordingError, match="no ground truth"):
        rec.groundtruth()
    np.savez(
        tmp_path / "rec" / "groundtruth.npz",
        joints=np.zeros((2, 2, 3)),
        joint_names=np.array(["a", "b"]),
    )
    with pytest.raises(
        RecordingError, match=r"joints have shape \(2, 2, 3\), expected \(3, 2, 3\)"
    ):
        Recording(tmp_path / "rec").groundtruth()


def test_writer_rejects_bad_frames(tmp_path):
    w = RecordingWriter(tmp_path / "rec", Intrinsics.kinect_v1(160))
    with pytest.raises(ValueError, match="depth frame must be uint16"):
        w.write_frame(np.zeros((120, 160), np.float32))
    with pytest.raises(ValueError, match="depth frame must be uint16"):
        w.write_frame(np.zeros((240, 320), np.uint16))
    with pytest.raises(FileExistsError):
        RecordingWriter(tmp_path / "rec", Intrinsics.kinect_v1(160))


# --- reference skeleton (another tracker's joints, kept apart from ground truth) -------------
REF_NAMES = ["top", "middle", "hand"]
REF_MAP = [("head", "top"), ("spine", "middle")]


def _write_reference(path, frames=3):
    joints = np.arange(frames * 3 * 3, dtype=np.float64).reshape(frames, 3, 3) / 10 + 1
    with RecordingWriter(path, Intrinsics.kinect_v1(160)) as w:
        for _ in range(frames):
            w.write_frame(np.zeros((120, 160), np.uint16))
        w.write_reference(joints, REF_NAMES, "another tracker", REF_MAP)
    return joints


def test_reference_round_trip_and_mapping(tmp_path):
    joints = _write_reference(tmp_path / "rec")
    rec = Recording(tmp_path / "rec")
    assert rec.has_reference and not rec.has_groundtruth
    ref = rec.reference()
    assert list(ref["joint_names"]) == REF_NAMES and str(ref["source"]) == "another tracker"
    np.testing.assert_allclose(ref["joints"], joints, rtol=1e-6)
    mapped, names = mapped_reference(ref)
    assert names == ("head", "spine") and mapped.shape == (3, 2, 3)
    np.testing.assert_allclose(mapped, joints[:, [0, 1]], rtol=1e-6)  # the hand is left out


@pytest.mark.parametrize(
    "change, message",
    [
        ({"joints": np.zeros((2, 3, 3))}, r"joints have shape \(2, 3, 3\), expected \(3, 3, 3\)"),
        ({"joint_map": np.array([["head", "nose"]])}, "does not have: nose"),
        ({"joint_map": np.array([["head", "top"], ["head", "middle"]])}, "twice"),
        ({"joint_map": np.array(["head"])}, r"\(M, 2\)"),
        ({"joint_names": np.array([1, 2, 3])}, "must be text"),
        ({"source": None}, "needs 'source'"),
    ],
)
def test_reference_errors(tmp_path, change, message):
    _write_reference(tmp_path / "rec")
    path = tmp_path / "rec" / "reference.npz"
    with np.load(path) as data:
        contents = {k: data[k] for k in data.files}
    contents.update(change)
    np.savez(path, **{k: v for k, v in contents.items() if v is not None})
    with pytest.raises(RecordingError, match=message):
        Recording(tmp_path / "rec").reference()


def test_reference_missing_or_unreadable(tmp_path):
    make_recording(tmp_path / "rec", labels=False, gt=False)
    with pytest.raises(RecordingError, match="no reference"):
        Recording(tmp_path / "rec").reference()
    (tmp_path / "rec" / "reference.npz").write_bytes(b"PK\x03\x04 cut off")
    with pytest.raises(RecordingError, match="reference.npz: unreadable"):
        Recording(tmp_path / "rec").reference()


def test_writer_rejects_bad_references(tmp_path):
    w = RecordingWriter(tmp_path / "rec", Intrinsics.kinect_v1(160))
    w.write_frame(np.zeros((120, 160), np.uint16))
    with pytest.raises(ValueError, match="reference has 2 frames, recording has 1"):
        w.write_reference(np.zeros((2, 3, 3)), REF_NAMES, "t", REF_MAP)
    with pytest.raises(ValueError, match="does not have: nose"):
        w.write_reference(np.zeros((1, 3, 3)), REF_NAMES, "t", [("head", "nose")])
    assert not (tmp_path / "rec" / "reference.npz").exists()
