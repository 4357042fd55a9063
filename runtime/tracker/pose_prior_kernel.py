"""The learned pose prior's normal equations (:mod:`runtime.tracker.pose_prior_term`) as one
compiled call (numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra); the
term imports it lazily and keeps its torch code for GPUs, autograd and where numba is
missing. Why: the torch version is a dozen small tensor ops, about 0.2 ms an iteration, all
dispatch, for a few thousand multiply-adds. Both CPU paths of an iteration (term by term and
:mod:`runtime.tracker.iteration_kernel`) use this one, so their poses stay the same to the
bit; its sums run in another order than torch's einsum, so it agrees with the torch code to
rounding.
"""

from __future__ import annotations

import numba
import numpy as np
import torch
from depthmocap.shared import skeleton as sk

__all__ = ["pose_prior_system_cpu"]

_FIRST_ANGLE = sk.ANGLE_DOFS.start


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _pose_prior(q, means, precisions, log_norms, w2, hess, grad):  # pragma: no cover - compiled
    B = q.shape[0]
    C, A = means.shape
    a = np.empty(A, np.float64)
    r = np.empty(A, np.float64)
    for b in range(B):
        for i in range(A):
            a[i] = q[b, _FIRST_ANGLE + i]
        best, best_cost = 0, np.inf
        for c in range(C):
            maha = 0.0
            for i in range(A):
                r[i] = a[i] - means[c, i]
            for i in range(A):
                row = 0.0
                for j in range(A):
                    row += precisions[c, i, j] * r[j]
                maha += r[i] * row
            cost = 0.5 * maha + log_norms[c]
            if cost < best_cost:
                best, best_cost = c, cost
        for i in range(A):
            r[i] = means[best, i] - a[i]
        for i in range(A):
            row = 0.0
            for j in range(A):
                p = precisions[best, i, j]
                hess[b, _FIRST_ANGLE + i, _FIRST_ANGLE + j] = w2 * p
                row += p * r[j]
            grad[b, _FIRST_ANGLE + i] = w2 * row


def pose_prior_system_cpu(
    q: torch.Tensor,
    means: torch.Tensor,
    precisions: torch.Tensor,
    log_norms: torch.Tensor,
    weight: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`~runtime.tracker.pose_prior_term.pose_prior_system` on the CPU: (B, 34, 34) and
    (B, 34) float64 for poses ``q`` (B, 34)."""
    B, D = q.shape
    hess = np.zeros((B, D, D), np.float64)
    grad = np.zeros((B, D), np.float64)
    _pose_prior(
        q.detach().numpy().astype(np.float64), means.numpy(), precisions.numpy(),
        log_norms.numpy(), float(weight) ** 2, hess, grad,
    )  # fmt: skip
    return torch.from_numpy(hess), torch.from_numpy(grad)
