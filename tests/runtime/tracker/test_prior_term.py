"""The tracker's prior term (runtime.tracker.prior_term): the predicted pose, its velocity gain,
and the prior's step onto the prediction."""

from __future__ import annotations

import pytest
import torch
from depthmocap.runtime.tracker.gauss_newton import solve_step
from depthmocap.runtime.tracker.prior_term import predict_pose, prior_residual, prior_system
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
