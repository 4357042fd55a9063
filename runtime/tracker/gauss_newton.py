"""Linearized residual rows, the normal equations, and the limited Gauss-Newton step.

Every data term of Wei's appendix A linearizes to rows of the form

    w * g^T (dp/dq) dq = w * r

for a model surface point p fixed on segment k, a direction g (3,) in camera frame, a residual
r and a weight w: the depth term's g is the surface normal (eq. 15), the extra depth term uses
the three camera axes (eq. 17), the silhouette term the distance-transform gradient pulled back
through the projection (eq. 16). A revolute DoF with world axis a through o moves p by
``a x (p - o)``, so its entry is ``g . (a x (p - o)) = (p x g) . a + g . (o x a)``: one (N, 6) @
(6, 31) product per iteration instead of the (N, 3, 34) point Jacobian. The root rotation's
columns are those of the left SO(3) increment (:func:`shared.kinematics.pose_update`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.compiled import compiled_module
from depthmocap.shared.kinematics import Kinematics, clamp_to_limits, pose_update
from depthmocap.shared.least_squares import damped, solve, solve_with_fixed

from .prior_term import prior_system, prior_weights
from .regions import batch_slots

__all__ = [
    "Rows",
    "cat_rows",
    "lever_table",
    "rows_jacobian",
    "normal_equations",
    "solve_step",
    "limit_step",
    "apply_step",
    "predicted_decrease",
    "gauss_newton_step",
]


@dataclass
class Rows:
    """N linearized residuals of the data terms.

    Attributes:
        batch: (N,) int64 pose each row belongs to.
        points: (N, 3) camera-frame model surface points (at the current pose).
        segment: (N,) int64 segment each point is fixed on.
        direction: (N, 3) g: the row is g^T dp/dq.
        residual: (N,) r (target of the linearized model).
        weight: (N,) w (1 / sigma times the subsampling compensation).
    """

    batch: torch.Tensor
    points: torch.Tensor
    segment: torch.Tensor
    direction: torch.Tensor
    residual: torch.Tensor
    weight: torch.Tensor

    def __len__(self) -> int:
        return int(self.residual.shape[0])


def cat_rows(rows: list[Rows]) -> Rows:
    """Concatenate the rows of several terms."""
    return Rows(*(torch.cat([getattr(r, f) for r in rows]) for f in Rows.__dataclass_fields__))


def lever_table(kin: Kinematics) -> torch.Tensor:
    """(B, 6, 34) per pose: a row's Jacobian entries are its lever ``(p x g, g)`` (6,) times
    this table, whose columns are ``(0, e_i)`` for the root translations and ``(a, o x a)``
    for the rotational DoFs (axis a through o), before the chain mask."""
    B = kin.origins.shape[0]
    axes = kin.dof_axes[:, 3:]  # (B, 31, 3)
    moments = torch.linalg.cross(kin.dof_origins[:, 3:], axes, dim=-1)
    rot = torch.cat([axes, moments], -1).transpose(1, 2)  # (B, 6, 31)
    eye = torch.eye(3, dtype=axes.dtype, device=axes.device)
    trans = torch.cat([torch.zeros_like(eye), eye], 0).expand(B, 6, 3)
    return torch.cat([trans, rot], 2)


def _levers(rows: Rows) -> torch.Tensor:
    g = rows.direction
    return torch.cat([torch.linalg.cross(rows.points, g, dim=-1), g], -1)  # (N, 6)


@functools.cache
def _affects(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(15, 34) 1 where DoF d moves segment k (its chain from the root), else 0."""
    return torch.as_tensor(sk.DOF_AFFECTS_SEGMENT, dtype=dtype, device=device)


