import math

import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import (
    clamp_to_limits,
    forward_kinematics,
    named_joint_positions,
    point_jacobian,
    pose_update,
    rest_pose,
    segment_points_to_world,
)
from depthmocap.shared.so3 import rotvec_to_matrix

J = {n: i for i, n in enumerate(sk.JOINT_NAMES)}


def random_poses(batch, dtype, device, seed=0, scale=0.5):
    g = torch.Generator().manual_seed(seed)
    q = rest_pose(batch, dtype=dtype)
    lim = torch.as_tensor(sk.DOF_LIMITS[6:], dtype=dtype)
    u = torch.rand(batch, 28, generator=g, dtype=dtype)
    q[:, 6:] = (lim[:, 0] + u * (lim[:, 1] - lim[:, 0])) * scale
    q[:, 3:6] += 0.5 * torch.randn(batch, 3, generator=g, dtype=dtype)
    q[:, 0:3] += 0.3 * torch.randn(batch, 3, generator=g, dtype=dtype)
    return q.to(device)


def joints(q, body=None):
    body = BodyShape.default(q.dtype, q.device) if body is None else body
    return named_joint_positions(forward_kinematics(q, body))


def test_rest_pose_golden(device, dtype):
    p = joints(rest_pose(1, (0.0, 0.0, 2.5), dtype, device))[0].cpu().double().numpy()
    # Body frame (x left, y up, z forward) maps to camera (x, -y, -z) when facing the camera.
    np.testing.assert_allclose(p[J["pelvis"]], [0, 0, 2.5], atol=1e-6)
    np.testing.assert_allclose(p[J["l_hip"]], [0.09, 0, 2.5], atol=1e-6)
    np.testing.assert_allclose(p[J["r_knee"]], [-0.09, 0.43, 2.5], atol=1e-6)
    np.testing.assert_allclose(p[J["l_ankle"]], [0.09, 0.85, 2.5], atol=1e-6)
    np.testing.assert_allclose(p[J["neck"]], [0, -0.52, 2.5], atol=1e-6)
    np.testing.assert_allclose(p[J["l_shoulder"]], [0.18, -0.52, 2.5], atol=1e-6)
    np.testing.assert_allclose(p[J["r_wrist"]], [-0.18, 0.03, 2.5], atol=1e-6)
    np.testing.assert_allclose(p[J["head"]], [0, -0.52 - 0.10 - 0.45 * 0.22, 2.5], atol=1e-6)


def test_joint_angles_golden(dtype):
    q = rest_pose(1, (0.0, 0.0, 2.5), dtype)
    q[0, sk.DOF_NAMES.index("l_radius_flex")] = math.pi / 2  # forearm points forward
    q[0, sk.DOF_NAMES.index("r_tibia_flex")] = math.pi / 2  # shank points backward
    q[0, sk.DOF_NAMES.index("l_humerus_abd")] = math.pi / 2  # right arm stays; left goes out
    p = joints(q)[0].double().numpy()
    # left arm abducted 90 deg: horizontal towards +x; elbow bent 90 deg: forearm forward.
    np.testing.assert_allclose(p[J["l_elbow"]], [0.18 + 0.29, -0.52, 2.5], atol=1e-6)
    np.testing.assert_allclose(p[J["l_wrist"]], [0.47, -0.52, 2.5 - 0.26], atol=1e-6)
    np.testing.assert_allclose(p[J["r_ankle"]], [-0.09, 0.43, 2.5 + 0.42], atol=1e-6)
    # Mirrored axes: the same angle on the right means the same motion.
    q2 = rest_pose(1, (0.0, 0.0, 2.5), dtype)
    q2[0, sk.DOF_NAMES.index("r_humerus_abd")] = math.pi / 2
    q2[0, sk.DOF_NAMES.index("r_radius_flex")] = math.pi / 2
    p2 = joints(q2)[0].double().numpy()
    np.testing.assert_allclose(p2[J["r_wrist"]], [-0.47, -0.52, 2.24], atol=1e-6)


