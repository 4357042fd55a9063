"""The learned pose prior as a tracker term (not in Wei; ``shared.pose_prior``).

Each pose takes its most likely mixture component c (the one of least cost
``1/2 d_c^2 + const_c``, ``d_c`` the Mahalanobis distance of its angles) and adds

    w^2 (a - mu_c)^T P_c (a - mu_c),   a = q[6:],

to the tracker's energy, ``w = tracker.pose_prior_weight``: ``w^2 P_c`` to the normal matrix's
angle block and ``w^2 P_c (mu_c - a)`` to its right-hand side (the data terms' convention:
``J^T W r`` with r the target minus the current value). Where the camera sees a limb its
data terms outweigh this by far; where it does not, the limb is drawn towards the angles the
rest of the pose makes likely instead of staying wherever it drifted.
"""

from __future__ import annotations

from functools import lru_cache

import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.compiled import compiled_module
from depthmocap.shared.pose_prior import PosePrior, load_pose_prior

__all__ = ["pose_prior_components", "pose_prior_system", "tracker_pose_prior"]


@lru_cache(maxsize=4)
def _load(path: str) -> PosePrior:
    return load_pose_prior(path)


def tracker_pose_prior(
    model: str, like: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The pose prior file ``model`` (relative: under the shipped ``models/``, as the hybrid's
    model files; ``shared.resources.model_file``) as means (C, A), precisions (C, A, A) and
    constant costs (C,), float64 on ``like``'s device; read once per process.

    Raises:
        shared.pose_prior.PosePriorError: a missing or unusable file.
    """
    from depthmocap.shared.resources import model_file

    return _tensors(str(model_file(model)), like.device)


@lru_cache(maxsize=8)
def _tensors(path: str, device: torch.device):
    return _load(path).tensors(torch.empty(0, device=device))


def pose_prior_components(
    q: torch.Tensor, means: torch.Tensor, precisions: torch.Tensor, log_norms: torch.Tensor
) -> torch.Tensor:
    """Each pose's most likely component (B,) long, for poses ``q`` (B, 34)."""
    d = q[:, None, sk.ANGLE_DOFS].to(means) - means  # (B, C, A)
    maha = torch.einsum("bca,cae,bce->bc", d, precisions, d)
    return (0.5 * maha + log_norms).argmin(1)


def pose_prior_system(
    q: torch.Tensor,
    means: torch.Tensor,
    precisions: torch.Tensor,
    log_norms: torch.Tensor,
    weight: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The prior's normal equations at poses ``q`` (B, 34): (B, 34, 34) and (B, 34) float64,
    zero outside the 28 angles (on the CPU without autograd: one compiled call,
    :mod:`runtime.tracker.pose_prior_kernel`)."""
    if q.device.type == "cpu" and not q.requires_grad:
        kernel = compiled_module("depthmocap.runtime.tracker.pose_prior_kernel")
        if kernel is not None:
            return kernel.pose_prior_system_cpu(q, means, precisions, log_norms, weight)
    c = pose_prior_components(q, means, precisions, log_norms)
    B, D = q.shape
    w2 = float(weight) ** 2
    prec = precisions[c]  # (B, A, A)
    r = means[c] - q[:, sk.ANGLE_DOFS].to(means)  # (B, A)
    hess = q.new_zeros(B, D, D, dtype=torch.float64)
    grad = q.new_zeros(B, D, dtype=torch.float64)
    hess[:, sk.ANGLE_DOFS, sk.ANGLE_DOFS] = w2 * prec
    grad[:, sk.ANGLE_DOFS] = w2 * torch.einsum("bae,be->ba", prec, r)
    return hess, grad