@functools.cache
def _chain_masks(device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """(K, 34) float64 :func:`_affects` and (34, K, 34) its per-segment products
    ``a_k[i] a_k[j]``: which Hessian entries a row on segment k reaches."""
    affects = _affects(torch.float64, device)
    return affects, affects.T[:, :, None] * affects[None]


def _assembly_kernel():
    """:mod:`runtime.tracker.normal_kernel` (numba's compiled normal equations), or None
    without numba."""
    return compiled_module("depthmocap.runtime.tracker.normal_kernel")


def rows_jacobian(kin: Kinematics, rows: Rows) -> torch.Tensor:
    """Jacobian rows g^T dp/dq: (N, 34)."""
    g = rows.direction
    table = lever_table(kin)
    lever = _levers(rows)
    if table.shape[0] == 1:
        jac = lever @ table[0]
    else:  # each row against its own pose's table only
        jac = (lever[:, None, :] @ table.index_select(0, rows.batch))[:, 0]
    return jac * _affects(g.dtype, g.device)[rows.segment]


def normal_equations(
    kin: Kinematics, rows: Rows, batch_size: int, columns: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Sum of w^2 J^T J and w^2 J^T r per pose: (B, 34, 34), (B, 34), float64.

    ``columns`` (N, 34), if given, multiplies the Jacobian rows: a term measured between two
    segments drops the DoFs that move both alike (:mod:`runtime.tracker.collision_term`).

    A row's Jacobian is its lever ``l = (p x g, g)`` times its pose's :func:`lever_table`
    ``T`` masked to its segment's chain (``T_k``), so the sums need only each (pose,
    segment)'s 6 x 6 moments ``sum w^2 l l^T`` and ``sum w^2 r l``: ``H = sum_k T_k^T M_k
    T_k``. N rows cost N outer products of 6 instead of N x 34 Jacobian entries; the moments
    are summed in float64.
    """
    if columns is not None:
        return _normal_equations_with_columns(kin, rows, batch_size, columns)
    K, B = sk.NUM_SEGMENTS, batch_size
    grads = rows.points.requires_grad or rows.direction.requires_grad
    grads = grads or rows.residual.requires_grad or rows.weight.requires_grad
    table = lever_table(kin).double()  # (B, 6, 34)
    cpu = table.device.type == "cpu" and not (grads or table.requires_grad)
    assembly = _assembly_kernel() if cpu else None
    if assembly is not None:
        return assembly.normal_equations_cpu(
            rows.points, rows.direction, rows.residual, rows.weight, rows.batch, rows.segment,
            table,
        )  # fmt: skip
    w = rows.weight.double()
    lever = _levers(rows).double() * w[:, None]  # (N, 6)
    ext = torch.cat([lever, (rows.residual.double() * w)[:, None]], 1)  # (N, 7)
    group = rows.batch * K + rows.segment
    stats = lever.new_zeros(B * K, 6, 7).index_add_(0, group, lever[:, :, None] * ext[:, None])
    D = table.shape[-1]
    # T^T M_k T for every segment k in two batched products, then each masked to the DoFs
    # that move segment k (a_k a_k^T) and summed over k.
    mt = stats[..., :6].reshape(B, K * 6, 6) @ table  # (B, K 6, D): M_k T
    tmt = table.transpose(1, 2) @ mt.reshape(B, K, 6, D).transpose(1, 2).reshape(B, 6, K * D)
    affects, mask = _chain_masks(lever.device)
    hess = (tmt.reshape(B, D, K, D) * mask).sum(2)
    tm = table.transpose(1, 2) @ stats[..., 6].reshape(B, K, 6).transpose(1, 2)  # (B, D, K)
    grad = (tm * affects.T).sum(2)
    return hess, grad


def _normal_equations_with_columns(
    kin: Kinematics, rows: Rows, batch_size: int, columns: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`normal_equations` with per-row column masks: the Jacobian rows themselves."""
    grads = rows.points.requires_grad or rows.direction.requires_grad
    grads = grads or kin.dof_axes.requires_grad or kin.dof_origins.requires_grad
    assembly = _assembly_kernel() if columns.device.type == "cpu" and not grads else None
    if assembly is not None:
        return assembly.column_rows_cpu(
            _levers(rows), rows.residual, rows.weight, rows.batch, rows.segment, columns,
            lever_table(kin).double(), batch_size,
        )  # fmt: skip
    jac = rows_jacobian(kin, rows) * (rows.weight[:, None] * columns)
    res = rows.residual * rows.weight
    if batch_size == 1:
        jt = jac.T[None]
        res = res[None]
    else:  # rows grouped by pose, zero-padded: (B, K, 34), not a (B, 34, N) mask product
        slot, real = batch_slots(rows.batch, batch_size)
        jac = jac[slot] * real[..., None]
        res = res[slot] * real
        jt = jac.transpose(1, 2)
    hess = (jt @ jac).double()
    grad = (jt @ res[..., None])[..., 0].double()
    return hess, grad


def solve_step(
    hess: torch.Tensor, grad: torch.Tensor, q: torch.Tensor, damping: float
) -> torch.Tensor:
    """Damped Gauss-Newton increment, with joint limits as a one-pass active set.

    After the unconstrained solve, joint angles that would leave their limits are fixed at the
    limit and the remaining DoFs are solved again with that fixed contribution moved to the
    right-hand side, so the other joints can compensate
    (:func:`shared.least_squares.solve_with_fixed`). The damping is uniform: ``damping`` times
    the mean curvature, so one setting suits poses whatever their data's scale. (B, 34) in q's
    dtype.
    """
    diag = hess.diagonal(dim1=-2, dim2=-1)
    lam = damping * diag.mean(-1, keepdim=True) + 1e-9
    matrix = damped(hess, lam.expand_as(diag))
    dq = solve(matrix, grad)
    q64 = q.double()
    target = clamp_to_limits(q64 + dq)
    fixed = torch.zeros_like(dq, dtype=torch.bool)
    fixed[:, 6:] = (target - (q64 + dq)).abs()[:, 6:] > 0
    fixed_dq = torch.where(fixed, target - q64, torch.zeros_like(dq))
    dq = solve_with_fixed(matrix, grad, fixed, fixed_dq)
    return dq.to(q.dtype)


def limit_step(dq: torch.Tensor, max_angle: float) -> torch.Tensor:
    """Shorten each (B, 34) step along its direction so no joint angle (nor the root rotation)
    changes by more than ``max_angle`` radians; ``max_angle <= 0`` leaves it unchanged.

    Scaling towards zero keeps a step that respects the joint limits inside them (the limits
    are a box around q).
    """
    if max_angle <= 0:
        return dq
    largest = dq[:, 3:].abs().amax(1, keepdim=True)
    return dq * (max_angle / largest.clamp_min(1e-12)).clamp(max=1.0)


def apply_step(q: torch.Tensor, dq: torch.Tensor) -> torch.Tensor:
    """``q (+) dq``, clamped to the joint limits."""
    return clamp_to_limits(pose_update(q, dq))


def predicted_decrease(hess: torch.Tensor, dq: torch.Tensor) -> torch.Tensor:
    """``dq^T H dq`` per pose, (B,): the energy the linearized model expects the Gauss-Newton
    step ``dq = H^-1 g`` to remove, in units of the noise scales squared.

    A step along a direction the data hardly constrain (a straight arm's twist) can be large in
    radians yet remove almost nothing; this measures the step in the energy's own metric.
    """
    d = dq.to(hess.dtype)
    return (d[:, None, :] @ hess @ d[:, :, None])[:, 0, 0]


def _step_kernel():
    """:mod:`runtime.tracker.step_kernel` (numba's compiled update), or None without numba."""
    return compiled_module("depthmocap.runtime.tracker.step_kernel")


def gauss_newton_step(
    hess: torch.Tensor,
    grad: torch.Tensor,
    q: torch.Tensor,
    q_pred: torch.Tensor | None,
    damping: float,
    max_angle: float,
    sigma_rad: float,
    sigma_m: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One tracker update from the data terms' normal equations: add the constant-acceleration
    prior towards ``q_pred`` (None: no prior), :func:`solve_step`, :func:`limit_step` to
    ``max_angle``, :func:`apply_step`.

    Args:
        hess, grad: (B, 34, 34), (B, 34) float64, the data terms' normal equations at q.
        q: (B, 34) the poses they were linearized at.
    Returns:
        the new poses (B, 34), the steps taken (B, 34), both in q's dtype, and each step's
        :func:`predicted_decrease` (B,) under the prior-augmented normal matrix.
    """
    kernel = _step_kernel() if q.device.type == "cpu" and not q.requires_grad else None
    if kernel is not None and not (hess.requires_grad or grad.requires_grad):
        w = prior_weights(q[:1], sigma_rad, sigma_m)[0]
        w2 = w * w  # as prior_system squares them, in q's dtype
        return kernel.gauss_newton_step_cpu(hess, grad, q, q_pred, w2, damping, max_angle)
    if q_pred is not None:
        diag, rhs, _ = prior_system(q, q_pred, sigma_rad, sigma_m)
        hess = hess + torch.diag_embed(diag.double())
        grad = grad + rhs.double()
    dq = limit_step(solve_step(hess, grad, q, damping), max_angle)
    return apply_step(q, dq), dq, predicted_decrease(hess, dq)
