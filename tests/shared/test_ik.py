import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.ik import NAMED_JOINT_MARKERS, Markers, fit_pose, marker_positions
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, rest_pose


def poses(batch, scale=0.4, seed=0):
    g = torch.Generator().manual_seed(seed)
    q = rest_pose(batch, dtype=torch.float64)
    lim = torch.as_tensor(sk.DOF_LIMITS[6:])
    q[:, 6:] = (
        lim[:, 0]
        + torch.rand(batch, 28, generator=g, dtype=torch.float64) * (lim[:, 1] - lim[:, 0])
    ) * scale
    q[:, 0:3] += 0.2 * torch.randn(batch, 3, generator=g, dtype=torch.float64)
    return q


def test_named_markers_match_named_joints():
    body = BodyShape.default(torch.float64)
    kin = forward_kinematics(poses(4), body)
    assert torch.allclose(marker_positions(kin, NAMED_JOINT_MARKERS), named_joint_positions(kin))


def test_recovers_joints_from_nearby_start():
    body = BodyShape.default(torch.float64)
    q = poses(16)
    targets = named_joint_positions(forward_kinematics(q, body))
    g = torch.Generator().manual_seed(1)
    q0 = q + 0.15 * torch.randn(q.shape, generator=g, dtype=torch.float64)
    res = fit_pose(targets, q0, body, prior=0.0, iterations=60)
    assert res.rms.max() < 1e-4, res.rms
    fitted = named_joint_positions(forward_kinematics(res.q, body))
    assert (fitted - targets).norm(dim=-1).max() < 1e-3


def test_missing_markers_are_ignored():
    body = BodyShape.default(torch.float64)
    q = poses(2)
    targets = named_joint_positions(forward_kinematics(q, body))
    wrist = sk.JOINT_NAMES.index("l_wrist")
    targets[:, wrist] = float("nan")  # missing: NaN or weight 0
    weights = torch.ones(2, len(sk.JOINT_NAMES), dtype=torch.float64)
    weights[:, 0] = 0.0
    targets[:, 0] = 100.0  # a wild outlier with zero weight
    res = fit_pose(targets, q + 0.05, body, weights=weights, iterations=60)
    assert torch.isfinite(res.q).all() and res.rms.max() < 2e-3


def test_limits_respected_for_unreachable_targets():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, dtype=torch.float64)
    targets = named_joint_positions(forward_kinematics(q, body))
    knee = sk.JOINT_NAMES.index("l_ankle")
    targets[0, knee, 2] -= 0.4  # ankle in front of the knee: knee would bend forwards
    res = fit_pose(targets, q, body)
    lim = torch.as_tensor(sk.DOF_LIMITS)
    assert (res.q[0, 6:] >= lim[6:, 0] - 1e-9).all() and (res.q[0, 6:] <= lim[6:, 1] + 1e-9).all()


def test_custom_markers_shape_check():
    body = BodyShape.default(torch.float64)
    m = Markers((13,), (1.0,))
    try:
        fit_pose(
            torch.zeros(1, 2, 3, dtype=torch.float64),
            rest_pose(1, dtype=torch.float64),
            body,
            markers=m,
        )
    except ValueError as err:
        assert "marker set has 1" in str(err)
    else:
        raise AssertionError("expected a ValueError")


def _torch_only(monkeypatch):
    import depthmocap.shared.ik as ik

    monkeypatch.setattr(ik, "_compiled_kernel", lambda *tensors: None)


def test_the_compiled_loop_follows_the_torch_loop(monkeypatch):
    """The CPU path (shared.ik_kernel) takes the torch loop's steps: in float64 the same poses
    and errors to rounding, over a batch with a missing marker, a prior and joints at their
    limits, and the same iteration count."""
    pytest.importorskip("numba")
    body = BodyShape.default(torch.float64)
    q = poses(6, scale=0.9, seed=3)
    targets = named_joint_positions(forward_kinematics(q, body))
    targets[1, 4] = float("nan")
    g = torch.Generator().manual_seed(2)
    targets = targets + 0.01 * torch.randn(targets.shape, generator=g, dtype=torch.float64)
    weights = torch.rand(6, len(sk.JOINT_NAMES), generator=g, dtype=torch.float64)
    q0 = q + 0.2 * torch.randn(q.shape, generator=g, dtype=torch.float64)
    args = (targets, q0, body, weights)
    compiled = fit_pose(*args, prior=1e-3, iterations=15)
    _torch_only(monkeypatch)
    reference = fit_pose(*args, prior=1e-3, iterations=15)
    assert compiled.iterations == reference.iterations
    torch.testing.assert_close(compiled.q, reference.q, atol=1e-7, rtol=0)
    torch.testing.assert_close(compiled.rms, reference.rms, atol=1e-9, rtol=0)


def test_the_compiled_loop_in_float32_and_with_autograd(monkeypatch):
    """float32 in, float32 out (computed in float64, so within float32's drift of the torch
    loop); a pose needing gradients takes the torch loop."""
    pytest.importorskip("numba")
    import depthmocap.shared.ik as ik

    body = BodyShape.default(torch.float32)
    q = poses(3, seed=4).float()
    targets = named_joint_positions(forward_kinematics(q, body))
    res = fit_pose(targets, q + 0.05, body, iterations=30)
    assert res.q.dtype == torch.float32 and res.rms.dtype == torch.float32
    assert res.rms.max() < 2e-3
    assert ik._compiled_kernel(targets.requires_grad_(True)) is None
    _torch_only(monkeypatch)
    ref = fit_pose(targets.detach(), q + 0.05, body, iterations=30)
    torch.testing.assert_close(res.q, ref.q, atol=2e-3, rtol=0)
