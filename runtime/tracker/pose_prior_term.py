"""The learned pose prior (``shared.pose_prior``) as the tracker uses it.

``TrackerConfig.pose_prior`` names the artifact (relative names under the shipped ``models/``
folder) and ``pose_prior_scale`` widens it: each angle's Gaussian has ``scale * std``. The
file is read once per name; :func:`pose_prior_weights` gives what
:func:`runtime.tracker.gauss_newton.gauss_newton_step` folds into Wei's prior.
"""

from __future__ import annotations

import functools
from pathlib import Path

import torch
from depthmocap.shared.pose_prior import PosePriorError, angle_weights, load_pose_prior

from .config import TrackerConfig

__all__ = ["PosePriorError", "pose_prior_weights", "resolve_pose_prior"]


def resolve_pose_prior(name: str) -> Path:
    """``name`` as a path: absolute as given, relative under the shipped models/ folder."""
    from depthmocap.shared.resources import MODELS_DIR

    path = Path(name)
    return path if path.is_absolute() else MODELS_DIR / path


@functools.lru_cache(maxsize=8)
def _weights(name: str, scale: float) -> tuple[torch.Tensor, torch.Tensor]:
    mean, w2 = angle_weights(load_pose_prior(resolve_pose_prior(name)), scale)
    return torch.from_numpy(mean), torch.from_numpy(w2)


def pose_prior_weights(
    cfg: TrackerConfig, like: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """The configured pose prior's mean (34,) and weights squared (34,) in ``like``'s dtype
    and device, or None when ``cfg.pose_prior`` is unset.

    Raises:
        PosePriorError: the file is missing, unreadable or of another format or version.
    """
    if not cfg.pose_prior:
        return None
    mean, w2 = _weights(str(cfg.pose_prior), float(cfg.pose_prior_scale))
    return mean.to(like), w2.to(like)

