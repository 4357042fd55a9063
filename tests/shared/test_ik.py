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
