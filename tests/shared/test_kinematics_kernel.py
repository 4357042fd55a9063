"""The compiled forward kinematics (numba) against the torch walk it replaces on the CPU."""

from __future__ import annotations

import pytest
import torch
from depthmocap.shared import kinematics as kinematics_module
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics

kernel = pytest.importorskip("depthmocap.shared.kinematics_kernel")

FIELDS = ("rotations", "origins", "dof_axes", "dof_origins", "lengths")


def _random_poses(n: int, dtype: torch.dtype, seed: int = 0) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    lim = torch.as_tensor(sk.DOF_LIMITS, dtype=dtype).clamp(-3.0, 3.0)
    q = lim[:, 0] + torch.rand(n, sk.NUM_DOFS, generator=gen, dtype=dtype) * (lim[:, 1] - lim[:, 0])
    q[:, :3] = torch.randn(n, 3, generator=gen, dtype=dtype)
    q[:, 3:6] = 2.0 * torch.randn(n, 3, generator=gen, dtype=dtype)
    q[0, 3:6] = 0.0  # the root's small-angle series
    q[1, 3:6] = 1e-6
    return q


def _torch_walk(q: torch.Tensor, body: BodyShape):
    """The torch code path: autograd on the pose forces it."""
    with torch.enable_grad():
        return forward_kinematics(q.clone().requires_grad_(True), body)


@pytest.mark.parametrize("dtype, tol", [(torch.float32, 2e-6), (torch.float64, 1e-12)])
def test_matches_torch_walk(dtype, tol):
    body = BodyShape.default(dtype)
    # A body with clavicle rest, chest tilt and lateral hips all non-zero.
    body.clavicle_rest = torch.tensor([0.2, -0.1], dtype=dtype)
    body.chest_tilt = torch.tensor(0.15, dtype=dtype)
    q = _random_poses(32, dtype)
    ref = _torch_walk(q, body)
    got = kernel.forward_kinematics_cpu(q, body)
    for name, value in zip(FIELDS, got):
        expected = getattr(ref, name).detach()
        assert value.dtype == dtype and value.shape == expected.shape, name
        torch.testing.assert_close(value, expected, atol=tol, rtol=0, msg=name)


def test_batched_bodies():
    """Pose b with body b: the size search fits one start per candidate body."""
    base = BodyShape.default(torch.float32)
    bodies = [base.scaled(s) for s in (0.9, 1.0, 1.1)]
    batched = base.scaled(torch.tensor([0.9, 1.0, 1.1]))
    q = _random_poses(3, torch.float32, seed=1)
    got = kernel.forward_kinematics_cpu(q, batched)
    for b, body in enumerate(bodies):
        ref = _torch_walk(q[b : b + 1], body)
        for name, value in zip(FIELDS, got):
            torch.testing.assert_close(value[b : b + 1], getattr(ref, name).detach(), atol=2e-6,
                                       rtol=0, msg=name)  # fmt: skip


def test_empty_batch():
    got = kernel.forward_kinematics_cpu(torch.zeros(0, sk.NUM_DOFS), BodyShape.default())
    assert [tuple(v.shape) for v in got] == [(0, 15, 3, 3), (0, 15, 3), (0, 34, 3), (0, 34, 3),
                                             (0, 15)]  # fmt: skip


def test_dispatch_keeps_autograd(monkeypatch):
    """Without gradients the CPU uses the kernel; with them, the differentiable walk."""
    calls = []
    real = kernel.forward_kinematics_cpu
    monkeypatch.setattr(kernel, "forward_kinematics_cpu", lambda *a: calls.append(1) or real(*a))
    body = BodyShape.default()
    q = _random_poses(2, torch.float32)
    with torch.no_grad():
        forward_kinematics(q, body)
    assert calls == [1]
    qg = q.clone().requires_grad_(True)
    kin = forward_kinematics(qg, body)
    kin.origins.sum().backward()
    assert calls == [1] and qg.grad is not None and qg.grad.abs().sum() > 0
    lengths = body.lengths.clone().requires_grad_(True)
    body.lengths = lengths
    forward_kinematics(q, body).origins.sum().backward()
    assert calls == [1] and lengths.grad is not None


def test_without_numba_the_walk_is_torch(monkeypatch):
    monkeypatch.setattr(kinematics_module, "_compiled_kernel", lambda: None)
    q = _random_poses(4, torch.float64)
    body = BodyShape.default(torch.float64)
    got = forward_kinematics(q, body)
    ref = kernel.forward_kinematics_cpu(q, body)
    torch.testing.assert_close(got.rotations, ref[0], atol=1e-12, rtol=0)
