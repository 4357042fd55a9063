"""The learned pose prior's file format (shared.pose_prior) and its fit
(train.mocap.pose_prior_fit)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from depthmocap.shared import skeleton as sk
from depthmocap.shared.pose_prior import (
    ANGLE_NAMES,
    PosePrior,
    PosePriorError,
    angle_weights,
    load_pose_prior,
    save_pose_prior,
)
from depthmocap.shared.resources import MODELS_DIR
from depthmocap.train.mocap.pose_prior_fit import fit_pose_prior

N = len(ANGLE_NAMES)


def _prior() -> PosePrior:
    rng = np.random.default_rng(0)
    return PosePrior(rng.normal(0, 0.3, N), rng.uniform(0.1, 0.8, N), 1234, "tests")


def test_round_trip(tmp_path):
    prior = _prior()
    save_pose_prior(tmp_path / "p.json", prior)
    back = load_pose_prior(tmp_path / "p.json")
    np.testing.assert_allclose(back.mean_rad, prior.mean_rad, atol=1e-6)
    np.testing.assert_allclose(back.std_rad, prior.std_rad, atol=1e-6)
    assert (back.frames, back.fitted_on) == (1234, "tests")


def test_shipped_prior_loads():
    prior = load_pose_prior(MODELS_DIR / "pose_prior.json")
    assert prior.frames > 1000 and (prior.std_rad > 0.05 - 1e-9).all()
    # the knees bend one way: their mean lies inside the joint limits
    lower, upper = np.asarray(sk.DOF_LIMITS)[sk.ANGLE_DOFS].T
    assert ((prior.mean_rad > lower) & (prior.mean_rad < upper)).all()


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(format="other"), "not a depthmocap-pose-prior"),
        (lambda d: d.update(version=99), "version 99"),
        (lambda d: d.update(dof_names=d["dof_names"][::-1]), "not this skeleton"),
        (lambda d: d["std_rad"].__setitem__(3, 0.0), "positive"),
        (lambda d: d["mean_rad"].__setitem__(0, "x"), "not numbers"),
        (lambda d: d.update(mean_rad=d["mean_rad"][:5]), "entries"),
    ],
)
def test_bad_files_raise(tmp_path, change, message):
    path = tmp_path / "p.json"
    save_pose_prior(path, _prior())
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))
    with pytest.raises(PosePriorError, match=message):
        load_pose_prior(path)


def test_missing_and_corrupt_files_raise(tmp_path):
    with pytest.raises(PosePriorError, match="no such file"):
        load_pose_prior(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(PosePriorError, match="not a readable JSON"):
        load_pose_prior(tmp_path / "bad.json")


def test_angle_weights_leave_the_root_free():
    prior = _prior()
    mean, w2 = angle_weights(prior, 2.0)
    assert mean.shape == w2.shape == (sk.NUM_DOFS,)
    assert (w2[:6] == 0).all() and (mean[:6] == 0).all()
    np.testing.assert_allclose(w2[6:], 1.0 / (2.0 * prior.std_rad) ** 2)
    np.testing.assert_allclose(mean[6:], prior.mean_rad)
    with pytest.raises(PosePriorError):
        angle_weights(prior, 0.0)


def test_fit_golden():
    q = np.zeros((4, sk.NUM_DOFS))
    q[:, 0] = [5.0, -5.0, 1.0, 2.0]  # the root is not part of the prior
    q[:, 6] = [0.0, 1.0, 0.0, 1.0]  # mean 0.5, std 0.5
    prior = fit_pose_prior(q, min_std_rad=0.05)
    assert prior.mean_rad[0] == pytest.approx(0.5) and prior.std_rad[0] == pytest.approx(0.5)
    assert prior.mean_rad[1] == 0.0 and prior.std_rad[1] == 0.05  # never moved: the floor
    assert prior.frames == 4
    with pytest.raises(ValueError):
        fit_pose_prior(q[:1])