def test_chest_tilt_leans_neck_and_shoulders_forward():
    body = BodyShape.default(torch.float64)
    body.chest_tilt = torch.tensor(0.2, dtype=torch.float64)
    q = rest_pose(1, (0.0, 0.0, 2.5), torch.float64)
    p = joints(q, body)[0].numpy()
    upright = joints(q)[0].double().numpy()
    # The chest (spine -> neck) leans forward (camera -z when facing it) by 0.2 rad.
    chest = float(body.lengths[2])
    lean = np.array([0.0, -chest * math.cos(0.2), -chest * math.sin(0.2)])
    np.testing.assert_allclose(p[J["neck"]], p[J["spine"]] + lean, atol=1e-9)
    np.testing.assert_allclose(p[J["l_shoulder"]] - p[J["neck"]], [0.18, 0, 0], atol=1e-9)
    np.testing.assert_allclose(p[J["pelvis"]], upright[J["pelvis"]], atol=1e-9)  # below: same
    np.testing.assert_allclose(p[J["l_ankle"]], upright[J["l_ankle"]], atol=1e-9)


def test_clavicle_rest_adds_to_clavicle_angles():
    """A body's clavicle rest turns both clavicles as their DoFs would (mirrored), so the
    shoulders drop and move forward; limits and priors then act around the rest. The arms
    still hang straight down at q = 0 and reach straight up at 180 degrees of abduction."""
    body = BodyShape.default(torch.float64)
    body.clavicle_rest = torch.tensor([-0.4, 0.2], dtype=torch.float64)
    q = rest_pose(1, (0.0, 0.0, 2.5), torch.float64)
    p = joints(q, body)[0].numpy()
    q_angles = q.clone()
    q_angles[0, list(sk.CLAVICLE_DOFS)] = torch.tensor([-0.4, 0.2, -0.4, 0.2]).double()
    by_angles = joints(q_angles)[0].numpy()
    for name in ("l_shoulder", "r_shoulder", "neck", "head", "l_ankle"):
        np.testing.assert_allclose(p[J[name]], by_angles[J[name]], atol=1e-12)
    for s in "lr":  # camera y points down: the elbow lies one upper arm below the shoulder
        down = p[J[f"{s}_elbow"]] - p[J[f"{s}_shoulder"]]
        np.testing.assert_allclose(down, [0.0, 0.29, 0.0], atol=1e-12)
    q[0, sk.DOF_NAMES.index("l_humerus_abd")] = math.pi
    p_up = joints(q, body)[0].numpy()
    up = p_up[J["l_elbow"]] - p_up[J["l_shoulder"]]
    np.testing.assert_allclose(up, [0.0, -0.29, 0.0], atol=1e-12)
    # Facing the camera (camera y down, z towards the person): the left shoulder lies 18 cm
    # along (cos p cos e, cos p sin e, sin p) of the body frame, i.e. lower and nearer.
    e, pr = -0.4, 0.2
    rel = 0.18 * np.array([math.cos(pr) * math.cos(e), -math.cos(pr) * math.sin(e), -math.sin(pr)])
    np.testing.assert_allclose(p[J["l_shoulder"]] - p[J["neck"]], rel, atol=1e-12)
    mirrored = p[J["r_shoulder"]] - p[J["neck"]]
    np.testing.assert_allclose(mirrored, rel * [-1, 1, 1], atol=1e-12)


def test_root_rotation_turns_whole_body():
    q = rest_pose(1, (0.0, 0.0, 2.5), torch.float64)
    # Person turned to show their left side: left shoulder now nearer the camera.
    q[0, 3:6] = torch.tensor([math.pi, 0.0, 0.0])
    r_turn = torch.tensor([0.0, math.pi / 2, 0.0], dtype=torch.float64)
    q_turn = pose_update(q, torch.cat([torch.zeros(3), r_turn, torch.zeros(28)])[None].double())
    p = joints(q_turn)[0].numpy()
    assert p[J["l_shoulder"]][2] < 2.5 - 0.17 and abs(p[J["l_shoulder"]][0]) < 1e-6


def test_bone_lengths_preserved_and_batch_consistent(device, dtype):
    q = random_poses(64, dtype, device)
    body = BodyShape.default(dtype, device)
    kin = forward_kinematics(q, body)
    parent = torch.as_tensor(sk.SEGMENT_PARENT[1:], device=device)
    rest = forward_kinematics(rest_pose(1, dtype=dtype, device=device), body)
    d = (kin.origins[:, 1:] - kin.origins[:, parent]).norm(dim=-1)
    d0 = (rest.origins[:, 1:] - rest.origins[:, parent]).norm(dim=-1)
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    assert torch.allclose(d, d0.expand_as(d), atol=tol)
    eye = torch.eye(3, dtype=dtype, device=device)
    ortho = kin.rotations @ kin.rotations.transpose(-1, -2)
    assert torch.allclose(ortho, eye.expand_as(ortho), atol=10 * tol)
    # Each pose alone gives the same as in the batch.
    single = forward_kinematics(q[5:6], body)
    assert torch.allclose(single.origins, kin.origins[5:6], atol=tol)


