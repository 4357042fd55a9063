"""The joint-angle prior (shared.pose_prior): fitting, the conditional mean (golden, against
the Gaussian's formula), the file's round trip and its errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.pose_prior import (
    ANGLE_DOFS,
    RIDGE_RAD2,
    PosePrior,
    PosePriorError,
    conditional_angles,
    fit_pose_prior,
    load_pose_prior,
    save_pose_prior,
)

A = len(ANGLE_DOFS)
KNEE, HIP = sk.DOF_NAMES.index("r_tibia_flex"), sk.DOF_NAMES.index("r_femur_flex")
OTHER_KNEE = sk.DOF_NAMES.index("l_tibia_flex")


def _correlated_poses(n: int = 4000) -> np.ndarray:
    """Poses whose right knee bends 0.8 times the left knee plus noise; the rest independent."""
    g = np.random.default_rng(0)
    q = g.normal(0.0, 0.3, (n, sk.NUM_DOFS))
    q[:, KNEE] = 0.8 * q[:, OTHER_KNEE] + g.normal(0.0, 0.05, n)
    return q


def test_fit_is_the_angles_mean_and_covariance():
    q = _correlated_poses()
    prior = fit_pose_prior(q, clips=3, fitted_on="test")
    angles = q[:, 6:]
    assert np.allclose(prior.mean, angles.mean(0))
    assert np.allclose(prior.covariance, np.cov(angles, rowvar=False))
    assert prior.frames == len(q) and prior.clips == 3
    with pytest.raises(PosePriorError, match="at least 2"):
        fit_pose_prior(q[:1], clips=1)


def test_conditional_mean_golden():
    """Held angles move to the Gaussian's conditional mean given the seen ones; the root and
    the seen angles stay; nothing held changes nothing."""
    prior = fit_pose_prior(_correlated_poses(), clips=1)
    q = torch.zeros(sk.NUM_DOFS, dtype=torch.float64)
    q[:6] = torch.tensor([0.1, 0.2, 2.5, 0.3, -0.2, 0.1], dtype=torch.float64)
    q[OTHER_KNEE] = 1.0
    q[KNEE] = -0.5  # the value held, to be replaced
    held = torch.zeros(sk.NUM_DOFS, dtype=torch.bool)
    held[KNEE] = True
    got = conditional_angles(prior, q, held)
    cov = prior.covariance + RIDGE_RAD2 * np.eye(A)
    h = ANGLE_DOFS.index(KNEE)
    s = [i for i in range(A) if i != h]
    x = q.numpy()[6:]
    expected = prior.mean[h] + cov[h, s] @ np.linalg.solve(cov[np.ix_(s, s)], x[s] - prior.mean[s])
    assert float(got[KNEE]) == pytest.approx(expected, abs=1e-12)
    assert float(got[KNEE]) == pytest.approx(0.8, abs=0.05)  # the correlation it learned
    keep = torch.ones(sk.NUM_DOFS, dtype=torch.bool)
    keep[KNEE] = False
    assert torch.equal(got[keep], q[keep])
    assert torch.equal(conditional_angles(prior, q, torch.zeros_like(held)), q)


def test_every_angle_held_gives_the_mean():
    prior = fit_pose_prior(_correlated_poses(), clips=1)
    q = torch.randn(sk.NUM_DOFS, dtype=torch.float32)
    held = torch.ones(sk.NUM_DOFS, dtype=torch.bool)
    got = conditional_angles(prior, q, held)
    assert got.dtype == torch.float32
    assert torch.equal(got[:6], q[:6])
    assert np.allclose(got[6:].numpy(), prior.mean, atol=1e-6)


def test_round_trip(tmp_path):
    prior = fit_pose_prior(_correlated_poses(200), clips=2, fitted_on="two clips")
    path = tmp_path / "prior.json"
    save_pose_prior(path, prior)
    back = load_pose_prior(path)
    assert np.array_equal(back.mean, prior.mean)
    assert np.array_equal(back.covariance, prior.covariance)
    assert (back.frames, back.clips, back.fitted_on) == (200, 2, "two clips")


def _write(path, **change) -> None:
    prior = fit_pose_prior(_correlated_poses(200), clips=2)
    save_pose_prior(path, prior)
    data = json.loads(path.read_text())
    data.update(change)
    path.write_text(json.dumps(data))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"format": "other"}, "not a pose-prior file"),
        ({"version": 99}, "version 99"),
        ({"dof_names": ["x"] * A}, "not this skeleton's"),
        ({"mean_rad": [0.0] * 3}, "must be"),
        ({"mean_rad": [float("nan")] * A}, "finite"),
        ({"covariance_rad2": (-np.eye(A)).tolist()}, "not negative"),
        ({"frames": None}, "malformed"),
    ],
)
def test_bad_files_are_clear_errors(tmp_path, change, message):
    path = tmp_path / "prior.json"
    _write(path, **change)
    with pytest.raises(PosePriorError, match=message):
        load_pose_prior(path)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(PosePriorError, match="cannot read"):
        load_pose_prior(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(PosePriorError, match="cannot read"):
        load_pose_prior(tmp_path / "bad.json")


def test_the_shipped_prior_loads():
    """models/pose_prior.json is this build's format, with bending knees and elbows on
    average (the clips' people stand, walk and reach)."""
    from depthmocap.shared.resources import MODELS_DIR

    prior = load_pose_prior(MODELS_DIR / "pose_prior.json")
    assert isinstance(prior, PosePrior) and prior.frames > 1000 and prior.clips > 100
    assert prior.mean[ANGLE_DOFS.index(KNEE)] > 0.3
