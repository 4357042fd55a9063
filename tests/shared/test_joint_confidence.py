"""The joint confidence behind the observed flags: features, the model, the file format."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.joint_confidence import (
    CUT_CAP_M,
    FRAME_FEATURES,
    GROUPS,
    JOINT_GROUP,
    JointConfidence,
    JointConfidenceError,
    confidence_features,
    frame_features,
    joint_confidence,
    load_joint_confidence,
    save_joint_confidence,
)

J = len(sk.JOINT_NAMES)


def _index(name: str) -> int:
    return sk.JOINT_NAMES.index(name)


def test_groups_pair_the_sides_and_keep_the_trunk_together():
    assert GROUPS == ("trunk", "shoulder", "elbow", "wrist", "hip", "knee", "ankle")
    assert JOINT_GROUP[_index("head")] == JOINT_GROUP[_index("pelvis")] == "trunk"
    assert JOINT_GROUP[_index("l_wrist")] == JOINT_GROUP[_index("r_wrist")] == "wrist"


def test_features_golden():
    support = torch.arange(J, dtype=torch.float64)  # joint j has j cm^2
    shown = torch.tensor([0.1, 0.2, 0.3, 0.4], dtype=torch.float64)
    f = confidence_features(support, shown)
    assert f.shape == (J, 3) and f.dtype == torch.float64
    assert torch.allclose(f[:, 0], torch.log1p(support))
    # visibility: the joint's limb (left arm 0.1, right arm 0.2, left leg 0.3, right leg 0.4)
    expect = {"head": 1.0, "spine": 1.0, "l_shoulder": 0.1, "l_wrist": 0.1, "r_elbow": 0.2,
              "l_hip": 0.3, "l_ankle": 0.3, "r_knee": 0.4}  # fmt: skip
    for name, value in expect.items():
        assert f[_index(name), 1].item() == pytest.approx(value), name
    # neighbour: wrist <- elbow, elbow <- wrist, shoulder <- elbow, legs alike, trunk: itself
    pairs = {"l_wrist": "l_elbow", "r_elbow": "r_wrist", "l_shoulder": "l_elbow",
             "r_ankle": "r_knee", "l_knee": "l_ankle", "r_hip": "r_knee",
             "neck": "neck"}  # fmt: skip
    for joint, neighbour in pairs.items():
        assert f[_index(joint), 2].item() == pytest.approx(math.log1p(_index(neighbour)))


def test_features_batch_and_missing_values():
    support = torch.full((2, 5, J), 3.0)
    support[0, 0, 0] = float("nan")
    support[1, 0, 0] = -2.0  # no area is negative: clamped to none
    shown = torch.full((2, 5, 4), float("nan"))
    f = confidence_features(support, shown)
    assert f.shape == (2, 5, J, 3)
    assert f[0, 0, 0, 0] == 0 and f[1, 0, 0, 0] == 0
    assert (f[..., _index("l_wrist"), 1] == 0).all()  # an unknown limb counts as hidden
    assert (f[..., _index("head"), 1] == 1).all()


def test_frame_features_golden():
    errors = {"overlap": 0.8, "depth_error_cm": 1.5, "surface_error_q97_mm": 40.0,
              "kept_over_detector": 1.0, "ik_rms_m": 0.02}  # fmt: skip
    f = frame_features(errors, "tracked")
    assert len(FRAME_FEATURES) == 5
    np.testing.assert_allclose(f, [0.8, 1.5, 0.4, 1.0, 0.0])
    # a detection whose refinement gave no signals; a waited track counts as kept too
    np.testing.assert_allclose(
        frame_features({"overlap": float("nan")}, "detected"), [0, 0, 0, 0, 1]
    )
    np.testing.assert_allclose(frame_features({"detector_waited": 1.0}, "tracked")[3], 1.0)


def test_version_2_features_add_the_frame_s_fit_and_the_capped_cut_distance():
    support = torch.full((2, J), 10.0, dtype=torch.float64)
    shown = torch.ones(2, 4, dtype=torch.float64)
    fit = torch.tensor([[0.9, 1.0, 0.3, 0.0, 0.0], [0.5, float("nan"), 0.8, 1.0, 1.0]])
    cut = torch.full((2, J), float("inf"))
    cut[1, _index("r_wrist")] = 0.07
    f = confidence_features(support, shown, fit, cut)
    assert f.shape == (2, J, 9)
    torch.testing.assert_close(f[..., :3], confidence_features(support, shown))
    assert (f[0, :, 3:8] == fit[0].double()).all()
    assert (f[1, :, 4] == 0).all()  # NaN counts as 0
    assert (f[0, :, 8] == CUT_CAP_M).all() and f[1, _index("r_wrist"), 8].item() == pytest.approx(
        0.07
    )
    with pytest.raises(ValueError, match="both"):
        confidence_features(support, shown, fit, None)


def _model(threshold=0.5, version=2):
    per = [1.0, 2.0, 0.5] if version == 1 else [1.0, 2.0, 0.5, 0.1, -0.2, 0.3, -1.0, 0.5, 4.0]
    if version == 3:
        per = per + [0.2, -0.1, 0.3, 0.4, -0.5, 0.6]
    w = np.tile(per, (len(GROUPS), 1))
    b = -np.arange(len(GROUPS), dtype=np.float64)
    return JointConfidence(w, b, threshold, 0.95, "test", 7, version)


@pytest.mark.parametrize("version", [1, 2, 3])
def test_confidence_is_the_logistic_of_each_group_s_weights(version):
    model = _model(version=version)
    support = torch.rand(3, J, dtype=torch.float64) * 50
    shown = torch.rand(3, 4, dtype=torch.float64)
    fit = torch.rand(3, 5, dtype=torch.float64)
    cut = torch.rand(3, J, dtype=torch.float64)
    joints = torch.rand(3, J, 3, dtype=torch.float64)
    parts = torch.rand(3, J, 2, dtype=torch.float64) * torch.tensor([0.3, 200.0])
    p = joint_confidence(model, support, shown, fit, cut, joints, parts)
    extra = [(), (fit, cut), (fit, cut, joints, parts)][version - 1]
    f = confidence_features(support, shown, *extra).numpy()
    group = np.array([GROUPS.index(g) for g in JOINT_GROUP])
    expect = 1 / (1 + np.exp(-(f @ model.weights[0] - group)))
    assert p.shape == (3, J)
    np.testing.assert_allclose(p.numpy(), expect, rtol=1e-12)
    if version == 1:  # reads neither the frame's fit nor the cut, given or not
        torch.testing.assert_close(joint_confidence(model, support, shown), p)
    else:
        with pytest.raises(ValueError, match="cut"):
            joint_confidence(model, support, shown)
    if version == 2:  # reads neither the joints nor their parts, given or not
        torch.testing.assert_close(joint_confidence(model, support, shown, fit, cut), p)
    if version == 3:
        with pytest.raises(ValueError, match="parts"):
            joint_confidence(model, support, shown, fit, cut)


def test_version_3_features_add_the_pose_and_the_parts_evidence():
    support = torch.full((2, J), 10.0, dtype=torch.float64)
    shown = torch.ones(2, 4, dtype=torch.float64)
    fit = torch.zeros(2, 5, dtype=torch.float64)
    cut = torch.full((2, J), float("inf"))
    joints = torch.zeros(2, J, 3, dtype=torch.float64)
    joints[:, _index("l_wrist")] = torch.tensor([0.3, -0.4, 0.0])  # 0.5 m from the pelvis
    joints[1] += torch.tensor([1.0, 2.0, 3.0])  # the same pose elsewhere: the same features
    parts = torch.zeros(2, J, 2, dtype=torch.float64)
    parts[:, :, 0] = 0.02
    parts[:, :, 1] = 99.0
    parts[1, _index("l_wrist")] = torch.tensor([float("inf"), 0.0])  # no forearm pixels
    parts[1, _index("r_wrist"), 0] = 3.0  # capped
    f = confidence_features(support, shown, fit, cut, joints, parts)
    assert f.shape == (2, J, 15)
    torch.testing.assert_close(f[..., :9], confidence_features(support, shown, fit, cut))
    w = _index("l_wrist")
    torch.testing.assert_close(f[:, w, 9:13], torch.tensor([[0.3, -0.4, 0.0, 0.5]] * 2).double())
    assert f[0, w, 13].item() == pytest.approx(math.log(3.0))  # log(1 + 100 * 0.02)
    assert f[0, w, 14].item() == pytest.approx(math.log(100.0))
    assert f[1, w, 13].item() == pytest.approx(math.log(51.0)) and f[1, w, 14].item() == 0.0
    assert f[1, _index("r_wrist"), 13].item() == pytest.approx(math.log(51.0))
    with pytest.raises(ValueError, match="version 3"):
        confidence_features(support, shown, fit, cut, joints, None)
    with pytest.raises(ValueError, match="version 3"):
        confidence_features(support, shown, None, None, joints, parts)


@pytest.mark.parametrize("version", [1, 2, 3])
def test_round_trip(tmp_path, version):
    model = _model(0.42, version)
    path = tmp_path / "sub" / "c.json"
    save_joint_confidence(path, model)
    back = load_joint_confidence(path)
    np.testing.assert_allclose(back.weights, model.weights)
    np.testing.assert_allclose(back.bias, model.bias)
    assert (back.threshold, back.recall, back.fitted_on, back.frames) == (0.42, 0.95, "test", 7)
    assert back.version == version and json.loads(path.read_text())["version"] == version
    assert not list(path.parent.glob("*.tmp"))


def test_weights_must_match_the_version_s_feature_set():
    G = len(GROUPS)
    with pytest.raises(JointConfidenceError, match=r"\(7, 15\)"):
        JointConfidence(np.zeros((G, 3)), np.zeros(G), 0.5)
    with pytest.raises(JointConfidenceError, match="version 5"):
        JointConfidence(np.zeros((G, 3)), np.zeros(G), 0.5, version=5)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(format="other"), "not a depthmocap-joint-confidence"),
        (lambda d: d.update(version=99), "version 99"),
        (lambda d: d.update(joint_names=d["joint_names"][::-1]), "joints"),
        (lambda d: d.update(features="other"), "features"),
        (lambda d: d["groups"].pop("wrist"), "groups"),
        (lambda d: d["groups"]["wrist"].update(weights=[1.0]), "bad joint-confidence values"),
        (lambda d: d["groups"]["wrist"].update(bias="x"), "bad joint-confidence values"),
        (lambda d: d.update(threshold=1.5), "threshold"),
        (lambda d: d.pop("threshold"), "bad joint-confidence values"),
    ],
)
def test_bad_files_say_what_is_wrong(tmp_path, change, message):
    path = tmp_path / "c.json"
    data = _model().to_json_dict()
    change(data)
    path.write_text(json.dumps(data))
    with pytest.raises(JointConfidenceError, match=message):
        load_joint_confidence(path)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(JointConfidenceError, match="no such"):
        load_joint_confidence(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(JointConfidenceError, match="not a readable"):
        load_joint_confidence(tmp_path / "bad.json")


def test_the_shipped_file_loads():
    from depthmocap.shared.resources import MODELS_DIR

    model = load_joint_confidence(MODELS_DIR / "joint_confidence.json")
    assert 0 < model.threshold < 1 and model.frames > 1000 and model.version == 3