def test_batched_bodies():
    q = random_poses(3, torch.float64, "cpu")
    body = BodyShape.default(torch.float64)
    scales = torch.tensor([0.8, 1.0, 1.2], dtype=torch.float64)
    big = body.scaled(scales)
    p = joints(q, big)
    for i, s in enumerate(scales):
        pi = joints(q[i : i + 1], body.scaled(s))
        assert torch.allclose(p[i], pi[0], atol=1e-12)
    # Scaling the body about the root scales joint offsets from the root.
    rel = p - q[:, None, :3]
    rel1 = joints(q, body) - q[:, None, :3]
    assert torch.allclose(rel, rel1 * scales[:, None, None], atol=1e-12)


def test_empty_batch(device):
    kin = forward_kinematics(torch.zeros(0, 34, device=device), BodyShape.default(device=device))
    assert kin.origins.shape == (0, 15, 3)


def test_bad_shape_raises():
    with pytest.raises(ValueError, match="q must have shape"):
        forward_kinematics(torch.zeros(3, 33), BodyShape.default())


def _setup_points(B=4, N=40, seed=1):
    q = random_poses(B, torch.float64, "cpu", seed=seed)
    g = torch.Generator().manual_seed(seed)
    seg = torch.randint(0, 15, (B, N), generator=g)
    local = 0.1 * torch.randn(B, N, 3, generator=g, dtype=torch.float64)
    return q, seg, local


def test_jacobian_matches_autograd():
    body = BodyShape.default(torch.float64)
    q, seg, local = _setup_points()
    kin = forward_kinematics(q, body)
    p = segment_points_to_world(kin, local, seg)
    jac = point_jacobian(kin, p, seg)

    def f(dq):
        return segment_points_to_world(forward_kinematics(pose_update(q, dq), body), local, seg)

    auto = torch.autograd.functional.jacobian(f, torch.zeros_like(q))  # (B, N, 3, B, 34)
    auto = torch.stack([auto[b, :, :, b] for b in range(q.shape[0])])
    rel = (jac - auto).abs().max() / auto.abs().max()
    assert rel < 1e-6, rel


def test_jacobian_matches_finite_differences():
    body = BodyShape.default(torch.float64)
    body.chest_tilt = torch.tensor(0.25, dtype=torch.float64)  # a rest rotation in the chain
    body.clavicle_rest = torch.tensor([-0.35, 0.15], dtype=torch.float64)
    q, seg, local = _setup_points(B=2, N=25, seed=3)
    kin = forward_kinematics(q, body)
    jac = point_jacobian(kin, segment_points_to_world(kin, local, seg), seg)
    eps = 1e-6
    fd = torch.zeros_like(jac)
    for d in range(34):
        dq = torch.zeros_like(q)
        dq[:, d] = eps
        plus = segment_points_to_world(forward_kinematics(pose_update(q, dq), body), local, seg)
        minus = segment_points_to_world(forward_kinematics(pose_update(q, -dq), body), local, seg)
        fd[..., d] = (plus - minus) / (2 * eps)
    rel = (jac - fd).abs().max() / fd.abs().max()
    assert rel < 1e-6, rel


def test_jacobian_sparsity_follows_tree():
    body = BodyShape.default(torch.float64)
    q = random_poses(1, torch.float64, "cpu")
    kin = forward_kinematics(q, body)
    seg = torch.tensor([sk.SEGMENT_NAMES.index("l_forearm")])
    jac = point_jacobian(
        kin, segment_points_to_world(kin, torch.zeros(1, 1, 3).double() + 0.1, seg), seg
    )[0, 0]
    moving = set(np.nonzero(jac.abs().sum(0).numpy() > 0)[0].tolist())
    leg = {sk.DOF_NAMES.index(n) for n in ("l_femur_flex", "r_tibia_flex", "head_x")}
    assert not moving & leg
    assert sk.DOF_NAMES.index("l_radius_flex") in moving  # the point is off the elbow axis
    assert {sk.DOF_NAMES.index("l_humerus_abd"), sk.DOF_NAMES.index("lower_back_x")} <= moving


