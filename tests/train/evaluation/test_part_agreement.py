"""The forest's parts against parts drawn from a skeleton (train.evaluation.part_agreement):
the grouping, the drawing on bone surfaces in both joint vocabularies, and a whole run on a tiny
rendered-like recording with a one-leaf forest."""

from __future__ import annotations

import json

import numpy as np
import pytest
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.forest_format import Forest, save_forest
from depthmocap.shared.labels import PART_NAMES
from depthmocap.shared.recording import RecordingWriter
from depthmocap.train.evaluation import part_agreement as pa
from depthmocap.train.importers.utd_mhad import KINECT_JOINTS

TORSO, L_FOREARM = pa.PART_GROUPS.index("torso"), pa.PART_GROUPS.index("l_forearm")


def test_every_part_has_a_group_and_sides_stay_apart():
    assert pa.PART_GROUP[0] == -1 and np.all(pa.PART_GROUP[1:] >= 0)
    for p, name in enumerate(PART_NAMES[1:], start=1):
        group = pa.PART_GROUPS[pa.PART_GROUP[p]]
        if name.startswith(("l_", "r_")) and group != "torso":
            assert group.startswith(name[:2]), (name, group)
    assert pa.PART_GROUPS[pa.PART_GROUP[PART_NAMES.index("r_shank_lower")]] == "r_shank"
    assert pa.PART_GROUPS[pa.PART_GROUP[PART_NAMES.index("l_clavicle")]] == "torso"


def _our_skeleton() -> dict[str, np.ndarray]:
    """A standing person 2 m away (camera frame: y down), arms out to the sides."""
    j = {
        "pelvis": (0, 0.0, 2.11), "spine": (0, -0.2, 2.11), "neck": (0, -0.5, 2.11),
        "head": (0, -0.7, 2.11), "l_shoulder": (0.2, -0.45, 2.11),
        "r_shoulder": (-0.2, -0.45, 2.11),
        "l_elbow": (0.5, -0.45, 2.11), "r_elbow": (-0.5, -0.45, 2.11),
        "l_wrist": (0.75, -0.45, 2.11), "r_wrist": (-0.75, -0.45, 2.11),
        "l_hip": (0.1, 0.05, 2.11), "r_hip": (-0.1, 0.05, 2.11), "l_knee": (0.12, 0.45, 2.11),
        "r_knee": (-0.12, 0.45, 2.11), "l_ankle": (0.12, 0.85, 2.11),
        "r_ankle": (-0.12, 0.85, 2.11),
    }  # fmt: skip
    return {k: np.array(v, float) for k, v in j.items()}


def test_points_on_a_bone_surface_take_its_group():
    j = _our_skeleton()
    names = list(sk.JOINT_NAMES)
    a, b, group = pa.skeleton_bones(np.stack([j[n] for n in names]), names)
    # 3.5 cm in front of the left forearm's middle; 11 cm in front of the spine; halfway.
    fore = 0.5 * (j["l_elbow"] + j["l_wrist"]) - [0, 0, 0.035]
    torso = j["spine"] - [0, 0, 0.11]
    points = np.stack([fore, torso, 0.5 * (fore + torso)])
    drawn, confident = pa.groups_from_bones(points, a, b, group)
    assert list(drawn[:2]) == [L_FOREARM, TORSO]
    assert list(confident) == [True, True, False]
    # Past the wrist lies our made-up hand: still the forearm.
    hand = j["l_wrist"] + [0.05, 0, -0.035]
    assert pa.groups_from_bones(hand[None], a, b, group)[0][0] == L_FOREARM


def test_the_kinect_sdk_vocabulary_and_a_missing_joint():
    rng = np.random.default_rng(0)
    a, b, group = pa.skeleton_bones(rng.normal(size=(20, 3)), KINECT_JOINTS)
    assert len(a) == len(b) == len(group) == 7 + 2 * 6  # feet and hands extend the limbs
    assert set(group) == set(range(len(pa.PART_GROUPS)))
    with pytest.raises(ValueError, match="lacks joints"):
        pa.skeleton_bones(np.zeros((3, 3)), ["pelvis", "spine", "neck"])


