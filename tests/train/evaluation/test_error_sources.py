"""Where the gross errors are (train.evaluation.error_sources): each place of a joint against a
hand-made depth image, the pooled table's shares (golden values), and a recording with a
result end to end through the command."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from depthmocap.runtime.export import ResultWriter
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, rest_pose
from depthmocap.shared.recording import RecordingWriter
from depthmocap.train.evaluation import error_sources as es

# 20 x 20 pixels, u = 10 x / z + 10: the person a 10 x 10 block at 2 m (pixels 5-14).
SMALL = Intrinsics(fx=10.0, fy=10.0, cx=10.0, cy=10.0, width=20, height=20)


def _block() -> np.ndarray:
    depth = np.zeros((20, 20))
    depth[5:15, 5:15] = 2.0
    depth[9, 9] = 0.0  # a hole
    return depth


def _at(u: float, v: float, z: float) -> list[float]:
    """The camera-frame point at pixel (u, v) and depth z."""
    return [(u - 10.0) * z / 10.0, (v - 10.0) * z / 10.0, z]


def test_joint_places_golden():
    joints = np.array(
        [
            _at(30.0, 10.0, 2.0),  # beyond the image's right edge
            _at(1.0, 10.0, 2.0),  # 4 px left of the block: off the body
            _at(12.0, 12.0, 1.8),  # 20 cm in front of the surface
            _at(12.0, 12.0, 2.05),  # just behind it: on the surface
            _at(12.0, 12.0, 2.3),  # 30 cm behind it: hidden
            _at(9.0, 9.0, 1.5),  # in front, but at a hole: proves nothing
            _at(3.0, 10.0, 2.0),  # 2 px off the block: within the slack
            [0.0, 0.0, -1.0],  # behind the camera
            [np.nan, 0.0, 2.0],  # missing
        ]
    )
    got = es.joint_places(_block(), joints, SMALL)
    want = ["outside", "off_body", "in_front", "on_surface", "hidden", "on_surface",
            "on_surface", "outside", "outside"]  # fmt: skip
    assert [es.PLACES[k] for k in got] == want


def test_gross_error_table_golden():
    run = {
        "error": np.array([[0.05, 0.30], [0.50, np.nan]]),
        "ours": np.array([[3, 3], [4, 0]]),
        "truth": np.array([[3, 4], [4, 0]]),
    }
    other = {"error": np.array([[0.25]]), "ours": np.array([[3]]), "truth": np.array([[4]])}
    rows = es.gross_error_table([run, other], threshold_m=0.2)
    total = 0.05 + 0.30 + 0.50 + 0.25
    assert [(r["ours"], r["truth"]) for r in rows] == [
        ("on_surface", "hidden"),
        ("hidden", "hidden"),
        ("all gross", ""),
    ]
    assert rows[0]["joints_pct"] == pytest.approx(50.0)  # 2 of the 4 estimates
    assert rows[0]["error_pct"] == pytest.approx(100 * 0.55 / total)
    assert rows[0]["mean_mm"] == pytest.approx(275.0)
    assert rows[1]["error_pct"] == pytest.approx(100 * 0.50 / total)
    assert rows[2]["joints_pct"] == pytest.approx(75.0)
    assert rows[2]["error_pct"] == pytest.approx(100 * 1.05 / total)
    assert "| on_surface | hidden | 50.0% |" in es.format_table(rows)
    assert es.gross_error_table([{**other, "error": np.array([[0.1]])}]) == []


CAM = Intrinsics.kinect_v1(160)


def _joints(q: torch.Tensor, body: BodyShape) -> np.ndarray:
    return named_joint_positions(forward_kinematics(q, body)).numpy()


def test_a_recording_end_to_end(tmp_path, capsys):
    """A person-sized block standing 2.5 m away with its floor (labels 0) in the depth, the
    truth a rest pose inside it; ours moves the left wrist 40 cm towards the camera and the
    right one 40 cm away: in front, and hidden, and the floor is not the person."""
    body = BodyShape.default(torch.float64)
    q = rest_pose(3, root_position=(0.0, 0.1, 2.5), dtype=torch.float64)
    truth = _joints(q, body)
    depth = np.full((CAM.height, CAM.width), 4000, np.uint16)  # the floor, far behind
    labels = np.zeros((CAM.height, CAM.width), np.uint8)
    u = CAM.fx * truth[0, :, 0] / truth[0, :, 2] + CAM.cx
    v = CAM.fy * truth[0, :, 1] / truth[0, :, 2] + CAM.cy
    u0, u1 = int(u.min()) - 3, int(u.max()) + 4
    v0, v1 = int(v.min()) - 3, int(v.max()) + 4
    depth[v0:v1, u0:u1] = 2450  # the body's surface, in front of its joints
    labels[v0:v1, u0:u1] = 1
    rec = tmp_path / "rec"
    with RecordingWriter(rec, CAM, fps=30.0, source="test") as w:
        for _ in range(3):
            w.write_frame(depth, labels)
        w.write_groundtruth(truth, sk.JOINT_NAMES, q=q.numpy())
    ours = truth.copy()
    left, right = sk.JOINT_NAMES.index("l_wrist"), sk.JOINT_NAMES.index("r_wrist")
    ours[:, left, 2] -= 0.4
    ours[:, right, 2] += 0.4
    res = tmp_path / "res"
    with ResultWriter(res, body, 30.0, CAM, "hybrid", "test") as w:
        for i in range(3):
            w.write_frame(i, i / 30, "tracked", ours[i], q[i].numpy(), {})
    places = es.recording_places(rec, res)
    assert places["error"].shape == (3, len(sk.JOINT_NAMES))
    assert [es.PLACES[k] for k in places["ours"][0, [left, right]]] == ["in_front", "hidden"]
    assert bool((places["truth"][:, [left, right]] == es.ON_SURFACE).all())
    out = tmp_path / "out"
    out.mkdir()
    entry = {"recording": str(rec), "result": str(res)}
    report = {"hybrid, default body": {"per_recording": {"rec": entry}}}
    (out / "report.json").write_text(json.dumps(report))
    assert es.main([str(out)]) == 0
    text = capsys.readouterr().out
    assert "| in_front | on_surface |" in text and "| hidden | on_surface |" in text
    assert "| all gross |  | 12.5% |" in text  # 2 of the 16 joints
    assert es.main([str(tmp_path)]) == 2  # no report.json there: said, not a traceback
    assert "no report.json" in capsys.readouterr().err
