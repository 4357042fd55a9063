"""A Gaussian over the body's joint angles, learned from motion capture: where an unseen limb
most likely is, given the rest of the body.

The tracker's own prior (Wei's constant acceleration) knows nothing of bodies: a limb the
camera does not see keeps whatever the last frames gave it. Across many people and motions the
joint angles are strongly correlated (arms swing against the legs, a squatting body bends both
knees, a raised thigh bends its knee), so the angles the camera sees predict the hidden ones.
:func:`conditional_angles` is that prediction: with the angles split into held ``h`` and seen
``s``, ``mean_h + cov_hs cov_ss^-1 (q_s - mean_s)``.

Only the 28 joint angles enter (DoFs 6-33 of ``shared.skeleton``); the root's position and
orientation depend on the camera, not the body. The file (``models/pose_prior.json``, fitted by
``python -m depthmocap.train.mocap.fit_pose_prior`` from the training split's clips):

    {"format": "depthmocap-pose-prior", "version": 1, "dof_names": [28 names],
     "mean_rad": [28], "covariance_rad2": [[28] x 28], "frames": N, "clips": M,
     "fitted_on": "..."}
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import skeleton as sk

__all__ = [
    "ANGLE_DOFS",
    "FORMAT",
    "VERSION",
    "PosePrior",
    "PosePriorError",
    "conditional_angles",
    "fit_pose_prior",
    "load_pose_prior",
    "save_pose_prior",
]

FORMAT, VERSION = "depthmocap-pose-prior", 1
# The joint angles the prior covers: every DoF but the root's six.
ANGLE_DOFS = tuple(range(6, sk.NUM_DOFS))
# Added to the covariance's diagonal (rad^2) before conditioning: angles the clips never moved
# would otherwise make it singular.
RIDGE_RAD2 = 1e-4


class PosePriorError(ValueError):
    """A pose-prior file that is missing, unreadable or of another format or version."""


@dataclass(frozen=True)
class PosePrior:
    """Mean (A,) and covariance (A, A) of the A = 28 joint angles (:data:`ANGLE_DOFS`),
    radians, with what they were fitted on."""

    mean: np.ndarray
    covariance: np.ndarray
    frames: int
    clips: int
    fitted_on: str = ""

    def __post_init__(self) -> None:
        A = len(ANGLE_DOFS)
        mean, cov = np.asarray(self.mean, float), np.asarray(self.covariance, float)
        if mean.shape != (A,) or cov.shape != (A, A):
            raise PosePriorError(
                f"pose prior: mean {mean.shape} and covariance {cov.shape} must be ({A},), "
                f"({A}, {A})"
            )
        if not (np.isfinite(mean).all() and np.isfinite(cov).all()):
            raise PosePriorError("pose prior: mean and covariance must be finite")
        if not np.allclose(cov, cov.T, atol=1e-9) or np.linalg.eigvalsh(cov).min() < -1e-9:
            raise PosePriorError("pose prior: the covariance must be symmetric and not negative")


def fit_pose_prior(q: np.ndarray, clips: int, fitted_on: str = "") -> PosePrior:
    """The angles' mean and covariance over the poses ``q`` (N, 34), N >= 2."""
    angles = np.asarray(q, dtype=np.float64)[:, list(ANGLE_DOFS)]
    if angles.shape[0] < 2 or not np.isfinite(angles).all():
        raise PosePriorError(f"pose prior: need at least 2 finite poses, got {angles.shape[0]}")
    return PosePrior(angles.mean(0), np.cov(angles, rowvar=False), len(angles), clips, fitted_on)


def conditional_angles(prior: PosePrior, q: torch.Tensor, held: torch.Tensor) -> torch.Tensor:
    """Pose ``q`` (34,) with its ``held`` (34,) bool angles replaced by their mean given the
    others under ``prior``; the root's DoFs and every angle not held are ``q``'s."""
    held = held.to(torch.bool).cpu()
    h = [i for i, a in enumerate(ANGLE_DOFS) if bool(held[a])]
    if not h:
        return q.clone()
    s = [i for i in range(len(ANGLE_DOFS)) if i not in h]
    cov = prior.covariance + RIDGE_RAD2 * np.eye(len(ANGLE_DOFS))
    x = q.detach().cpu().double().numpy()[list(ANGLE_DOFS)]
    mean = prior.mean
    given = mean[h]
    if s:
        given = given + cov[np.ix_(h, s)] @ np.linalg.solve(cov[np.ix_(s, s)], x[s] - mean[s])
    out = q.clone()
    out[[ANGLE_DOFS[i] for i in h]] = torch.as_tensor(given, dtype=q.dtype, device=q.device)
    return out


def save_pose_prior(path: str | Path, prior: PosePrior) -> None:
    """Write ``prior`` as JSON (module docstring)."""
    data = {
        "format": FORMAT,
        "version": VERSION,
        "dof_names": [sk.DOF_NAMES[a] for a in ANGLE_DOFS],
        "mean_rad": np.asarray(prior.mean).tolist(),
        "covariance_rad2": np.asarray(prior.covariance).tolist(),
        "frames": int(prior.frames),
        "clips": int(prior.clips),
        "fitted_on": prior.fitted_on,
    }
    Path(path).write_text(json.dumps(data) + "\n")


def load_pose_prior(path: str | Path) -> PosePrior:
    """Read a pose-prior file; :class:`PosePriorError` when it is missing, unreadable, of
    another format or version, or for other joint angles."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise PosePriorError(f"{path}: cannot read the pose prior ({err})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise PosePriorError(f"{path}: not a pose-prior file (format {FORMAT!r})")
    if data.get("version") != VERSION:
        raise PosePriorError(
            f"{path}: pose-prior version {data.get('version')!r}, this build reads {VERSION}"
        )
    names = [sk.DOF_NAMES[a] for a in ANGLE_DOFS]
    if data.get("dof_names") != names:
        raise PosePriorError(f"{path}: the prior's joint angles are not this skeleton's")
    try:
        return PosePrior(
            np.asarray(data["mean_rad"], dtype=np.float64),
            np.asarray(data["covariance_rad2"], dtype=np.float64),
            int(data["frames"]),
            int(data["clips"]),
            str(data.get("fitted_on", "")),
        )
    except (KeyError, TypeError, ValueError) as err:
        if isinstance(err, PosePriorError):
            raise
        raise PosePriorError(f"{path}: malformed pose prior ({err})") from None