def test_jacobian_on_device(device):
    body = BodyShape.default(torch.float32, device)
    q = random_poses(2, torch.float32, device)
    kin = forward_kinematics(q, body)
    seg = torch.arange(15, device=device)
    pts = segment_points_to_world(kin, torch.full((2, 15, 3), 0.05, device=device), seg)
    jac = point_jacobian(kin, pts, seg)
    assert jac.shape == (2, 15, 3, 34) and jac.device.type == device.type
    assert jac.dtype == torch.float32 and torch.isfinite(jac).all()


def test_pose_update_root_on_manifold():
    q = random_poses(8, torch.float64, "cpu")
    same = pose_update(q, torch.zeros_like(q))
    # The root rotation vector may be re-canonicalized (angle <= pi): compare rotations.
    assert torch.allclose(same[:, :3], q[:, :3]) and torch.allclose(same[:, 6:], q[:, 6:])
    assert torch.allclose(rotvec_to_matrix(same[:, 3:6]), rotvec_to_matrix(q[:, 3:6]), atol=1e-12)
    # Large root increments never leave SO(3) or produce NaN (no gimbal lock).
    dq = torch.zeros_like(q)
    dq[:, 3:6] = torch.tensor([0.0, math.pi / 2, 0.0])
    for _ in range(4):
        q = pose_update(q, dq)
    assert torch.isfinite(q).all()
    assert q[:, 3:6].norm(dim=-1).max() <= math.pi + 1e-9


def test_clamp_to_limits():
    q = torch.full((1, 34), 10.0, dtype=torch.float64)
    c = clamp_to_limits(q)
    assert torch.equal(c[:, :6], q[:, :6])
    assert torch.allclose(c[0, 6:], torch.as_tensor(sk.DOF_LIMITS[6:, 1]))


def test_transform_pose_moves_every_joint_rigidly():
    from depthmocap.shared.kinematics import transform_pose

    q = random_poses(5, torch.float64, "cpu")
    rot = rotvec_to_matrix(torch.tensor([0.3, -1.2, 2.0], dtype=torch.float64))
    t = torch.tensor([0.1, 0.2, -0.3], dtype=torch.float64)
    moved = joints(transform_pose(q, rot, t))
    expected = joints(q) @ rot.T + t
    assert torch.allclose(moved, expected, atol=1e-10)


def test_skeleton_constants_are_built_once_per_content_dtype_and_device():
    """On CUDA each fresh constant was a host-to-device copy and a sync; the cache hands
    out one tensor per content, dtype and device, equal to a fresh one."""
    from depthmocap.shared import kinematics as kin_module

    like = torch.zeros(1, dtype=torch.float32)
    a = kin_module._const([1.0, -1.0, 2.0], like)
    assert kin_module._const((1.0, -1.0, 2.0), like) is a  # same content, same tensor
    assert torch.equal(a, torch.tensor([1.0, -1.0, 2.0]))
    b = kin_module._const([1.0, -1.0, 2.0], like.double())
    assert b is not a and b.dtype == torch.float64
    i = kin_module._index([3, 1], like)
    assert i.dtype == torch.long and kin_module._index(np.array([3, 1]), like) is i
    assert kin_module._index([3, 2], like) is not i


def test_constants_first_made_in_inference_mode_still_serve_autograd(monkeypatch):
    """runtime-track estimates in torch.inference_mode; the skeleton's cached constants it
    creates there must not break a later autograd pass in the same process (the Python API
    tracks, then a caller differentiates)."""
    import depthmocap.shared.kinematics as kinematics

    monkeypatch.setattr(kinematics, "_CONSTANTS", {})  # made afresh below, in inference mode
    body = BodyShape.default()
    q = rest_pose(2, (0.0, 0.0, 2.5))
    with torch.inference_mode():
        named_joint_positions(forward_kinematics(pose_update(q, torch.zeros_like(q)), body))

    def joints(dq):
        return named_joint_positions(forward_kinematics(pose_update(q, dq), body)).sum(0)

    jac = torch.autograd.functional.jacobian(joints, torch.zeros_like(q), vectorize=True)
    assert torch.isfinite(jac).all() and jac.abs().sum() > 0
