"""The tracker's collision term: arm sample points (golden values), rows only for arms inside
the torso, its Jacobian against autograd, and Gauss-Newton pushing a folded arm out."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from depthmocap.runtime.raycast import segment_geometry
from depthmocap.runtime.tracker import Tracker, TrackerConfig, collision_term
from depthmocap.runtime.tracker.collision_term import (
    ARM_SAMPLES,
    HAND_SAMPLES,
    TORSO_SEGMENTS,
    arm_sample_points,
    collision_rows,
)
from depthmocap.runtime.tracker.gauss_newton import normal_equations, rows_jacobian, solve_step
from depthmocap.runtime.tracker.label_term import capsule_offsets
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import forward_kinematics, pose_update, rest_pose

pytestmark = pytest.mark.usefixtures("one_thread")

D = {n: i for i, n in enumerate(sk.DOF_NAMES)}


def _round_torso_body() -> BodyShape:
    """The default body with circular torso sections: there the capsule's signed distance
    is exact and its gradient is the row's direction."""
    body = BodyShape.default(torch.float64)
    radii = body.radii.clone()
    for k in TORSO_SEGMENTS:
        radii[k] = radii[k].mean()
    return dataclasses.replace(body, radii=radii)


def _folded_arm_pose() -> torch.Tensor:
    """Left upper arm swung in towards the body, forearm bent across it: the axis runs up to
    6 cm deep through the torso. The right arm hangs at the side."""
    q = rest_pose(1, root_position=(0.0, 0.1, 2.4), dtype=torch.float64)
    q[0, D["l_humerus_abd"]] = math.radians(-20)
    q[0, D["l_radius_flex"]] = math.radians(150)
    q[0, D["lower_back_x"]] = math.radians(10)
    return q


def _depths(q: torch.Tensor, body: BodyShape) -> torch.Tensor:
    """Signed distance (B, M) of each arm sample point to its nearest torso capsule."""
    kin = forward_kinematics(q, body)
    geom = segment_geometry(body, q)
    points, _ = arm_sample_points(kin)
    rot, origin = geom.frames(kin)
    out = []
    for k in TORSO_SEGMENTS:
        n = points.shape[1]
        out.append(
            capsule_offsets(
                points[0],
                rot[0, k].expand(n, 3, 3),
                origin[0, k].expand(n, 3),
                geom.basis[k].expand(n, 3, 3),
                geom.span[k].expand(n, 2),
                geom.scale[k].expand(n, 3),
            )[0]  # fmt: skip
        )
    return torch.stack(out, -1).min(-1).values[None]


def test_arm_sample_points_golden_values():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, root_position=(0.0, 0.0, 2.0), dtype=torch.float64)
    kin = forward_kinematics(q, body)
    points, seg = arm_sample_points(kin)
    assert points.shape == (1, len(ARM_SAMPLES), 3)
    assert seg.tolist() == [s for s, _ in ARM_SAMPLES]
    for m, (s, frac) in enumerate(ARM_SAMPLES):
        axis = kin.rotations[0, s] @ torch.as_tensor(sk.SEGMENT_AXIS[s], dtype=torch.float64)
        expected = kin.origins[0, s] + frac * body.lengths[s] * axis
        torch.testing.assert_close(points[0, m], expected)
    # The last upper-arm sample of each side is its elbow.
    for side in "lr":
        upper = sk.SEGMENT_NAMES.index(f"{side}_upper_arm")
        fore = sk.SEGMENT_NAMES.index(f"{side}_forearm")
        m = max(i for i, (s, f) in enumerate(ARM_SAMPLES) if s == upper)
        torch.testing.assert_close(points[0, m], kin.origins[0, fore])


def test_no_rows_act_with_the_arms_outside_the_torso():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, root_position=(0.0, 0.1, 2.4), dtype=torch.float64)
    q[0, D["l_humerus_abd"]] = q[0, D["r_humerus_abd"]] = math.radians(30)
    assert bool((_depths(q, body) > 0).all())
    rows, columns = collision_rows(forward_kinematics(q, body), segment_geometry(body, q))
    assert len(rows) == len(ARM_SAMPLES) and columns.shape == (len(ARM_SAMPLES), sk.NUM_DOFS)
    assert bool((rows.weight == 0).all()) and bool((rows.residual == 0).all())


def test_rows_act_only_deeper_than_the_tolerance(monkeypatch):
    body = BodyShape.default(torch.float64)
    q = _folded_arm_pose()
    depth = _depths(q, body)[0]
    kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
    hand = torch.tensor(HAND_SAMPLES)
    on_hand = [(sk.SEGMENT_NAMES[s], f) for (s, f), h in zip(ARM_SAMPLES, HAND_SAMPLES) if h]
    assert len(on_hand) == 4 and all(n.endswith("forearm") and f > 0.5 for n, f in on_hand)
    monkeypatch.setattr(collision_term, "SIGMA_COLLISION_M", 0.004)
    for tolerance, hand_tolerance in ((0.0, 0.0), (0.03, 0.03), (0.01, 0.05)):
        monkeypatch.setattr(collision_term, "COLLISION_TOLERANCE_M", tolerance)
        monkeypatch.setattr(collision_term, "COLLISION_HAND_TOLERANCE_M", hand_tolerance)
        rows, _ = collision_rows(kin, geom)
        allowed = torch.where(hand, hand_tolerance, tolerance).double()
        inside = depth < -allowed
        assert bool(inside.any()), "the folded arm must reach into the torso"
        torch.testing.assert_close(rows.weight, inside.double() / 0.004)
        torch.testing.assert_close(rows.residual, (-allowed - depth).clamp_min(0))
    # Only the left arm is folded in.
    left = torch.tensor([sk.SEGMENT_NAMES[s].startswith("l_") for s, _ in ARM_SAMPLES])
    assert bool((rows.weight[~left] == 0).all()) and bool((rows.weight[left] > 0).any())


