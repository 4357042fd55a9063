"""The learned pose prior as a tracker term: its equations are the Gauss-Newton form of its
energy (autograd), each pose takes its most likely component, a step on the prior alone lands
on that component's mean, and the tracker reads the shipped file."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from depthmocap.runtime.tracker.pose_prior_term import (
    pose_prior_components,
    pose_prior_system,
    tracker_pose_prior,
)
from depthmocap.shared import skeleton as sk
from depthmocap.shared.pose_prior import ANGLE_NAMES, PosePrior

A = len(ANGLE_NAMES)


def _prior_tensors(seed: int = 0):
    rng = np.random.default_rng(seed)
    m = rng.normal(size=(3, A, A))
    cov = m @ np.swapaxes(m, 1, 2) / A + 0.05 * np.eye(A)
    prior = PosePrior(np.array([0.5, 0.3, 0.2]), rng.normal(0, 0.5, size=(3, A)), cov)
    return prior.tensors(torch.empty(0))


def _energy(q, means, precisions, c, weight):
    d = q[sk.ANGLE_DOFS] - means[c]
    return weight**2 * d @ precisions[c] @ d


def test_equations_are_the_energy_s_gauss_newton_form():
    means, precisions, log_norms = _prior_tensors()
    q = torch.randn(2, sk.NUM_DOFS, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    hess, grad = pose_prior_system(q, means, precisions, log_norms, 1.7)
    comps = pose_prior_components(q, means, precisions, log_norms)
    for b in range(2):
        c = int(comps[b])
        qb = q[b].clone().requires_grad_(True)
        (g,) = torch.autograd.grad(_energy(qb, means, precisions, c, 1.7), qb)
        h = torch.autograd.functional.hessian(
            lambda x, c=c: _energy(x, means, precisions, c, 1.7), q[b]
        )
        torch.testing.assert_close(grad[b], -0.5 * g)
        torch.testing.assert_close(hess[b], 0.5 * h)
    assert hess[:, :6].abs().max() == 0 and grad[:, :6].abs().max() == 0


def test_each_pose_takes_its_most_likely_component():
    means, precisions, log_norms = _prior_tensors()
    q = torch.zeros(3, sk.NUM_DOFS, dtype=torch.float64)
    q[:, sk.ANGLE_DOFS] = means
    assert pose_prior_components(q, means, precisions, log_norms).tolist() == [0, 1, 2]
    # by brute force over the components' costs
    gen = torch.Generator().manual_seed(2)
    q = torch.randn(64, sk.NUM_DOFS, dtype=torch.float64, generator=gen)
    d = q[:, None, sk.ANGLE_DOFS] - means
    costs = [
        [0.5 * float(d[b, c] @ precisions[c] @ d[b, c]) + float(log_norms[c]) for c in range(3)]
        for b in range(64)
    ]
    expected = torch.as_tensor(np.argmin(costs, 1))
    assert torch.equal(pose_prior_components(q, means, precisions, log_norms), expected)


def test_a_step_on_the_prior_alone_reaches_the_mean():
    means, precisions, log_norms = _prior_tensors()
    q = torch.zeros(1, sk.NUM_DOFS, dtype=torch.float64)
    q[0, sk.ANGLE_DOFS] = means[1] + 0.05
    c = int(pose_prior_components(q, means, precisions, log_norms)[0])
    hess, grad = pose_prior_system(q, means, precisions, log_norms, 2.0)
    block = hess[0, sk.ANGLE_DOFS, sk.ANGLE_DOFS]
    dq = torch.linalg.solve(block, grad[0, sk.ANGLE_DOFS])
    torch.testing.assert_close(q[0, sk.ANGLE_DOFS] + dq, means[c])


def test_the_compiled_equations_match_torch_s():
    pytest.importorskip("numba")
    means, precisions, log_norms = _prior_tensors()
    gen = torch.Generator().manual_seed(4)
    q = torch.randn(16, sk.NUM_DOFS, generator=gen)  # float32, as the tracker's
    compiled = pose_prior_system(q, means, precisions, log_norms, 2.5)
    by_torch = pose_prior_system(q.clone().requires_grad_(True), means, precisions, log_norms, 2.5)
    for a, b in zip(compiled, by_torch, strict=True):
        torch.testing.assert_close(a, b.detach(), rtol=1e-12, atol=1e-12)


def test_float32_poses_give_float64_equations():
    means, precisions, log_norms = _prior_tensors()
    hess, grad = pose_prior_system(torch.zeros(1, sk.NUM_DOFS), means, precisions, log_norms, 1.0)
    assert hess.dtype == grad.dtype == torch.float64


def test_the_tracker_reads_the_shipped_prior():
    means, precisions, log_norms = tracker_pose_prior("pose_prior.json", torch.empty(0))
    assert means.shape[1] == A and precisions.shape[1:] == (A, A)
    assert means.dtype == torch.float64 and torch.isfinite(log_norms).all()


def test_a_tracker_with_a_bad_prior_file_fails_when_made(tmp_path):
    from depthmocap.runtime.tracker import Tracker, TrackerConfig, TrackerConfigError
    from depthmocap.shared.body import BodyShape
    from depthmocap.shared.camera import Intrinsics

    body, intr = BodyShape.default(torch.float32), Intrinsics.kinect_v1()
    (tmp_path / "bad.json").write_text("{not json")
    cfg = TrackerConfig(pose_prior_weight=2.0, pose_prior_model=str(tmp_path / "bad.json"))
    with pytest.raises(TrackerConfigError, match="pose_prior_model: .*not a readable pose-prior"):
        Tracker(body, intr, cfg)
    off = TrackerConfig(pose_prior_model=str(tmp_path / "bad.json"))  # weight 0: never read
    Tracker(body, intr, off)
    Tracker(body, intr, TrackerConfig(pose_prior_weight=2.0))  # the shipped file


def test_a_missing_prior_file_is_a_clear_error(tmp_path):
    from depthmocap.shared.pose_prior import PosePriorError

    with pytest.raises(PosePriorError, match="no such pose-prior file"):
        tracker_pose_prior(str(tmp_path / "none.json"), torch.empty(0))
