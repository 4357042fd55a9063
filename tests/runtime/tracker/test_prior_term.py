"""The tracker's prior term (runtime.tracker.prior_term): the predicted pose, its velocity gain,
and the prior's step onto the prediction."""

from __future__ import annotations

import pytest
import torch
from depthmocap.runtime.tracker.gauss_newton import solve_step
from depthmocap.runtime.tracker.prior_term import (
    predict_pose,
    prior_residual,
    prior_system,
    with_pose_prior,
)
from depthmocap.shared import skeleton as sk
from depthmocap.shared.kinematics import pose_update
from depthmocap.shared.so3 import rotvec_to_matrix

D = {n: i for i, n in enumerate(sk.DOF_NAMES)}

pytestmark = pytest.mark.usefixtures("one_thread")


def _two_poses(make_pose) -> tuple[torch.Tensor, torch.Tensor]:
    """The test pose and the one a frame before: moved right, elbow straighter, root turned."""
    q1, q2 = make_pose(), make_pose()
    q2[0, 0] -= 0.02
    q2[0, D["l_radius_flex"]] -= 0.1
    q2[0, 3:6] = torch.tensor([3.0, 0.15, -0.1], dtype=torch.float64)
    return q1, q2


class TestPredictPose:
    def test_velocity_gain(self, make_pose):
        q1, q2 = _two_poses(make_pose)
        r1, r2 = rotvec_to_matrix(q1[:, 3:6]), rotvec_to_matrix(q2[:, 3:6])
        # Gain 1 is Wei's constant velocity: root rotation R1 R2^T R1.
        full = predict_pose(q1, q2, 1.0)
        assert torch.allclose(rotvec_to_matrix(full[:, 3:6]), r1 @ r2.transpose(-1, -2) @ r1)
        assert torch.equal(predict_pose(q1, q2, 0.0), q1)
        half = predict_pose(q1, q2, 0.5)
        assert float(half[0, 0] - q1[0, 0]) == pytest.approx(0.01)
        assert float(half[0, D["l_radius_flex"]] - q1[0, D["l_radius_flex"]]) == pytest.approx(0.05)
        # Half the rotation step: applying it twice gives the full prediction.
        step = rotvec_to_matrix(half[:, 3:6]) @ r1.transpose(-1, -2)
        assert torch.allclose(step @ step @ r1, rotvec_to_matrix(full[:, 3:6]), atol=1e-9)


class TestPriorSystem:
    def test_step_onto_the_prediction(self, make_pose):
        """The prediction's golden offsets, then the prior alone steps onto it."""
        q1, q2 = _two_poses(make_pose)
        pred = predict_pose(q1, q2)
        assert float(pred[0, 0] - q1[0, 0]) == pytest.approx(0.02)
        assert float(pred[0, D["l_radius_flex"]] - q1[0, D["l_radius_flex"]]) == pytest.approx(0.1)
        assert float(prior_residual(pred, pred).abs().max()) < 1e-9
        # The prior alone moves the pose onto the prediction (up to the damping).
        w2, rhs, _ = prior_system(q1, pred, 0.05, 0.02)
        dq = solve_step(torch.diag_embed(w2), rhs, q1, 1e-6)
        moved = pose_update(q1, dq)
        assert float(prior_residual(moved, pred).abs().max()) < 1e-4

    def test_root_residual_is_the_vee_of_the_relative_rotation(self, make_pose):
        """The root's residual is sin(angle) axis of R_pred R^T: the vee of its antisymmetric
        part, whichever sign the quaternions take."""
        q1, q2 = _two_poses(make_pose)
        rel = rotvec_to_matrix(q2[:, 3:6]) @ rotvec_to_matrix(q1[:, 3:6]).transpose(-1, -2)
        vee = 0.5 * torch.stack(
            [rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]],
            -1,
        )
        assert torch.allclose(prior_residual(q1, q2)[:, 3:6], vee, atol=1e-12)
        assert float(vee.norm()) > 0.02  # a real turn, not the identity


class TestPosePrior:
    def test_folded_prior_has_the_sum_of_both_gradients(self, make_pose):
        """Wei's prior and the learned one folded into one Gaussian give the same normal
        equations as the two added (the energies differ by a constant), the root untouched."""
        g = torch.Generator().manual_seed(3)
        q = make_pose().expand(3, -1).clone()
        q_pred = q + 0.1 * torch.randn(3, 34, generator=g, dtype=q.dtype)
        mean = 0.3 * torch.randn(34, generator=g, dtype=q.dtype)
        s2 = torch.rand(34, generator=g, dtype=q.dtype) * 30.0
        s2[:6] = 0.0
        w2_wei, rhs_wei, _ = prior_system(q, q_pred, 0.05, 0.02)
        w2, rhs, _ = prior_system(q, q_pred, 0.05, 0.02, (mean, s2))
        torch.testing.assert_close(w2, w2_wei + s2)
        torch.testing.assert_close(rhs[:, 6:], rhs_wei[:, 6:] + s2[6:] * (mean[6:] - q[:, 6:]))
        assert torch.equal(rhs[:, :6], rhs_wei[:, :6])
        target, _ = with_pose_prior(q_pred, w2_wei, (mean, s2))
        assert torch.equal(target[:, :6], q_pred[:, :6])

    @pytest.mark.parametrize("compiled", [True, False])
    def test_a_free_angle_moves_towards_the_mean(self, make_pose, monkeypatch, compiled):
        """With no data on it, an angle steps the golden fraction s2 / (w2 + s2) of the way
        from the prediction to the prior's mean; every other DoF stays (compiled and torch
        updates alike)."""
        from depthmocap.runtime.tracker import gauss_newton

        if compiled:
            pytest.importorskip("numba")
        else:
            monkeypatch.setattr(gauss_newton, "_step_kernel", lambda: None)
        q = make_pose()
        k = D["l_femur_abd"]
        mean = torch.zeros(34, dtype=q.dtype)
        s2 = torch.zeros(34, dtype=q.dtype)
        mean[k], s2[k] = q[0, k] - 0.2, 100.0  # the mean 0.2 rad away, sigma 0.1 rad
        hess = torch.zeros(1, 34, 34, dtype=torch.float64)
        grad = torch.zeros(1, 34, dtype=torch.float64)
        q_new = gauss_newton.gauss_newton_step(
            hess, grad, q, q.clone(), 0.0, 1.0, 0.05, 0.02, (mean, s2)
        )[0]
        expected = -0.2 * 100.0 / (1.0 / 0.05**2 + 100.0)
        assert float(q_new[0, k] - q[0, k]) == pytest.approx(expected, rel=1e-4)
        others = torch.ones(34, dtype=torch.bool)
        others[k] = False
        assert float((q_new[0, others] - q[0, others]).abs().max()) < 1e-6