def test_collision_jacobian_matches_autograd(monkeypatch):
    body = _round_torso_body()
    q = _folded_arm_pose()
    kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
    monkeypatch.setattr(collision_term, "COLLISION_TOLERANCE_M", 0.0)
    monkeypatch.setattr(collision_term, "COLLISION_HAND_TOLERANCE_M", 0.0)
    rows, columns = collision_rows(kin, geom)
    act = rows.weight > 0
    assert int(act.sum()) >= 3
    analytic = (rows_jacobian(kin, rows) * columns)[act]
    numeric = torch.autograd.functional.jacobian(
        lambda dq: _depths(pose_update(q, dq[None]), body)[0],
        torch.zeros(sk.NUM_DOFS, dtype=torch.float64),
    )[act]
    # The row predicts how far the point moves out of the torso: the depth's increase. The
    # root's and the torso's own DoFs move point and capsule together: zero columns.
    torch.testing.assert_close(analytic, numeric, atol=1e-6, rtol=1e-4)
    assert bool((analytic[:, :6] == 0).all())
    assert bool(analytic[:, D["l_humerus_abd"]].abs().max() > 0)


def test_gauss_newton_pushes_a_folded_arm_out(monkeypatch):
    body = BodyShape.default(torch.float64)
    q = _folded_arm_pose()
    monkeypatch.setattr(collision_term, "COLLISION_TOLERANCE_M", 0.01)
    monkeypatch.setattr(collision_term, "COLLISION_HAND_TOLERANCE_M", 0.01)
    monkeypatch.setattr(collision_term, "SIGMA_COLLISION_M", 0.005)
    start = _depths(q, body).min()
    assert start < -0.04
    for _ in range(8):
        kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
        rows, columns = collision_rows(kin, geom)
        hess, grad = normal_equations(kin, rows, 1, columns)
        hess = hess + torch.eye(sk.NUM_DOFS, dtype=torch.float64) * 1e-2  # a weak prior
        q = pose_update(q, solve_step(hess, grad, q, 1e-3))
    assert _depths(q, body).min() > -0.012
    # Only the left arm moved; the torso, the root and the right arm kept their values.
    left_arm = [i for i, n in enumerate(sk.DOF_NAMES) if n.startswith(("l_clavicle", "l_humerus",
                                                                        "l_radius"))]  # fmt: skip
    others = [i for i in range(sk.NUM_DOFS) if i not in left_arm]
    torch.testing.assert_close(q[0, others], _folded_arm_pose()[0, others])


def test_tracker_with_the_collision_term_runs():
    intr = Intrinsics.kinect_v1(160)
    body = BodyShape.default()
    q = _folded_arm_pose().float()[0]
    from depthmocap.runtime.raycast import render_body

    depth = render_body(q[None], body, intr).depth[0]
    res = Tracker(body, intr, TrackerConfig(use_collision=True)).step(depth, depth > 0, q)
    assert torch.isfinite(res.q).all() and res.overlap > 0.9


def test_a_batch_gives_the_rows_of_each_pose():
    body = BodyShape.default(torch.float64)
    q = torch.cat([_folded_arm_pose(), rest_pose(1, root_position=(0.2, 0.0, 3.0),
                                                 dtype=torch.float64)])  # fmt: skip
    q[1, D["r_humerus_abd"]] = math.radians(-30)  # the second pose's right arm swings in
    kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
    both, both_columns = collision_rows(kin, geom)
    hess, grad = normal_equations(kin, both, 2, both_columns)
    M = len(ARM_SAMPLES)
    assert both.batch.tolist() == [0] * M + [1] * M
    for b in range(2):
        one = q[b : b + 1]
        k1, g1 = forward_kinematics(one, body), segment_geometry(body, one)
        rows, columns = collision_rows(k1, g1)
        sl = slice(b * M, (b + 1) * M)
        torch.testing.assert_close(both.residual[sl], rows.residual)
        torch.testing.assert_close(both.weight[sl], rows.weight)
        torch.testing.assert_close(both_columns[sl], columns)
        h1, g1_ = normal_equations(k1, rows, 1, columns)
        torch.testing.assert_close(hess[b], h1[0])
        torch.testing.assert_close(grad[b], g1_[0])
        assert bool((rows.weight > 0).any())


def test_the_compiled_term_gives_the_torch_rows_bit_for_bit(assert_same_rows, monkeypatch):
    """runtime.tracker.collision_kernel (one compiled call, CPU float32) against the torch
    code it replaces, on poses with the arms out and swung into the torso: the same rows
    and columns to the bit, contacts included."""
    pytest.importorskip("depthmocap.runtime.tracker.collision_kernel")
    body = BodyShape.default(torch.float32)
    q = rest_pose(3, root_position=(0.0, 0.1, 2.5))
    q[1, D["l_humerus_abd"]] = -0.5  # the left arm into the torso
    q[2, D["l_humerus_abd"]], q[2, D["l_radius_flex"]] = -1.5, 2.5  # and across it
    q[2, D["r_humerus_flex"]] = 1.5  # the right arm forward, clear
    kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
    got, got_columns = collision_term.collision_rows(kin, geom)
    monkeypatch.setattr(collision_term, "compiled_float32", lambda name, *t: None)
    want, want_columns = collision_term.collision_rows(kin, geom)
    assert bool((want.weight > 0).any()) and bool((want.weight == 0).any())
    assert_same_rows(got, want)
    assert torch.equal(got_columns, want_columns)
