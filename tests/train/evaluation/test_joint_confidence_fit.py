"""Fitting the joint confidence: the logistic regression, the threshold, the figures."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.joint_confidence import GROUPS, joint_confidence
from depthmocap.train.evaluation.joint_confidence_fit import (
    fit_confidence,
    fit_logistic,
    flag_figures,
    main,
)

J = len(sk.JOINT_NAMES)


def test_logistic_regression_recovers_known_weights():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(20000, 2)) * [2.0, 0.5] + [1.0, -1.0]
    true_w, true_b = np.array([1.5, -2.0]), 0.3
    y = (rng.random(len(x)) < 1 / (1 + np.exp(-(x @ true_w + true_b)))).astype(float)
    w, b = fit_logistic(x, y, l2=0.0)
    np.testing.assert_allclose(w, true_w, atol=0.12)
    assert b == pytest.approx(true_b, abs=0.12)


def test_flag_figures_golden():
    observed = np.array([[True, True, False], [True, False, False]])
    in_view = np.array([[True, False, True], [True, True, False]])
    error = np.array([[0.05, 0.3, 0.5], [0.1, 0.1, 0.9]])
    f = flag_figures(observed, in_view, error)
    assert f["recall"] == pytest.approx(2 / 4)  # two of the four joints in view flagged
    assert f["failure"] == pytest.approx(1 / 2)  # frame 0 flags a joint 30 cm off
    assert f["in_view"] == pytest.approx(2 / 3)


def _evidence(rng, frames=3000):
    """Joints in view with the same spread of support whether right or wrong; a wrong joint
    (2% of the limbs' joints) is on a limb the model hardly shows. An area test cannot tell
    them apart; the fitted confidence, which reads the limb's visibility, must."""
    in_view = rng.random((frames, J)) < 0.85
    support = np.where(in_view, rng.gamma(3.0, 30.0, (frames, J)), rng.gamma(1.0, 2.0, (frames, J)))
    limbs = {"l_arm": 0, "r_arm": 1, "l_leg": 2, "r_leg": 3}
    limb_of = np.array([
        -1 if n in ("head", "neck", "spine", "pelvis")
        else limbs[n[:2] + ("arm" if n[2:] in ("shoulder", "elbow", "wrist") else "leg")]
        for n in sk.JOINT_NAMES
    ])  # fmt: skip
    visibility = rng.uniform(0.3, 1.0, (frames, 4))
    bad_limb = rng.random((frames, 4)) < 0.02
    visibility[bad_limb] = rng.uniform(0.0, 0.1, int(bad_limb.sum()))
    wrong = np.zeros((frames, J), dtype=bool)
    limb_joints = limb_of >= 0
    wrong[:, limb_joints] = bad_limb[:, limb_of[limb_joints]]
    error = np.where(wrong, 0.35, 0.04)
    return support, visibility, in_view, error


def _inputs(evidence):
    return [torch.as_tensor(evidence[k]) for k in ("support", "visibility", "fit", "cut_m")]


def test_fitted_flags_keep_the_recall_and_fail_less_than_the_area_test():
    rng = np.random.default_rng(1)
    support, visibility, in_view, error = _evidence(rng)
    frames = len(support)
    evidence = {"support": support, "visibility": visibility, "in_view": in_view, "error_m": error,
                "fit": rng.random((frames, 5)), "cut_m": np.full((frames, J), np.inf)}  # fmt: skip
    model = fit_confidence(evidence, recall=0.9)
    assert model.recall == pytest.approx(0.9, abs=0.002) and model.version == 2
    p = joint_confidence(model, *_inputs(evidence)).numpy()
    fitted = flag_figures(p >= model.threshold, in_view, error)
    area = np.quantile(support[in_view], 0.1)  # an area test keeping as many joints in view
    plain = flag_figures(support >= area, in_view, error)
    assert fitted["recall"] == pytest.approx(0.9, abs=0.002)
    assert plain["recall"] == pytest.approx(0.9, abs=0.002)
    assert plain["failure"] > 0.05
    assert fitted["failure"] < 0.5 * plain["failure"]


def test_joints_near_the_person_s_cut_are_learned_from_the_cut_distance():
    """Wrong joints are the ones near where the person leaves the image; nothing else tells
    them apart, so version 2's cut feature must carry the fit."""
    rng = np.random.default_rng(2)
    frames = 3000
    support = rng.gamma(3.0, 30.0, (frames, J))
    visibility = rng.uniform(0.3, 1.0, (frames, 4))
    in_view = np.ones((frames, J), dtype=bool)
    cut = np.where(rng.random((frames, J)) < 0.1, rng.uniform(0.0, 0.08, (frames, J)), np.inf)
    error = np.where(cut < 0.08, 0.3, 0.03)
    evidence = {"support": support, "visibility": visibility, "in_view": in_view, "error_m": error,
                "fit": np.zeros((frames, 5)), "cut_m": cut}  # fmt: skip
    model = fit_confidence(evidence, recall=0.85)
    p = joint_confidence(model, *_inputs(evidence)).numpy()
    flags = p >= model.threshold
    assert flag_figures(flags, in_view, error)["failure"] < 0.05
    assert (model.weights[:, 8] > 0).all()  # further from the cut: more trusted, every group


def test_joints_far_from_their_parts_are_learned_from_the_parts_evidence():
    """Wrong joints are the ones the forest sees none of their parts near; with ``parts`` in
    the evidence the fit is version 3 and its nearest-part feature carries it."""
    rng = np.random.default_rng(3)
    frames = 3000
    support = rng.gamma(3.0, 30.0, (frames, J))
    visibility = rng.uniform(0.3, 1.0, (frames, 4))
    in_view = np.ones((frames, J), dtype=bool)
    wrong = rng.random((frames, J)) < 0.05
    near = np.where(wrong, rng.uniform(0.2, 0.5, (frames, J)), rng.uniform(0.0, 0.05, (frames, J)))
    parts = np.stack([near, rng.uniform(50, 500, (frames, J))], -1)
    joints = rng.normal(0.0, 0.3, (frames, J, 3)) + np.array([0.0, 0.0, 3.0])
    evidence = {"support": support, "visibility": visibility, "in_view": in_view,
                "error_m": np.where(wrong, 0.3, 0.03), "fit": np.zeros((frames, 5)),
                "cut_m": np.full((frames, J), np.inf),
                "joints": joints, "parts": parts}  # fmt: skip
    model = fit_confidence(evidence, recall=0.9)
    assert model.version == 3 and model.weights.shape == (len(GROUPS), 15)
    inputs = _inputs(evidence) + [torch.as_tensor(evidence[k]) for k in ("joints", "parts")]
    p = joint_confidence(model, *inputs).numpy()
    assert flag_figures(p >= model.threshold, in_view, evidence["error_m"])["failure"] < 0.02
    assert (model.weights[:, 13] < 0).all()  # further from its parts: less trusted


def test_cli_rejects_bad_arguments(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--recordings", str(tmp_path / "none"), "--out", str(tmp_path / "c.json")])
    with pytest.raises(SystemExit):
        main(["--recordings", str(tmp_path), "--out", str(tmp_path / "c.json"), "--recall", "0"])
    assert main(["--recordings", str(tmp_path), "--out", str(tmp_path / "c.json")]) == 2
    assert "no recordings with ground truth" in capsys.readouterr().err


@pytest.mark.parametrize("with_parts", [True, False])
def test_cli_says_which_version_it_fitted(tmp_path, capsys, monkeypatch, with_parts):
    """Evidence recorded before version 3's parts fits version 2, and the command says so."""
    import depthmocap.train.evaluation.joint_confidence_fit as fit_module
    from depthmocap.shared.joint_confidence import load_joint_confidence

    rng = np.random.default_rng(4)
    support, visibility, in_view, error = _evidence(rng, frames=500)
    evidence = {"support": support, "visibility": visibility, "in_view": in_view, "error_m": error,
                "fit": rng.random((500, 5)), "cut_m": np.full((500, J), np.inf),
                "joints": rng.normal(0.0, 0.3, (500, J, 3)),
                "observed": support >= 5.0}  # fmt: skip
    if with_parts:
        evidence["parts"] = np.stack([rng.random((500, J)), rng.random((500, J)) * 100], -1)
    monkeypatch.setattr(fit_module, "_evidence", lambda *a: evidence)
    out = tmp_path / "c.json"
    assert main(["--recordings", str(tmp_path), "--out", str(out)]) == 0
    version = 3 if with_parts else 2
    captured = capsys.readouterr()
    assert f"version {version}," in captured.out and load_joint_confidence(out).version == version
    assert ("record it again" in captured.err) is not with_parts


def _recording_with_truth(path, frames=3):
    from depthmocap.shared.camera import Intrinsics
    from depthmocap.shared.recording import RecordingWriter

    truth = np.zeros((frames, J, 3))
    truth[..., 2] = 2.0
    truth[:, :, 0] = np.linspace(-0.3, 0.3, J)
    with RecordingWriter(path, Intrinsics.kinect_v1(320)) as w:
        for _ in range(frames):
            w.write_frame(np.zeros((240, 320), np.uint16), np.zeros((240, 320), np.uint8))
        w.write_groundtruth(truth, list(sk.JOINT_NAMES))
    return truth


def test_recording_evidence_pairs_each_posed_frame_with_its_truth(tmp_path):
    from depthmocap.train.evaluation.joint_confidence_fit import recording_evidence

    truth = _recording_with_truth(tmp_path / "rec")
    joints = truth[[0, 2]].copy()
    joints[1, 3, 1] += 0.25  # frame 2's pelvis 25 cm off
    np.savez(
        tmp_path / "rec.npz", frame=np.array([0, 2]), support=np.full((2, J), 7.0),
        visibility=np.ones((2, 4)), joints=joints, observed=np.ones((2, J), bool),
        fit=np.ones((2, 5)), cut_m=np.full((2, J), np.inf),
    )  # fmt: skip
    e = recording_evidence(tmp_path / "rec", tmp_path / "rec.npz")
    assert e["support"].shape == (2, J) and e["in_view"].shape == (2, J)
    assert e["fit"].shape == (2, 5) and np.isinf(e["cut_m"]).all()
    assert not e["in_view"].any()  # no depth: no joint is in view
    expect = np.zeros((2, J))
    expect[1, 3] = 0.25
    np.testing.assert_allclose(e["error_m"], expect, atol=1e-6)  # stored as float32
    np.savez(
        tmp_path / "bad.npz", frame=np.array([5]), support=np.zeros((1, J)),
        visibility=np.ones((1, 4)), joints=truth[:1], observed=np.ones((1, J), bool),
        fit=np.ones((1, 5)), cut_m=np.ones((1, J)),
    )  # fmt: skip
    with pytest.raises(ValueError, match="frames beyond"):
        recording_evidence(tmp_path / "rec", tmp_path / "bad.npz")


def test_an_unreadable_evidence_file_is_a_clear_error(tmp_path):
    from depthmocap.train.evaluation.joint_confidence_fit import recording_evidence

    _recording_with_truth(tmp_path / "rec")
    (tmp_path / "torn.npz").write_bytes(b"PK\x03\x04 torn")
    with pytest.raises(ValueError, match="not a readable evidence file.*delete it"):
        recording_evidence(tmp_path / "rec", tmp_path / "torn.npz")
    np.savez(tmp_path / "short.npz", frame=np.array([0]))  # keys missing (an older file)
    with pytest.raises(ValueError, match="not a readable evidence file"):
        recording_evidence(tmp_path / "rec", tmp_path / "short.npz")
