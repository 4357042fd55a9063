"""The pose prior's file (shared.pose_prior): round trip, constant costs, clear errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from depthmocap.shared.pose_prior import (
    ANGLE_NAMES,
    PosePrior,
    PosePriorError,
    load_pose_prior,
    save_pose_prior,
)
from depthmocap.shared.resources import MODELS_DIR

A = len(ANGLE_NAMES)


def _prior(C: int = 2, seed: int = 0) -> PosePrior:
    rng = np.random.default_rng(seed)
    m = rng.normal(size=(C, A, A))
    cov = m @ np.swapaxes(m, 1, 2) / A + 0.1 * np.eye(A)
    return PosePrior(np.full(C, 1.0 / C), rng.normal(size=(C, A)), cov, "test", 10)


def test_round_trip(tmp_path):
    prior = _prior()
    save_pose_prior(tmp_path / "p.json", prior)
    back = load_pose_prior(tmp_path / "p.json")
    np.testing.assert_array_equal(back.means, prior.means)
    np.testing.assert_array_equal(back.covariances, prior.covariances)
    np.testing.assert_array_equal(back.weights, prior.weights)
    assert (back.fitted_on, back.frames) == ("test", 10)


def test_constant_costs_golden():
    """One standard normal component: 1/2 log det(2 pi I) = A/2 log(2 pi); two equal
    halves add log 2 each."""
    one = PosePrior(np.ones(1), np.zeros((1, A)), np.eye(A)[None])
    assert one.log_norms[0] == pytest.approx(0.5 * A * math.log(2 * math.pi))
    two = PosePrior(np.full(2, 0.5), np.zeros((2, A)), np.repeat(4 * np.eye(A)[None], 2, 0))
    expected = math.log(2) + 0.5 * A * math.log(2 * math.pi * 4)
    np.testing.assert_allclose(two.log_norms, expected)
    np.testing.assert_allclose(two.precisions, np.repeat(np.eye(A)[None] / 4, 2, 0))


def test_the_shipped_prior_loads():
    prior = load_pose_prior(MODELS_DIR / "pose_prior.json")
    assert prior.frames > 1000 and "mocap" in prior.fitted_on


def _write(path, **changes):
    data = _prior().to_json_dict()
    data.update(changes)
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"format": "other"}, "not a depthmocap-pose-prior file"),
        ({"version": 99}, "version 99"),
        ({"dof_names": list(ANGLE_NAMES[::-1])}, "angles are not this build's"),
        ({"weights": [0.3, 0.3]}, "sum to 1"),
        ({"means": [[0.0] * 5] * 2}, "means"),
        ({"means": [0.0] * 28}, r"means must be \(C, A\)"),
        ({"covariances": (-np.repeat(np.eye(A)[None], 2, 0)).tolist()}, "positive definite"),
    ],
)
def test_bad_files_say_why(tmp_path, changes, message):
    path = _write(tmp_path / "p.json", **changes)
    with pytest.raises(PosePriorError, match=message):
        load_pose_prior(path)


def test_missing_and_corrupt_files(tmp_path):
    with pytest.raises(PosePriorError, match="no such pose-prior file"):
        load_pose_prior(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(PosePriorError, match="not a readable pose-prior file"):
        load_pose_prior(tmp_path / "bad.json")
