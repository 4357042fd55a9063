"""Gauss-Newton helpers of the tracker (runtime.tracker.gauss_newton): the rows' Jacobian
against autograd, the limits' active set, step limiting and the predicted decrease."""

from __future__ import annotations

import pytest
import torch
from depthmocap.runtime.tracker import gauss_newton
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics, pose_update, segment_points_to_world

D = {n: i for i, n in enumerate(sk.DOF_NAMES)}

pytestmark = pytest.mark.usefixtures("one_thread")


class TestRowsJacobian:
    def test_jacobian_matches_autograd(self, make_pose):
        body = BodyShape.default(torch.float64)
        q = make_pose()
        g = torch.Generator().manual_seed(0)
        seg = torch.randint(0, 15, (40,), generator=g)
        local = torch.randn(1, 40, 3, generator=g, dtype=torch.float64) * 0.1
        direction = torch.randn(40, 3, generator=g, dtype=torch.float64)
        kin = forward_kinematics(q, body)
        points = segment_points_to_world(kin, local, seg)[0]
        rows = gauss_newton.Rows(
            torch.zeros(40, dtype=torch.long),
            points,
            seg,
            direction,
            torch.zeros(40, dtype=torch.float64),
            torch.ones(40, dtype=torch.float64),
        )
        analytic = gauss_newton.rows_jacobian(kin, rows)

        def f(dq):
            p = segment_points_to_world(
                forward_kinematics(pose_update(q, dq[None]), body), local, seg
            )
            return (p[0] * direction).sum(-1)

        numeric = torch.autograd.functional.jacobian(f, torch.zeros(34, dtype=torch.float64))
        assert torch.allclose(analytic, numeric, atol=1e-9)


class TestNormalEquations:
    @pytest.mark.parametrize("compiled", [True, False])
    @pytest.mark.parametrize("batch", [1, 3])
    def test_match_the_explicit_jacobian(self, batch, compiled, monkeypatch):
        """The per-segment moment sums give J^T W^2 J and J^T W^2 r of the explicit rows,
        each pose from its own rows only; with per-row column masks too; both the compiled
        assembly (the CPU path) and torch's."""
        if compiled:
            pytest.importorskip("numba")
        else:
            monkeypatch.setattr(gauss_newton, "_assembly_kernel", lambda: None)
        body = BodyShape.default(torch.float64)
        g = torch.Generator().manual_seed(2)
        q = torch.zeros(batch, 34, dtype=torch.float64)
        q[:, 2] = 2.5
        q[:, 6:] = 0.3 * torch.randn(batch, 28, generator=g, dtype=torch.float64)
        kin = forward_kinematics(q, body)
        n = 300
        rows = gauss_newton.Rows(
            torch.randint(0, batch, (n,), generator=g),
            torch.randn(n, 3, generator=g, dtype=torch.float64) + torch.tensor([0, 0, 2.5]),
            torch.randint(0, 15, (n,), generator=g),
            torch.randn(n, 3, generator=g, dtype=torch.float64),
            torch.randn(n, generator=g, dtype=torch.float64),
            torch.rand(n, generator=g, dtype=torch.float64),
        )
        jac = gauss_newton.rows_jacobian(kin, rows) * rows.weight[:, None]
        res = rows.residual * rows.weight
        columns = (torch.rand(n, 34, generator=g) > 0.3).double()
        hess, grad = gauss_newton.normal_equations(kin, rows, batch)
        hess_c, grad_c = gauss_newton.normal_equations(kin, rows, batch, columns)
        for b in range(batch):
            mine = rows.batch == b
            j, r = jac[mine], res[mine]
            torch.testing.assert_close(hess[b], j.T @ j, atol=1e-9, rtol=1e-9)
            torch.testing.assert_close(grad[b], j.T @ r, atol=1e-9, rtol=1e-9)
            jc = j * columns[mine]
            torch.testing.assert_close(hess_c[b], jc.T @ jc, atol=1e-9, rtol=1e-9)
            torch.testing.assert_close(grad_c[b], jc.T @ r, atol=1e-9, rtol=1e-9)

    @pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
    def test_compiled_normal_equations_equal_torch(self, monkeypatch, dtype):
        """The compiled normal equations (the CPU path) agree with torch's batched products
        to rounding, batched or not, and so does the column-masked form; rows of zero weight
        add nothing."""
        pytest.importorskip("numba")
        g = torch.Generator().manual_seed(3)
        body = BodyShape.default(torch.float64)
        q = torch.zeros(3, 34, dtype=torch.float64)
        q[:, 2] = 2.5
        q[:, 6:] = 0.3 * torch.randn(3, 28, generator=g, dtype=torch.float64)
        kin = forward_kinematics(q.to(dtype), body.to(dtype))
        rows = gauss_newton.Rows(
            torch.randint(0, 3, (400,), generator=g),
            torch.randn(400, 3, generator=g, dtype=torch.float64) + torch.tensor([0, 0, 2.5]),
            torch.randint(0, 15, (400,), generator=g),
            torch.randn(400, 3, generator=g, dtype=torch.float64),
            torch.randn(400, generator=g, dtype=torch.float64),
            torch.rand(400, generator=g, dtype=torch.float64),
        )
        rows.weight[::7] = 0.0
        for field in ("points", "direction", "residual", "weight"):
            setattr(rows, field, getattr(rows, field).to(dtype))
        columns = (torch.rand(400, 34, generator=g) > 0.3).to(dtype)
        compiled = gauss_newton.normal_equations(kin, rows, 3)
        compiled_c = gauss_newton.normal_equations(kin, rows, 3, columns)
        monkeypatch.setattr(gauss_newton, "_assembly_kernel", lambda: None)
        reference = gauss_newton.normal_equations(kin, rows, 3)
        reference_c = gauss_newton.normal_equations(kin, rows, 3, columns)
        for got, want in zip(compiled + compiled_c, reference + reference_c, strict=True):
            assert got.dtype == torch.float64
            tol = 1e-12 if dtype == torch.float64 else 1e-5
            torch.testing.assert_close(got, want, rtol=tol, atol=tol * want.abs().max())


