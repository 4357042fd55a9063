"""A learned pose prior: where human joint angles usually are, from the training motion capture.

Wei's prior (``runtime.tracker.prior_term``) only asks for smooth motion: a limb the depth
image does not constrain (outside the image, hidden behind the body) keeps whatever velocity
it had and is pushed wherever the silhouette term has no objection, out of the image or into
the body's shadow, and stays there. A weak pull towards the poses people actually take settles
those degrees of freedom where the data leave them free, and is negligible where the data
speak. It is a per-angle Gaussian over the 28 joint angles (the root, where the person
stands and faces, is left free), fitted on every frame of the training mocap clips retargeted
to the tracking skeleton (``python -m depthmocap.train.mocap.pose_prior_fit``), shipped as
``models/pose_prior.json``:

    {"format": "depthmocap-pose-prior", "version": 1, "dof_names": [28 names],
     "mean_rad": [28], "std_rad": [28], "frames": 22474, "fitted_on": "..."}
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import skeleton as sk

__all__ = [
    "ANGLE_NAMES",
    "FORMAT",
    "VERSION",
    "PosePrior",
    "PosePriorError",
    "angle_weights",
    "load_pose_prior",
    "save_pose_prior",
]

FORMAT = "depthmocap-pose-prior"
VERSION = 1
ANGLE_NAMES = sk.DOF_NAMES[sk.ANGLE_DOFS]


class PosePriorError(ValueError):
    """A pose-prior file that is missing, unreadable, of another format or version, or
    inconsistent."""


@dataclass
class PosePrior:
    """Per-angle Gaussian over the joint angles (module docstring).

    Attributes:
        mean_rad: (28,) mean of each joint angle (``skeleton.ANGLE_DOFS`` order), radians.
        std_rad: (28,) standard deviation of each, radians, > 0.
        frames: how many mocap frames it was fitted on.
        fitted_on: where those frames came from.
    """

    mean_rad: np.ndarray
    std_rad: np.ndarray
    frames: int = 0
    fitted_on: str = ""

    def __post_init__(self) -> None:
        self.mean_rad = np.asarray(self.mean_rad, dtype=np.float64)
        self.std_rad = np.asarray(self.std_rad, dtype=np.float64)
        n = len(ANGLE_NAMES)
        if self.mean_rad.shape != (n,) or self.std_rad.shape != (n,):
            raise PosePriorError(
                f"mean_rad and std_rad must have {n} entries, got {self.mean_rad.shape} and "
                f"{self.std_rad.shape}"
            )
        finite = np.isfinite(self.mean_rad).all() and np.isfinite(self.std_rad).all()
        if not (finite and (self.std_rad > 0).all()):
            raise PosePriorError("mean_rad must be finite and std_rad positive and finite")


def save_pose_prior(path: str | Path, prior: PosePrior) -> None:
    """Write ``prior`` as JSON (module docstring)."""
    data = {
        "format": FORMAT,
        "version": VERSION,
        "dof_names": list(ANGLE_NAMES),
        "mean_rad": [round(float(v), 6) for v in prior.mean_rad],
        "std_rad": [round(float(v), 6) for v in prior.std_rad],
        "frames": int(prior.frames),
        "fitted_on": prior.fitted_on,
    }
    Path(path).write_text(json.dumps(data, indent=1) + "\n")


def load_pose_prior(path: str | Path) -> PosePrior:
    """Read a pose-prior file.

    Raises:
        PosePriorError: missing, not JSON, of another format or version, or with DoF names or
            values that do not fit this skeleton.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise PosePriorError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise PosePriorError(f"{path}: not a readable JSON file ({err})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise PosePriorError(f"{path}: not a {FORMAT} file")
    if data.get("version") != VERSION:
        raise PosePriorError(
            f"{path}: format version {data.get('version')!r}, this build reads {VERSION}"
        )
    if data.get("dof_names") != list(ANGLE_NAMES):
        raise PosePriorError(f"{path}: its joint angles are not this skeleton's")
    try:
        values = [[float(v) for v in data[k]] for k in ("mean_rad", "std_rad")]
    except (KeyError, TypeError, ValueError) as err:
        raise PosePriorError(f"{path}: mean_rad / std_rad missing or not numbers ({err})") from None
    try:
        return PosePrior(
            values[0], values[1], int(data.get("frames", 0)), str(data.get("fitted_on", ""))
        )
    except PosePriorError as err:
        raise PosePriorError(f"{path}: {err}") from None


def angle_weights(prior: PosePrior, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The prior as the tracker's per-DoF Gaussian: mean (34,) and ``1 / (scale std)^2`` (34,),
    zero weight (and mean 0) on the six root DoFs."""
    if not (scale > 0 and math.isfinite(scale)):
        raise PosePriorError(f"scale must be positive and finite, got {scale}")
    mean = np.zeros(sk.NUM_DOFS)
    w2 = np.zeros(sk.NUM_DOFS)
    mean[sk.ANGLE_DOFS] = prior.mean_rad
    w2[sk.ANGLE_DOFS] = 1.0 / (scale * prior.std_rad) ** 2
    return mean, w2
