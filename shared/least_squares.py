"""Damped normal equations: the one linear solve behind every Gauss-Newton/LM fit here.

Three fits linearize their residuals and solve ``(H + diag(d)) dx = g`` for the step: the
inverse kinematics (:mod:`shared.ik`), the tracker (:mod:`runtime.tracker.gauss_newton`) and
the shape personalization (:mod:`runtime.personalize.fit`). They differ in how they scale the
damping d (per-parameter curvature, mean curvature, a floor) and in what they do with limits
afterwards, so each builds its own d; the solve, and the solve with some unknowns held at
given values (the tracker's joint-limit active set), live here once.

Shapes are batch-first: ``hess`` (..., n, n), ``grad``/``damping`` (..., n); an unbatched
(n, n) system works too. The operations are kept in a fixed order, so a caller gets the same
bits as the inline code it replaced.
"""

from __future__ import annotations

import torch

__all__ = ["damped", "solve", "damped_solve", "solve_with_fixed"]


def damped(hess: torch.Tensor, damping: torch.Tensor) -> torch.Tensor:
    """``H + diag(d)``: (..., n, n) from hess (..., n, n) and damping (..., n)."""
    return hess + torch.diag_embed(damping)


def solve(matrix: torch.Tensor, rhs: torch.Tensor) -> torch.Tensor:
    """``A^-1 b`` for A (..., n, n) and b (..., n): (..., n).

    On a GPU the factorization's error check is skipped (``solve_ex``), since reading it makes
    the host wait for the device twice per Gauss-Newton iteration; a singular A then gives
    non-finite values instead of an error. The callers' matrices are damped, so positive
    definite."""
    if matrix.device.type == "cpu":
        return torch.linalg.solve(matrix, rhs[..., None])[..., 0]
    return torch.linalg.solve_ex(matrix, rhs[..., None])[0][..., 0]


def damped_solve(hess: torch.Tensor, grad: torch.Tensor, damping: torch.Tensor) -> torch.Tensor:
    """The damped step ``(H + diag(d))^-1 g``: (..., n).

    Damping bounds the step where the residuals hardly constrain a parameter (H nearly
    singular), trading Gauss-Newton's fast convergence for gradient descent's safety.
    """
    return solve(damped(hess, damping), grad)


def solve_with_fixed(
    matrix: torch.Tensor, rhs: torch.Tensor, fixed: torch.Tensor, value: torch.Tensor
) -> torch.Tensor:
    """Solve ``A x = b`` for the free unknowns with ``x[fixed] = value[fixed]`` held: (B, n).

    Holding some unknowns (a joint at its limit) moves their contribution ``A[:, fixed] value``
    to the right-hand side, so the free unknowns can compensate for what the held ones cannot
    do; solving the reduced system with an identity block for the held rows keeps the batch
    one (B, n, n) solve.

    Args:
        matrix: (B, n, n) A, e.g. the damped normal matrix.
        rhs: (B, n) b.
        fixed: (B, n) bool, the unknowns to hold.
        value: (B, n) their values; must be zero where not ``fixed``.
    """
    free = ~fixed
    both = free[:, :, None] & free[:, None, :]
    reduced = torch.where(both, matrix, torch.zeros_like(matrix))
    reduced = reduced + torch.diag_embed(fixed.to(matrix.dtype))
    moved = torch.where(free, rhs - (matrix @ value[..., None])[..., 0], value)
    return solve(reduced, moved)
