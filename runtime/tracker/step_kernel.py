"""The tracker's Gauss-Newton update (:func:`runtime.tracker.gauss_newton.gauss_newton_step`)
as one compiled call (numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:mod:`runtime.tracker.gauss_newton` imports it lazily and keeps its torch code for GPUs,
autograd and where numba is missing.

Why: after the normal equations, each iteration adds the prior, damps, solves, holds the
joints that would leave their limits and solves again, shortens the step, applies it on SO(3)
for the root and tests it: ~90 small tensor ops, 1.3 ms an iteration whatever the batch, all
dispatch. Here the same steps run per pose in float64 with a Cholesky solve (the damped matrix
is symmetric positive definite) where torch factors by LU, so results agree with torch's to
its rounding, not to the bit.
"""

from __future__ import annotations

import numba
import numpy as np
import torch
from depthmocap.shared import ik_kernel
from depthmocap.shared import skeleton as sk

__all__ = ["gauss_newton_step_cpu"]

_LIMITS = np.ascontiguousarray(sk.DOF_LIMITS, dtype=np.float64)  # (34, 2)
_quaternion = ik_kernel._quaternion
_compose = ik_kernel._compose
cholesky_solve = ik_kernel.cholesky_solve


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _step(hess, grad, q, q_pred, prior_w2, use_prior, damping, max_angle, limits, q_out, dq_out,
          decrease):  # fmt: skip  # pragma: no cover - compiled
    B, D = grad.shape
    h = np.empty((D, D), np.float64)
    m = np.empty((D, D), np.float64)
    g = np.empty(D, np.float64)
    rhs = np.empty(D, np.float64)
    dq = np.empty(D, np.float64)
    fixed_dq = np.zeros(D, np.float64)
    fixed = np.zeros(D, np.bool_)
    for b in range(B):
        for i in range(D):
            g[i] = grad[b, i]
            for j in range(D):
                h[i, j] = hess[b, i, j]
        if use_prior:  # the prior's diagonal and w^2 (q_pred (-) q), the root as sin(a) axis
            for i in range(D):
                h[i, i] += prior_w2[i]
                if i < 3 or i >= 6:
                    g[i] += prior_w2[i] * (q_pred[b, i] - q[b, i])
            pw, px, py, pz = _quaternion(q_pred[b, 3], q_pred[b, 4], q_pred[b, 5])
            cw, cx, cy, cz = _quaternion(q[b, 3], q[b, 4], q[b, 5])
            cx, cy, cz = -cx, -cy, -cz
            w = pw * cw - (px * cx + py * cy + pz * cz)
            rx = pw * cx + cw * px + (py * cz - pz * cy)
            ry = pw * cy + cw * py + (pz * cx - px * cz)
            rz = pw * cz + cw * pz + (px * cy - py * cx)
            g[3] += prior_w2[3] * 2.0 * w * rx
            g[4] += prior_w2[4] * 2.0 * w * ry
            g[5] += prior_w2[5] * 2.0 * w * rz
        mean = 0.0
        for i in range(D):
            mean += h[i, i]
        lam = damping * mean / D + 1e-9
        for i in range(D):
            for j in range(i + 1):
                m[i, j] = h[i, j]
            m[i, i] += lam
        cholesky_solve(m, g, dq)
        # Joint angles that would leave their limits are held there; the rest solve again.
        n_fixed = 0
        for i in range(D):
            fixed[i] = False
            fixed_dq[i] = 0.0
            if i >= 6:
                want = q[b, i] + dq[i]
                target = min(max(want, limits[i, 0]), limits[i, 1])
                if target != want:
                    fixed[i] = True
                    fixed_dq[i] = target - q[b, i]
                    n_fixed += 1
        if n_fixed > 0:
            for i in range(D):
                if fixed[i]:
                    rhs[i] = fixed_dq[i]
                else:
                    t = g[i]
                    for j in range(D):
                        t -= (h[i, j] + (lam if i == j else 0.0)) * fixed_dq[j]
                    rhs[i] = t
                for j in range(i + 1):
                    if fixed[i] or fixed[j]:
                        m[i, j] = 1.0 if i == j else 0.0
                    else:
                        m[i, j] = h[i, j] + (lam if i == j else 0.0)
            cholesky_solve(m, rhs, dq)
        if max_angle > 0:
            largest = 0.0
            for i in range(3, D):
                largest = max(largest, abs(dq[i]))
            scale = min(max_angle / max(largest, 1e-12), 1.0)
            for i in range(D):
                dq[i] *= scale
        dec = 0.0
        for i in range(D):
            t = 0.0
            for j in range(D):
                t += h[i, j] * dq[j]
            dec += dq[i] * t
        decrease[b] = dec
        for i in range(D):
            dq_out[b, i] = dq[i]
            if i < 3 or i >= 6:
                v = q[b, i] + dq[i]
                q_out[b, i] = v if i < 6 else min(max(v, limits[i, 0]), limits[i, 1])
        q_out[b, 3], q_out[b, 4], q_out[b, 5] = _compose(
            dq[3], dq[4], dq[5], q[b, 3], q[b, 4], q[b, 5]
        )


def gauss_newton_step_cpu(
    hess: torch.Tensor,
    grad: torch.Tensor,
    q: torch.Tensor,
    q_pred: torch.Tensor | None,
    prior_w2: torch.Tensor,
    damping: float,
    max_angle: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The updated poses (B, 34) and steps (B, 34) in q's dtype and the predicted decreases
    (B,) float64, for CPU tensors: ``hess`` (B, 34, 34), ``grad`` (B, 34) float64 without the
    prior, ``q`` the poses linearized at, ``q_pred`` the prior's prediction (None: no prior),
    ``prior_w2`` (34,) its weights squared."""
    B, D = grad.shape
    q64 = q.double().numpy()
    q_out = np.empty((B, D), np.float64)
    dq_out = np.empty((B, D), np.float64)
    decrease = np.empty(B, np.float64)
    _step(
        np.ascontiguousarray(hess.numpy()), np.ascontiguousarray(grad.numpy()), q64,
        q64 if q_pred is None else q_pred.double().numpy(), prior_w2.double().numpy(),
        q_pred is not None, float(damping), float(max_angle), _LIMITS, q_out, dq_out, decrease,
    )  # fmt: skip
    return (
        torch.from_numpy(q_out).to(q.dtype),
        torch.from_numpy(dq_out).to(q.dtype),
        torch.from_numpy(decrease),
    )
