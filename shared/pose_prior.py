"""A pose prior learned from motion capture: a Gaussian mixture over the joint angles.

Wei's tracker holds a limb the camera does not see only by its constant-acceleration prior,
so a hidden limb keeps whatever pose it drifted into (the far arm in profile, a leg behind the
other). Real poses are not arbitrary: given the rest of the body, a hidden limb's angles are
narrowed down a good deal. A Gaussian mixture over the 28 joint angles (``q[6:]``; the root's
position and heading are the camera's business), fitted on the training split's motion capture
(``python -m depthmocap.train.mocap.pose_prior_fit``), gives each pose the cost

    E(q) = min_c [ 1/2 (a - mu_c)^T P_c (a - mu_c) - log pi_c + 1/2 log det(2 pi C_c) ],
    a = q[6:],

the negative log-likelihood of its most likely component (as SMPLify's max-component GMM
prior): each component's term is quadratic, so it enters a Gauss-Newton step exactly. The
tracker weighs it (``tracker.pose_prior_weight``) against its data terms:
:mod:`runtime.tracker.pose_prior_term`.

Shipped as ``models/pose_prior.json``:

    {"format": "depthmocap-pose-prior", "version": 1, "dof_names": [28 names],
     "weights": [C], "means": [C][28], "covariances": [C][28][28], "fitted_on": "...",
     "frames": N}
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import skeleton as sk
from .json_file import read_json_file, write_json_file

__all__ = [
    "FORMAT",
    "VERSION",
    "PosePrior",
    "PosePriorError",
    "load_pose_prior",
    "save_pose_prior",
]

FORMAT = "depthmocap-pose-prior"
VERSION = 1
# The angles the prior covers: every joint angle, none of the root's six.
ANGLE_NAMES: tuple[str, ...] = sk.DOF_NAMES[6:]


class PosePriorError(ValueError):
    """A pose-prior file that cannot be used."""


@dataclass(frozen=True)
class PosePrior:
    """A Gaussian mixture over the joint angles.

    Attributes:
        weights: (C,) mixture weights, summing to 1.
        means: (C, A) component means (A = 28 angles, radians).
        covariances: (C, A, A) symmetric positive definite.
        fitted_on: what it was fitted on; frames: how many poses.
    """

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    fitted_on: str = ""
    frames: int = 0

    def __post_init__(self) -> None:
        if np.ndim(self.means) != 2:
            raise PosePriorError(f"pose prior means must be (C, A), got {np.shape(self.means)}")
        C, A = np.shape(self.means)
        if (
            A != len(ANGLE_NAMES)
            or np.shape(self.weights) != (C,)
            or np.shape(self.covariances) != (C, A, A)
        ):
            raise PosePriorError(
                f"a pose prior needs weights (C,), means (C, {len(ANGLE_NAMES)}) and "
                f"covariances (C, {len(ANGLE_NAMES)}, {len(ANGLE_NAMES)}); got "
                f"{np.shape(self.weights)}, {np.shape(self.means)}, {np.shape(self.covariances)}"
            )
        values = (self.weights, self.means, self.covariances)
        if C == 0 or not all(np.isfinite(v).all() for v in values):
            raise PosePriorError("a pose prior needs at least one component and finite values")
        if (self.weights <= 0).any() or abs(float(self.weights.sum()) - 1.0) > 1e-6:
            raise PosePriorError(f"mixture weights must be positive and sum to 1: {self.weights}")
        if not np.allclose(self.covariances, np.swapaxes(self.covariances, 1, 2), atol=1e-9):
            raise PosePriorError("covariances must be symmetric")
        if (np.linalg.eigvalsh(self.covariances)[:, 0] <= 0).any():
            raise PosePriorError("covariances must be positive definite")

    @property
    def precisions(self) -> np.ndarray:
        """(C, A, A) the inverse covariances."""
        return np.linalg.inv(self.covariances)

    @property
    def log_norms(self) -> np.ndarray:
        """(C,) ``-log pi_c + 1/2 log det(2 pi C_c)``: each component's constant cost."""
        _, logdet = np.linalg.slogdet(self.covariances)
        A = self.means.shape[1]
        return -np.log(self.weights) + 0.5 * (logdet + A * math.log(2 * math.pi))

    def tensors(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Means (C, A), precisions (C, A, A) and constant costs (C,) on ``like``'s device,
        float64 (the normal equations' dtype)."""
        kw = {"dtype": torch.float64, "device": like.device}
        return (
            torch.as_tensor(self.means, **kw),
            torch.as_tensor(self.precisions, **kw),
            torch.as_tensor(self.log_norms, **kw),
        )

    def to_json_dict(self) -> dict:
        return {
            "format": FORMAT,
            "version": VERSION,
            "dof_names": list(ANGLE_NAMES),
            "weights": [float(w) for w in self.weights],
            "means": np.asarray(self.means, np.float64).tolist(),
            "covariances": np.asarray(self.covariances, np.float64).tolist(),
            "fitted_on": self.fitted_on,
            "frames": int(self.frames),
        }


def save_pose_prior(path: str | Path, prior: PosePrior) -> None:
    """Write ``prior`` as JSON (atomically)."""
    write_json_file(path, prior.to_json_dict())


def load_pose_prior(path: str | Path) -> PosePrior:
    """Read a pose-prior file.

    Raises:
        PosePriorError: missing or unreadable file, another format or version, angles other
            than this build's, or bad values.
    """
    path = Path(path)
    data = read_json_file(path, "pose-prior", PosePriorError)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise PosePriorError(f"{path}: not a {FORMAT} file")
    if data.get("version") != VERSION:
        raise PosePriorError(
            f"{path}: pose-prior version {data.get('version')!r}, this build reads {VERSION}"
        )
    if data.get("dof_names") != list(ANGLE_NAMES):
        raise PosePriorError(f"{path}: its angles are not this build's")
    try:
        return PosePrior(
            np.asarray(data["weights"], np.float64),
            np.asarray(data["means"], np.float64),
            np.asarray(data["covariances"], np.float64),
            str(data.get("fitted_on", "")),
            int(data.get("frames", 0)),
        )
    except (KeyError, TypeError, ValueError) as err:
        raise PosePriorError(f"{path}: {err}") from None
