"""The collision term's leg samples (``legs=True``): each leg's axis kept out of the other
leg's capsules. Which samples and targets, rows only for legs laid into each other, the
Jacobian against autograd, Gauss-Newton separating crossed legs, and the compiled rows
against the torch ones (the fused iteration with them: ``test_iteration_kernel``)."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.runtime.raycast import segment_geometry
from depthmocap.runtime.tracker import collision_term
from depthmocap.runtime.tracker.gauss_newton import normal_equations, rows_jacobian, solve_step
from depthmocap.runtime.tracker.label_term import capsule_offsets
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics, pose_update, rest_pose

ARM_SAMPLES, LEG_SAMPLES = collision_term.ARM_SAMPLES, collision_term.LEG_SAMPLES
collision_rows = collision_term.collision_rows
collision_samples = collision_term.collision_samples

pytestmark = pytest.mark.usefixtures("one_thread")

D = {n: i for i, n in enumerate(sk.DOF_NAMES)}
SEG = {n: i for i, n in enumerate(sk.SEGMENT_NAMES)}
M_ARMS = len(ARM_SAMPLES)


def _crossed_legs_pose(adduction_deg: float = -15.0, dtype=torch.float64) -> torch.Tensor:
    """Standing, the right leg swung in across the left: at -15 degrees the knees are 7 cm
    apart and the shanks cross above the ankles."""
    q = rest_pose(1, root_position=(0.0, 0.1, 2.4), dtype=dtype)
    q[0, D["r_femur_abd"]] = math.radians(adduction_deg)
    return q


def _leg_depths(q: torch.Tensor, body: BodyShape) -> torch.Tensor:
    """Signed distance (B, L) of each leg sample to the nearest of its target capsules."""
    kin = forward_kinematics(q, body)
    geom = segment_geometry(body, q)
    samples = collision_samples(legs=True)
    points, _ = collision_term.collision_sample_points(kin, legs=True)
    rot, origin = geom.frames(kin)
    B = q.shape[0]
    out = torch.empty(B, len(LEG_SAMPLES), dtype=q.dtype)
    for b in range(B):
        for i in range(len(LEG_SAMPLES)):
            m = M_ARMS + i
            signed = [
                capsule_offsets(points[b, m][None], rot[b, k][None], origin[b, k][None],
                                geom.basis[k][None], geom.span[k][None], geom.scale[k][None])[0]
                for k in samples.targets[m]
            ]  # fmt: skip
            out[b, i] = torch.cat(signed).min()
    return out


def test_leg_samples_keep_out_of_the_other_leg():
    arms, both = collision_samples(legs=False), collision_samples(legs=True)
    assert both.segment[:M_ARMS] == arms.segment and both.targets[:M_ARMS] == arms.targets
    assert len(both.segment) == M_ARMS + len(LEG_SAMPLES)
    for m in range(M_ARMS, len(both.segment)):
        name = sk.SEGMENT_NAMES[both.segment[m]]
        other = "r" if name.startswith("l_") else "l"
        assert name.split("_", 1)[1] in ("thigh", "shank") and both.kind[m] == 2
        targets = {sk.SEGMENT_NAMES[t] for t in both.targets[m]}
        assert targets == {f"{other}_thigh", f"{other}_shank"}
    # Each side's samples end at the knee and the ankle.
    for side in "lr":
        ends = {s for s, f in LEG_SAMPLES if f == 1.0 and sk.SEGMENT_NAMES[s][0] == side}
        assert ends == {SEG[f"{side}_thigh"], SEG[f"{side}_shank"]}
    assert collision_term.sample_tolerances(both)[M_ARMS:] == (
        (collision_term.COLLISION_LEG_TOLERANCE_M,) * len(LEG_SAMPLES)
    )


def test_no_leg_rows_with_the_legs_apart_or_without_legs():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, root_position=(0.0, 0.1, 2.4), dtype=torch.float64)
    q[0, D["l_femur_abd"]] = q[0, D["r_femur_abd"]] = math.radians(8)
    assert bool((_leg_depths(q, body) > 0).all())
    rows, columns = collision_rows(forward_kinematics(q, body), segment_geometry(body, q), True)
    assert len(rows) == M_ARMS + len(LEG_SAMPLES) and columns.shape == (len(rows), sk.NUM_DOFS)
    assert bool((rows.weight == 0).all())
    # Crossed legs give leg rows only with legs=True; the arm rows stay as they were.
    q = _crossed_legs_pose()
    kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
    arms_only, _ = collision_rows(kin, geom)
    with_legs, _ = collision_rows(kin, geom, legs=True)
    assert len(arms_only) == M_ARMS and bool((arms_only.weight == 0).all())
    torch.testing.assert_close(with_legs.weight[:M_ARMS], arms_only.weight)
    assert bool((with_legs.weight[M_ARMS:] > 0).any())


def test_leg_rows_act_only_deeper_than_the_tolerance(monkeypatch):
    body = BodyShape.default(torch.float64)
    q = _crossed_legs_pose()
    depth = _leg_depths(q, body)[0]
    kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
    monkeypatch.setattr(collision_term, "SIGMA_COLLISION_M", 0.004)
    for tolerance in (0.0, 0.01, 0.03):
        monkeypatch.setattr(collision_term, "COLLISION_LEG_TOLERANCE_M", tolerance)
        rows, _ = collision_rows(kin, geom, legs=True)
        inside = depth < -tolerance
        assert bool(inside.any()) and bool((~inside).any())
        torch.testing.assert_close(rows.weight[M_ARMS:], inside.double() / 0.004)
        torch.testing.assert_close(rows.residual[M_ARMS:], (-tolerance - depth).clamp_min(0))
        # The argument (TrackerConfig.leg_collision_tolerance_m) gives the same rows as the
        # constant, whatever the constant holds.
        monkeypatch.setattr(collision_term, "COLLISION_LEG_TOLERANCE_M", 0.05)
        given, _ = collision_rows(kin, geom, legs=True, leg_tolerance=tolerance)
        torch.testing.assert_close(given.weight, rows.weight)
        torch.testing.assert_close(given.residual, rows.residual)
    # Both legs get rows: the left leg's samples lie in the right leg as much as the reverse.
    left = torch.tensor([sk.SEGMENT_NAMES[s].startswith("l_") for s, _ in LEG_SAMPLES])
    act = rows.weight[M_ARMS:] > 0
    assert bool(act[left].any()) and bool(act[~left].any())


def test_the_leg_tolerance_setting_reaches_the_tolerance_table():
    from depthmocap.runtime.tracker.config import TrackerConfig, TrackerConfigError

    samples = collision_samples(legs=True)
    tolerances = collision_term.sample_tolerances(samples, 0.02)
    assert tolerances[M_ARMS:] == (0.02,) * len(LEG_SAMPLES)
    assert tolerances[:M_ARMS] == collision_term.sample_tolerances(samples)[:M_ARMS]
    assert TrackerConfig(leg_collision_tolerance_m=0.02).leg_collision_tolerance_m == 0.02
    for bad in (-0.01, math.nan, math.inf):
        with pytest.raises(TrackerConfigError, match="leg_collision_tolerance_m"):
            TrackerConfig(leg_collision_tolerance_m=bad)


def test_leg_collision_jacobian_matches_autograd(monkeypatch):
    """A leg row predicts how far its point leaves the other leg when its own leg moves; the
    DoFs that move the other leg's capsule (the root's, the other hip's and knee's) get no
    column: that leg has rows of its own."""
    body = BodyShape.default(torch.float64)  # round leg capsules: the exact distance
    q = _crossed_legs_pose()
    q[0, D["r_femur_flex"]] = math.radians(4)  # off the plane: every DoF matters
    q[0, D["l_tibia_flex"]] = math.radians(-8)
    kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
    monkeypatch.setattr(collision_term, "COLLISION_LEG_TOLERANCE_M", 0.0)
    rows, columns = collision_rows(kin, geom, legs=True)
    act = (rows.weight > 0)[M_ARMS:]
    assert int(act.sum()) >= 3
    analytic = (rows_jacobian(kin, rows) * columns)[M_ARMS:][act]
    numeric = torch.autograd.functional.jacobian(
        lambda dq: _leg_depths(pose_update(q, dq[None]), body)[0],
        torch.zeros(sk.NUM_DOFS, dtype=torch.float64),
    )[act]
    seg = torch.tensor([s for s, _ in LEG_SAMPLES])[act]
    own = torch.as_tensor(sk.DOF_AFFECTS_SEGMENT)[seg].bool()  # (A, 34): moves the point
    kept = columns[M_ARMS:][act].bool()
    assert bool((own[:, :6]).all()) and not bool(kept[:, :6].any())
    # The point's own leg's columns (those the target does not move) match autograd.
    check = own & kept
    assert bool(check.any(1).all())
    torch.testing.assert_close(analytic[check], numeric[check], atol=1e-6, rtol=1e-4)
    assert bool((analytic[~kept] == 0).all())


def test_gauss_newton_separates_crossed_legs(monkeypatch):
    body = BodyShape.default(torch.float64)
    q = _crossed_legs_pose()
    monkeypatch.setattr(collision_term, "COLLISION_LEG_TOLERANCE_M", 0.0)
    monkeypatch.setattr(collision_term, "SIGMA_COLLISION_M", 0.005)
    assert _leg_depths(q, body).min() < -0.03
    for _ in range(8):
        kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
        rows, columns = collision_rows(kin, geom, legs=True)
        hess, grad = normal_equations(kin, rows, 1, columns)
        hess = hess + torch.eye(sk.NUM_DOFS, dtype=torch.float64) * 1e-2  # a weak prior
        q = pose_update(q, solve_step(hess, grad, q, 1e-3))
    assert _leg_depths(q, body).min() > -0.005
    # Only the legs moved; the root, the torso and the arms kept their values.
    leg_dofs = ("l_femur", "r_femur", "l_tibia", "r_tibia")
    legs = [i for i, n in enumerate(sk.DOF_NAMES) if n.startswith(leg_dofs)]
    others = [i for i in range(sk.NUM_DOFS) if i not in legs]
    torch.testing.assert_close(q[0, others], _crossed_legs_pose()[0, others])


def test_the_compiled_leg_rows_are_the_torch_rows_bit_for_bit(assert_same_rows, monkeypatch):
    pytest.importorskip("depthmocap.runtime.tracker.collision_kernel")
    body = BodyShape.default(torch.float32)
    q = rest_pose(3, root_position=(0.0, 0.1, 2.5))
    q[1, D["r_femur_abd"]] = -0.25  # the right leg across the left
    q[2, D["l_femur_abd"]], q[2, D["l_tibia_flex"]] = -0.3, -0.4  # the left across, bent
    q[2, D["l_humerus_abd"]] = -0.5  # and the left arm into the torso
    kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
    got, got_columns = collision_rows(kin, geom, legs=True)
    monkeypatch.setattr(collision_term, "compiled_float32", lambda name, *t: None)
    want, want_columns = collision_rows(kin, geom, legs=True)
    assert bool((want.weight[M_ARMS:] > 0).any()) and bool((want.weight == 0).any())
    assert_same_rows(got, want)
    assert torch.equal(got_columns, want_columns)