def test_agreement_reads_rows_as_the_drawn_group():
    c = np.zeros((10, 10), int)
    c[TORSO, TORSO], c[TORSO, L_FOREARM], c[L_FOREARM, L_FOREARM] = 3, 1, 4
    r = pa.agreement(c)
    assert r["pixels"] == 8 and r["overall"] == pytest.approx(7 / 8)
    assert r["per_group"]["torso"] == pytest.approx(0.75) and r["per_group"]["l_forearm"] == 1.0
    assert r["per_group"]["head"] is None


def _one_leaf_forest(part: str, intr: Intrinsics) -> Forest:
    dist = np.zeros((1, len(PART_NAMES)), np.float16)
    dist[0, PART_NAMES.index(part)] = 1
    return Forest(
        u=np.zeros((1, 2), np.float32), v=np.zeros((1, 2), np.float32),
        threshold=np.zeros(1, np.float32), left=np.array([-1]), right=np.array([-1]),
        leaf=np.array([0]), leaf_dist=dist, roots=np.array([0]), class_names=PART_NAMES,
        camera=intr.as_dict(),
    )  # fmt: skip


def test_a_run_on_a_labelled_recording(tmp_path, capsys):
    """A flat front 2 m away over the spine, labelled chest: the drawing calls it torso, and a
    forest that says chest everywhere agrees on all of it."""
    intr = Intrinsics.kinect_v1(160)
    j = _our_skeleton()
    depth = np.zeros((intr.height, intr.width), np.uint16)
    labels = np.zeros(depth.shape, np.uint8)
    # Columns within 4 cm of x = 0 at 2 m, rows from 10 to 40 cm above the pelvis.
    u0, u1 = int(intr.cx - 0.04 * intr.fx / 2), int(intr.cx + 0.04 * intr.fx / 2)
    v0, v1 = int(intr.cy - 0.4 * intr.fy / 2), int(intr.cy - 0.1 * intr.fy / 2)
    depth[v0:v1, u0:u1], labels[v0:v1, u0:u1] = 2000, PART_NAMES.index("chest")
    with RecordingWriter(tmp_path / "data" / "rec", intr, fps=30.0, source="test") as w:
        for _ in range(2):
            w.write_frame(depth, labels)
        joints = np.stack([j[n] for n in sk.JOINT_NAMES])
        w.write_groundtruth(np.stack([joints, joints]), list(sk.JOINT_NAMES), q=np.zeros((2, 34)))
    chest, head = tmp_path / "chest.npz", tmp_path / "head.npz"
    save_forest(chest, _one_leaf_forest("chest", intr))
    save_forest(head, _one_leaf_forest("head", intr))
    out = tmp_path / "agreement.json"
    args = ["--data", str(tmp_path / "data"), "--every", "1", "--out", str(out)]
    assert pa.main([*args, "--model", str(chest), "--model", str(head)]) == 0
    report = json.loads(out.read_text())
    pixels = 2 * (v1 - v0) * (u1 - u0)
    mine = report[str(chest)]
    assert mine["forest"]["pixels"] == pixels and mine["forest"]["per_group"]["torso"] == 1.0
    assert mine["drawn_vs_labels"]["overall"] == 1.0
    assert report[str(head)]["forest"]["overall"] == 0.0
    assert "chest.npz" in capsys.readouterr().out
    # A skeleton far from every pixel: nothing counted, a row of dashes rather than a crash.
    far = tmp_path / "far"
    with RecordingWriter(far / "rec", intr, fps=30.0, source="test") as w:
        w.write_frame(depth, labels)
        w.write_groundtruth(joints[None] + [5.0, 0, 0], list(sk.JOINT_NAMES), q=np.zeros((1, 34)))
    assert pa.main(["--data", str(far), "--model", str(chest), "--out", str(out)]) == 0
    assert json.loads(out.read_text())[str(chest)]["forest"]["overall"] is None
    # Bad input: clear errors, no traceback.
    assert pa.main(["--data", str(tmp_path / "none")]) == 2
    assert pa.main([*args, "--model", str(tmp_path / "missing.npz")]) == 2
    assert "error:" in capsys.readouterr().err
