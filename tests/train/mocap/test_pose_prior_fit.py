"""Fitting the pose prior (train.mocap.pose_prior_fit): mirrored poses are the mirror images of
the body, EM recovers a known mixture, the CLI writes a file the runtime reads."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
from depthmocap.shared.pose_prior import ANGLE_NAMES, load_pose_prior
from depthmocap.train.mocap import pose_prior_fit
from depthmocap.train.mocap.pose_prior_fit import fit_mixture, mirror_angles


def _joints(angles: np.ndarray) -> np.ndarray:
    q = torch.zeros(len(angles), sk.NUM_DOFS, dtype=torch.float64)
    q[:, sk.ANGLE_DOFS] = torch.as_tensor(angles)
    return named_joint_positions(forward_kinematics(q, BodyShape.default(torch.float64))).numpy()


def test_mirrored_angles_pose_the_mirror_image():
    """Body frame x is the person's left: the mirrored pose's joints are the pose's with x
    negated and left and right exchanged."""
    rng = np.random.default_rng(0)
    lo, hi = sk.DOF_LIMITS[6:, 0], sk.DOF_LIMITS[6:, 1]
    angles = lo + (hi - lo) * rng.uniform(0.2, 0.8, size=(5, len(ANGLE_NAMES)))
    joints, mirrored = _joints(angles), _joints(mirror_angles(angles))
    names = list(sk.JOINT_NAMES)
    other = [names.index({"l": "r", "r": "l"}[n[0]] + n[1:]) if n[:2] in ("l_", "r_") else i
             for i, n in enumerate(names)]  # fmt: skip
    expected = joints[:, other] * np.array([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(mirrored, expected, atol=1e-9)
    np.testing.assert_array_equal(mirror_angles(mirror_angles(angles)), angles)


def test_em_recovers_a_known_mixture():
    rng = np.random.default_rng(1)
    a = rng.normal([0.0, 0.0], [0.1, 0.3], size=(600, 2))
    b = rng.normal([2.0, -1.0], [0.2, 0.1], size=(300, 2))
    weights, means, cov, _ = fit_mixture(np.concatenate([a, b]), 2, floor_rad=1e-3, seed=0)
    order = np.argsort(means[:, 0])
    np.testing.assert_allclose(weights[order], [2 / 3, 1 / 3], atol=0.01)
    np.testing.assert_allclose(means[order], [[0, 0], [2, -1]], atol=0.05)
    np.testing.assert_allclose(np.sqrt(np.diagonal(cov[order], axis1=1, axis2=2)),
                               [[0.1, 0.3], [0.2, 0.1]], rtol=0.15)  # fmt: skip


def test_too_few_poses_is_an_error():
    with pytest.raises(ValueError, match="too few"):
        fit_mixture(np.zeros((10, 28)), 4, 0.05)


def test_cli_fits_from_cached_angles(tmp_path):
    rng = np.random.default_rng(2)
    angles = rng.normal(0.0, 0.3, size=(400, len(ANGLE_NAMES)))
    np.savez(tmp_path / "angles.npz", angles=angles)
    out = tmp_path / "prior.json"
    argv = ["--cache", str(tmp_path / "angles.npz"), "--out", str(out), "--components", "2"]
    assert pose_prior_fit.main(argv) == 0
    prior = load_pose_prior(out)
    assert prior.frames == 800 and prior.means.shape == (2, len(ANGLE_NAMES))
    # mirrored poses in: the mixture's mean pose is its own mirror image
    mean = (prior.weights[:, None] * prior.means).sum(0, keepdims=True)
    np.testing.assert_allclose(mirror_angles(mean), mean, atol=1e-6)


def test_cli_without_clips_fails_clearly(tmp_path, capsys):
    argv = ["--mocap", str(tmp_path / "none"), "--out", str(tmp_path / "p.json")]
    assert pose_prior_fit.main(argv) == 1
    assert "no clips" in capsys.readouterr().err
