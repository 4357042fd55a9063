"""bench.segmentation_accuracy on a tiny rendered recording with labels."""

from __future__ import annotations

import numpy as np
from depthmocap.bench.segmentation_accuracy import main, mask_iou, segmentation_misses
from depthmocap.runtime.raycast import part_labels, render_body
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import rest_pose
from depthmocap.shared.recording import Recording, RecordingWriter

INTR = Intrinsics.kinect_v1(320)


def test_mask_iou_golden():
    a = np.zeros((4, 4), bool)
    b = a.copy()
    assert mask_iou(a, b) == 1.0
    a[0, :2] = True
    b[0, 1:3] = True
    assert mask_iou(a, b) == 1 / 3


def test_a_rendered_person_is_found_and_an_empty_frame_not_counted(tmp_path, capsys):
    body = BodyShape.default()
    render = render_body(rest_pose(1, (0.0, 0.0, 2.5)), body, INTR)
    depth = (render.depth[0].numpy() * 1000).round().astype(np.uint16)
    labels = part_labels(render, body)[0].numpy().astype(np.uint8)
    path = tmp_path / "recs" / "person"
    with RecordingWriter(path, INTR) as w:
        w.write_frame(depth, labels)
        w.write_frame(np.zeros_like(depth), np.zeros_like(labels))  # nobody
        w.write_frame(depth, labels)
    r = segmentation_misses(Recording(path))
    assert r["in_view"].tolist() == [True, False, True]
    assert (r["stream"][r["in_view"]] > 0.95).all() and (r["single"][r["in_view"]] > 0.95).all()
    assert main(["--recordings", str(tmp_path / "recs")]) == 0
    out = capsys.readouterr().out
    assert "2 frames with the person in view (1 without" in out
    assert "stream 0 frames (0.00%)" in out
    assert main(["--recordings", str(tmp_path)]) == 2  # no recordings directly in it


def test_settings_from_yaml_and_bad_ones(tmp_path, capsys):
    body = BodyShape.default()
    render = render_body(rest_pose(1, (0.0, 0.0, 2.5)), body, INTR)
    path = tmp_path / "recs" / "person"
    with RecordingWriter(path, INTR) as w:
        w.write_frame(
            (render.depth[0].numpy() * 1000).round().astype(np.uint16),
            part_labels(render, body)[0].numpy().astype(np.uint8),
        )
    good = tmp_path / "largest.yaml"
    good.write_text("convex_weight: 1.0\n")
    assert main(["--recordings", str(tmp_path / "recs"), "--segmentation-config", str(good)]) == 0
    bad = tmp_path / "bad.yaml"
    bad.write_text("no_such_key: 1\n")
    assert main(["--recordings", str(tmp_path / "recs"), "--segmentation-config", str(bad)]) == 2
    assert "no_such_key" in capsys.readouterr().err


def test_every_must_be_positive(tmp_path):
    import pytest

    with pytest.raises(SystemExit) as err:
        main(["--recordings", str(tmp_path), "--every", "0"])
    assert err.value.code == 2
