"""How far to trust each output joint: a learned confidence behind the observed flags.

A joint is reported *observed* (the Kinect SDK's "tracked") or *inferred*. The tracker's own
test (:mod:`runtime.tracker.joint_support`) asks whether enough of the model's surface near the
joint is confirmed by the depth image and the forest's labels. On the broad tuning sets that
test leaves a joint more than 20 cm off in 6% of the frames among the joints it calls
observed, and half of those joints are in view: a limb laid on the right depth in the wrong
place. What tells them apart better than the joint's own area is its neighbourhood: how much
of the limb the model shows at all, and whether the next joint along the limb is confirmed
too (a wrist whose elbow finds no support is rarely where the model puts it).

Per joint ``j`` the model reads three features (:func:`confidence_features`):

- ``log(1 + a_j)``, ``a_j`` the joint's confirmed area in cm^2 (``joint_support_cm2``);
- the visible fraction of the joint's limb in the model's rendering (``limb_visibility``;
  1 for the trunk's joints);
- ``log(1 + a_n)``, ``n`` the joint's neighbour along its limb (wrist -> elbow, elbow ->
  wrist, shoulder -> elbow; the legs alike; the trunk's joints their own area again),

and gives ``p_j = sigmoid(w_g . f_j + b_g)`` with one weight vector per joint group ``g``
(trunk, shoulders, elbows, wrists, hips, knees, ankles; left and right share one). A joint is
observed when ``p_j >= threshold``. Weights and threshold are fitted on tracked synthetic
recordings with ground truth (``python -m depthmocap.train.evaluation.joint_confidence_fit``):
the target is "in view and within 20 cm", the threshold keeps a chosen share (95%) of the
joints in view. Shipped as ``models/joint_confidence.json``:

    {"format": "depthmocap-joint-confidence", "version": 1, "joint_names": [16 names],
     "features": "support_visibility_neighbour", "groups": {"wrist": {"weights": [3],
     "bias": b}, ...}, "threshold": t, "recall": 0.95, "fitted_on": "...", "frames": N}
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from . import skeleton as sk
from .json_file import read_json_file, write_json_file

__all__ = [
    "FEATURES",
    "FORMAT",
    "GROUPS",
    "JOINT_GROUP",
    "NUM_FEATURES",
    "VERSION",
    "JointConfidence",
    "JointConfidenceError",
    "confidence_features",
    "joint_confidence",
    "load_joint_confidence",
    "save_joint_confidence",
]

FORMAT = "depthmocap-joint-confidence"
VERSION = 1
FEATURES = "support_visibility_neighbour"
NUM_FEATURES = 3


def _group(name: str) -> str:
    return name[2:] if name[:2] in ("l_", "r_") else "trunk"


# (J,) the group of each named joint, and the groups in a fixed order.
JOINT_GROUP: tuple[str, ...] = tuple(_group(n) for n in sk.JOINT_NAMES)
GROUPS: tuple[str, ...] = tuple(dict.fromkeys(JOINT_GROUP))

# The limb of each joint in ``limb_visibility``'s order (left arm, right arm, left leg, right
# leg); -1: a trunk joint, whose "limb" is always shown.
_LIMB_OF = {"shoulder": 0, "elbow": 0, "wrist": 0, "hip": 2, "knee": 2, "ankle": 2}
_LIMB = torch.tensor(
    [
        -1 if g == "trunk" else _LIMB_OF[g] + (n[0] == "r")
        for n, g in zip(sk.JOINT_NAMES, JOINT_GROUP, strict=True)
    ]
)
# The neighbour along the limb whose support each joint reads (a trunk joint: itself).
_NEXT = {"wrist": "elbow", "elbow": "wrist", "shoulder": "elbow",
         "ankle": "knee", "knee": "ankle", "hip": "knee"}  # fmt: skip
_NEIGHBOUR = torch.tensor(
    [
        i if g == "trunk" else sk.JOINT_NAMES.index(n[:2] + _NEXT[g])
        for i, (n, g) in enumerate(zip(sk.JOINT_NAMES, JOINT_GROUP, strict=True))
    ]
)


class JointConfidenceError(ValueError):
    """A joint-confidence file that is missing, unreadable, of another format or version, or
    inconsistent."""


def confidence_features(support_cm2: torch.Tensor, limb_visibility: torch.Tensor) -> torch.Tensor:
    """The model's features (module docstring).

    Args:
        support_cm2: (..., J) each named joint's confirmed area, J = ``len(JOINT_NAMES)``;
            NaN counts as none.
        limb_visibility: (..., 4) visible fraction of the left/right arm and leg in the
            model's rendering; NaN counts as hidden.
    Returns:
        (..., J, 3) float64.
    """
    support = torch.nan_to_num(support_cm2.double(), nan=0.0).clamp_min(0.0).log1p()
    shown = torch.nan_to_num(limb_visibility.double(), nan=0.0)
    limb = _LIMB.to(support.device)
    padded = torch.cat([shown, shown.new_ones(*shown.shape[:-1], 1)], -1)  # index -1: trunk
    visibility = padded[..., limb]
    neighbour = support[..., _NEIGHBOUR.to(support.device)]
    return torch.stack([support, visibility, neighbour], -1)


@dataclass
class JointConfidence:
    """Per-group logistic weights and the observed threshold (module docstring).

    Attributes:
        weights: (G, 3) one row per group of :data:`GROUPS`.
        bias: (G,).
        threshold: a joint is observed when its confidence reaches this.
        recall: the share of in-view joints the threshold kept where it was fitted.
        fitted_on: what it was fitted on (free text, for the record).
        frames: how many frames it was fitted on.
    """

    weights: np.ndarray
    bias: np.ndarray
    threshold: float
    recall: float = float("nan")
    fitted_on: str = ""
    frames: int = 0
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.weights = np.asarray(self.weights, dtype=np.float64)
        self.bias = np.asarray(self.bias, dtype=np.float64)
        G = len(GROUPS)
        if self.weights.shape != (G, NUM_FEATURES) or self.bias.shape != (G,):
            raise JointConfidenceError(
                f"weights must be ({G}, {NUM_FEATURES}) and bias ({G},), got "
                f"{self.weights.shape} and {self.bias.shape}"
            )
        finite = np.isfinite(self.weights).all() and np.isfinite(self.bias).all()
        if not finite or not (0.0 <= self.threshold <= 1.0):
            raise JointConfidenceError(
                f"weights must be finite and the threshold in [0, 1], got {self.threshold}"
            )

    def per_joint(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """((J, 3), (J,)) float64 weights and biases of each named joint, on ``like``'s
        device (kept, so a stream converts them once)."""
        key = str(like.device)
        if key not in self._cache:
            group = [GROUPS.index(g) for g in JOINT_GROUP]
            self._cache[key] = (
                torch.as_tensor(self.weights[group], device=like.device),
                torch.as_tensor(self.bias[group], device=like.device),
            )
        return self._cache[key]

    def to_json_dict(self) -> dict:
        groups = {
            g: {"weights": np.round(w, 8).tolist(), "bias": round(float(b), 8)}
            for g, w, b in zip(GROUPS, self.weights, self.bias, strict=True)
        }
        return {
            "format": FORMAT,
            "version": VERSION,
            "joint_names": list(sk.JOINT_NAMES),
            "features": FEATURES,
            "groups": groups,
            "threshold": round(float(self.threshold), 8),
            "recall": None if math.isnan(self.recall) else round(float(self.recall), 6),
            "fitted_on": self.fitted_on,
            "frames": int(self.frames),
        }


def joint_confidence(
    model: JointConfidence, support_cm2: torch.Tensor, limb_visibility: torch.Tensor
) -> torch.Tensor:
    """(..., J) float64 confidence in [0, 1] of each named joint (module docstring); inputs
    as :func:`confidence_features`."""
    f = confidence_features(support_cm2, limb_visibility)
    w, b = model.per_joint(f)
    return torch.sigmoid((f * w).sum(-1) + b)


def save_joint_confidence(path: str | Path, model: JointConfidence) -> None:
    """Write ``model`` as JSON (atomically: a reader never sees half a file)."""
    write_json_file(path, model.to_json_dict())


def load_joint_confidence(path: str | Path) -> JointConfidence:
    """Read a joint-confidence file.

    Raises:
        JointConfidenceError: missing or unreadable file, another format, version or feature
            set, joint names other than this build's, or bad values.
    """
    path = Path(path)
    data = read_json_file(path, "joint-confidence", JointConfidenceError)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise JointConfidenceError(f"{path}: not a {FORMAT} file")
    if data.get("version") != VERSION:
        raise JointConfidenceError(
            f"{path}: joint-confidence version {data.get('version')!r}, this build reads {VERSION}"
        )
    if data.get("joint_names") != list(sk.JOINT_NAMES):
        raise JointConfidenceError(f"{path}: its joints are not this build's")
    if data.get("features") != FEATURES:
        raise JointConfidenceError(
            f"{path}: features {data.get('features')!r}, this build computes {FEATURES!r}"
        )
    groups = data.get("groups")
    if not isinstance(groups, dict) or set(groups) != set(GROUPS):
        raise JointConfidenceError(f"{path}: groups must be exactly {list(GROUPS)}")
    recall = data.get("recall")
    try:
        return JointConfidence(
            np.asarray([groups[g]["weights"] for g in GROUPS], dtype=np.float64),
            np.asarray([groups[g]["bias"] for g in GROUPS], dtype=np.float64),
            float(data["threshold"]),
            float("nan") if recall is None else float(recall),
            str(data.get("fitted_on", "")),
            int(data.get("frames", 0)),
        )
    except (KeyError, TypeError, ValueError) as err:
        raise JointConfidenceError(f"{path}: bad joint-confidence values ({err})") from None