class TestSolveStep:
    def test_golden(self, make_pose):
        """The limits' active set keeps joints inside: a hyper-extending elbow stays put."""
        q = make_pose()
        q[0, D["l_radius_flex"]] = 0.0
        hess = torch.eye(34, dtype=torch.float64)[None]
        grad = torch.zeros(1, 34, dtype=torch.float64)
        grad[0, D["l_radius_flex"]] = -0.5  # wants hyper-extension
        grad[0, D["l_humerus_abd"]] = 0.1
        dq = gauss_newton.solve_step(hess, grad, q, 0.0)
        assert float(dq[0, D["l_radius_flex"]]) == pytest.approx(0.0, abs=1e-12)
        assert float(dq[0, D["l_humerus_abd"]]) == pytest.approx(0.1, rel=1e-6)


class TestLimitStep:
    def test_golden(self):
        """Long steps are shortened along their direction; short ones are unchanged."""
        dq = torch.zeros(2, 34, dtype=torch.float64)
        dq[0, 0], dq[0, D["l_femur_twist"]], dq[0, D["head_x"]] = 0.3, 0.5, -0.1
        dq[1, D["head_x"]] = 0.05
        out = gauss_newton.limit_step(dq, 0.2)
        assert torch.allclose(out[0], dq[0] * 0.4)  # 0.5 rad -> 0.2: the whole step x 0.4
        assert torch.equal(out[1], dq[1])  # short enough: unchanged
        assert torch.equal(gauss_newton.limit_step(dq, 0.0), dq)


class TestPredictedDecrease:
    def test_golden(self):
        """The predicted decrease is the quadratic model's."""
        hess = torch.diag(torch.tensor([4.0, 1.0], dtype=torch.float64))[None].repeat(2, 1, 1)
        hess[1, 0, 1] = hess[1, 1, 0] = 1.0
        dq = torch.tensor([[0.5, 2.0], [1.0, -1.0]])
        # 4 * 0.25 + 4 = 5; 4 + 1 - 2 * 1 = 3
        assert gauss_newton.predicted_decrease(hess, dq).tolist() == [5.0, 3.0]
        # For the Gauss-Newton step dq = H^-1 g it is the drop of the quadratic model
        # g.dq - dq'H dq/2 times two.
        g = torch.tensor([[1.0, 2.0]], dtype=torch.float64)
        step = torch.linalg.solve(hess[1:], g[..., None])[..., 0]
        drop = 2 * (g * step).sum() - gauss_newton.predicted_decrease(hess[1:], step)
        assert torch.allclose(gauss_newton.predicted_decrease(hess[1:], step), drop)


class TestGaussNewtonStep:
    @pytest.mark.parametrize("use_prior", [True, False])
    def test_compiled_update_equals_torch(self, make_pose, monkeypatch, use_prior):
        """The compiled update (the CPU path: prior, damped Cholesky solve, the limits'
        active set, the step limit, the SO(3) root update) agrees with torch's LU path to
        float32 rounding, with joints pushed past their limits and a root turned by the
        prior."""
        pytest.importorskip("numba")
        g = torch.Generator().manual_seed(5)
        B = 4
        q = make_pose().expand(B, -1).clone()
        q[:, 3:6] += 0.2 * torch.randn(B, 3, generator=g, dtype=q.dtype)
        q_pred = q + 0.05 * torch.randn(B, 34, generator=g, dtype=q.dtype)
        a = torch.randn(B, 60, 34, generator=g, dtype=torch.float64)
        hess = a.transpose(1, 2) @ a
        grad = 40.0 * torch.randn(B, 34, generator=g, dtype=torch.float64)
        grad[:, D["l_radius_flex"]] = -500.0  # past the elbow's limit: held there
        args = (hess, grad, q, q_pred if use_prior else None, 0.1, 0.3, 0.2, 0.05)
        compiled = gauss_newton.gauss_newton_step(*args)
        monkeypatch.setattr(gauss_newton, "_step_kernel", lambda: None)
        reference = gauss_newton.gauss_newton_step(*args)
        q_new, dq, decrease = compiled
        assert q_new.dtype == q.dtype and dq.dtype == q.dtype and decrease.dtype == torch.float64
        torch.testing.assert_close(q_new, reference[0], rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(dq, reference[1], rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(decrease, reference[2], rtol=1e-4, atol=1e-6)
        assert dq[:, 3:].abs().max() <= 0.3 + 1e-6  # the step limit bites
        lower, upper = (torch.as_tensor(sk.DOF_LIMITS, dtype=q.dtype)[:, i] for i in (0, 1))
        assert bool(((q_new[:, 6:] >= lower[6:]) & (q_new[:, 6:] <= upper[6:])).all())
