"""The damped normal-equation solve (shared.least_squares): the damped step solves the damped
system, and held unknowns keep their values while the free ones solve their rows with the
held contribution on the right-hand side."""

from __future__ import annotations

import torch
from depthmocap.shared.least_squares import damped, damped_solve, solve, solve_with_fixed


def _system(batch: int = 3, n: int = 6, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    a = torch.randn(batch, 2 * n, n, generator=gen, dtype=torch.float64)
    return a.transpose(1, 2) @ a, torch.randn(batch, n, generator=gen, dtype=torch.float64)


def test_damped_solve_solves_the_damped_system():
    hess, grad = _system()
    damping = 0.1 * hess.diagonal(dim1=-2, dim2=-1)
    x = damped_solve(hess, grad, damping)
    residual = (hess @ x[..., None])[..., 0] + damping * x - grad
    assert residual.abs().max() < 1e-10
    assert torch.equal(
        damped(hess, damping).diagonal(dim1=-2, dim2=-1), hess.diagonal(0, -2, -1) + damping
    )


def test_unbatched_system():
    hess, grad = _system(batch=1)
    assert torch.equal(solve(hess[0], grad[0]), solve(hess, grad)[0])


def test_solve_with_fixed_holds_values_and_solves_the_free_rows():
    hess, grad = _system()
    fixed = torch.zeros_like(grad, dtype=torch.bool)
    fixed[0, 1] = fixed[1, [0, 4]] = True
    value = torch.where(fixed, torch.full_like(grad, 0.25), torch.zeros_like(grad))
    x = solve_with_fixed(hess, grad, fixed, value)
    assert torch.equal(x[fixed], value[fixed])
    residual = (hess @ x[..., None])[..., 0] - grad
    assert residual[~fixed].abs().max() < 1e-10
    nothing = torch.zeros_like(fixed)
    torch.testing.assert_close(solve_with_fixed(hess, grad, nothing, 0 * grad), solve(hess, grad))


def test_solve_on_every_device_solves_the_system(device):
    """On a GPU the solve skips its error check (no host sync): the same solution."""
    hess, grad = _system()
    x = solve(hess.to(device), grad.to(device)).cpu()
    assert ((hess @ x[..., None])[..., 0] - grad).abs().max() < 1e-10
