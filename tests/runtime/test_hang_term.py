"""The hidden-arm pull: residuals (golden values), Jacobian (finite differences), the normal
equations it adds, the hidden-arm gate, and that a tracked frame's visible arms are untouched."""

from __future__ import annotations

import math

import pytest
import torch

from runtime.raycast import render_body
from runtime.tracker import Tracker, TrackerConfig
from runtime.tracker.hang_term import ARM_DOFS, hang_residuals, hang_system, hidden_arms
from shared import skeleton as sk
from shared.body import BodyShape
from shared.camera import Intrinsics
from shared.kinematics import forward_kinematics, pose_update, rest_pose
from shared.so3 import matrix_to_rotvec, rotvec_to_matrix

pytestmark = pytest.mark.usefixtures("one_thread")

INTR = Intrinsics.kinect_v1(160)
D = {n: i for i, n in enumerate(sk.DOF_NAMES)}
DOWN = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)


def _random_poses(batch: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    q = rest_pose(batch, dtype=torch.float64)
    q[:, 3:] += 0.3 * torch.randn(batch, sk.NUM_DOFS - 3, generator=g, dtype=torch.float64)
    return q


def test_residuals_golden_values():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, dtype=torch.float64)  # facing the camera upright, arms hanging
    q[0, D["l_humerus_abd"]] = math.pi / 2  # left arm straight out sideways
    q[0, D["r_radius_flex"]] = math.pi / 2  # right forearm forward, towards the camera
    res, _ = hang_residuals(forward_kinematics(q, body), DOWN * 3.0)  # any length of down
    torch.testing.assert_close(res[0, 1, 0], torch.zeros(3, dtype=torch.float64), atol=1e-6, rtol=0)
    # |d - u| for two unit vectors at 90 degrees is sqrt(2).
    for arm, bone in ((0, 0), (0, 1), (1, 1)):
        assert float(res[0, arm, bone].norm()) == pytest.approx(math.sqrt(2), abs=1e-6)
    # The right forearm points at the camera (-z in camera frame): d - u = (0, 1, 1).
    torch.testing.assert_close(res[0, 1, 1], torch.tensor([0.0, 1.0, 1.0], dtype=torch.float64))


def test_jacobian_matches_finite_differences():
    body = BodyShape.default(torch.float64)
    q = _random_poses(3)
    _, jac = hang_residuals(forward_kinematics(q, body), DOWN)
    eps = 1e-6
    for arm, (humerus, elbow) in enumerate(ARM_DOFS):
        for k, dof in enumerate((*humerus, elbow)):
            step = torch.zeros_like(q)
            step[:, dof] = eps
            plus = hang_residuals(forward_kinematics(q + step, body), DOWN)[0]
            minus = hang_residuals(forward_kinematics(q - step, body), DOWN)[0]
            # The residual is d - u: its derivative is minus the model's Jacobian.
            numeric = -(plus - minus)[:, arm] / (2 * eps)
            torch.testing.assert_close(jac[:, arm, :, :, k], numeric, atol=1e-7, rtol=0)
    # The elbow does not move the upper arm.
    assert float(jac[:, :, 0, :, 3].abs().max()) == 0.0


def test_system_only_touches_active_arms_and_is_positive_semidefinite():
    body = BodyShape.default(torch.float64)
    q = _random_poses(3, seed=1)
    kin = forward_kinematics(q, body)
    active = torch.tensor([[True, False], [False, False], [True, True]])
    hess, grad, energy = hang_system(kin, DOWN, active, 0.3)
    left = [*ARM_DOFS[0][0], ARM_DOFS[0][1]]
    others = [i for i in range(sk.NUM_DOFS) if i not in left]
    assert float(hess[0][others].abs().max()) == 0.0 and float(grad[0, others].abs().max()) == 0.0
    assert float(hess[1].abs().max()) == 0.0 and float(energy[1]) == 0.0
    torch.testing.assert_close(hess, hess.transpose(-1, -2))
    assert float(torch.linalg.eigvalsh(hess).min()) > -1e-9
    res, _ = hang_residuals(kin, DOWN)
    torch.testing.assert_close(energy[2], (res[2] ** 2).sum() / 0.3**2)


def test_gauss_newton_on_the_pull_hangs_a_raised_arm():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, dtype=torch.float64)
    q[0, D["l_humerus_abd"]] = 1.0
    q[0, D["l_humerus_flex"]] = 0.6
    q[0, D["l_radius_flex"]] = 1.2
    active = torch.tensor([[True, True]])
    start = float(hang_system(forward_kinematics(q, body), DOWN, active, 0.3)[2][0])
    for _ in range(10):
        hess, grad, _ = hang_system(forward_kinematics(q, body), DOWN, active, 0.3)
        hess = hess + 1e-6 * torch.eye(sk.NUM_DOFS, dtype=torch.float64)
        q = pose_update(q, torch.linalg.solve(hess, grad[..., None])[..., 0])
    end = float(hang_system(forward_kinematics(q, body), DOWN, active, 0.3)[2][0])
    assert start > 10.0 and end < 1e-6 * start
    # The torso did not move to hang the arm.
    torch.testing.assert_close(q[0, :14], rest_pose(1, dtype=torch.float64)[0, :14])


def test_hidden_arms_gate_by_visibility():
    body = BodyShape.default(torch.float64)
    facing = rest_pose(1, root_position=(0.0, 0.1, 2.4), dtype=torch.float64)
    # Turned 90 degrees about the vertical: the left side away from the camera, the left arm
    # hanging behind the torso.
    profile = facing.clone()
    turn = rotvec_to_matrix(torch.tensor([[0.0, math.pi / 2, 0.0]], dtype=torch.float64))
    profile[:, 3:6] = matrix_to_rotvec(rotvec_to_matrix(facing[:, 3:6]) @ turn)
    render = render_body(torch.cat([facing, profile]), body, INTR)
    assert hidden_arms(render, INTR, body, 0.1).tolist() == [[False, False], [True, False]]
    # A threshold above every visible fraction counts every arm hidden, zero none.
    assert bool(hidden_arms(render, INTR, body, 10.0).all())
    assert not bool(hidden_arms(render, INTR, body, 0.0).any())


def test_tracker_with_the_pull_leaves_visible_arms_alone():
    body = BodyShape.default()
    q = rest_pose(1, root_position=(0.0, 0.1, 2.4))
    q[0, D["l_humerus_abd"]] = 0.5
    q[0, D["r_humerus_abd"]] = 0.7
    depth = render_body(q, body, INTR).depth[0]
    start = q[0].clone()
    start[D["l_humerus_abd"]] += 0.1
    results = [
        Tracker(body, INTR, TrackerConfig(use_hang=hang, downsample=1)).step(
            depth, depth > 0, start
        )
        for hang in (False, True)
    ]
    torch.testing.assert_close(results[0].q, results[1].q)
    assert float(results[1].limb_visibility[:2].min()) > 0.5
