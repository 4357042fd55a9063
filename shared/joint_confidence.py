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

and, in version 2 (:data:`FEATURES`), six more:

- the whole frame's fit, the same for every joint (:func:`frame_features`): its silhouette
  overlap, depth error (cm) and 97th-percentile surface error (dm), whether Wei's tests
  failed and the track was kept over a worse detection (or while the detector waited), and
  whether the pose is a detection. A kept failed track has a mean joint error two and a half
  times a passed one's (broad protocol: 96 against 38 mm);
- how far the joint is from where the person leaves the image, capped at
  :data:`CUT_CAP_M` (:mod:`shared.image_cut`): a limb cut by the image's edge is drawn back
  onto what the camera sees;

and, in version 3, six more (:func:`pose_part_features`):

- the joint's offset from the pelvis in the camera frame (x, y, z and its length): where a
  limb is against the body says how unusual, and so how often wrong, the pose is;
- where the forest sees the joint's parts (:mod:`shared.part_evidence`): the distance from the
  joint to the 5th nearest pixel labelled one of its parts (``log(1 + 100 d)``, capped at
  :data:`PART_CAP_M`), and how many such pixels there are (``log(1 + n)``). The forest labels
  the pixels without the fit, so a limb laid on the right depth in the wrong place is far from
  its own parts' pixels.

Fitted on the tuning sets and checked on the size tuning set (held out): frames with an
observed joint over 20 cm 5.41% with version 1's three features, 5.00% with the frame's fit
added, 4.64% with the cut too (94.3% of the joints in view flagged; ``docs/experiments.md``,
fortieth session), 4.15% with version 3's pose and parts (94.6% flagged; forty-second
session).

It gives ``p_j = sigmoid(w_g . f_j + b_g)`` with one weight vector per joint group ``g``
(trunk, shoulders, elbows, wrists, hips, knees, ankles; left and right share one). A joint is
observed when ``p_j >= threshold``. Weights and threshold are fitted on tracked synthetic
recordings with ground truth (``python -m depthmocap.train.evaluation.joint_confidence_fit``):
the target is "in view and within 20 cm", the threshold keeps a chosen share (95%) of the
joints in view. Shipped as ``models/joint_confidence.json``:

    {"format": "depthmocap-joint-confidence", "version": 3, "joint_names": [16 names],
     "features": "support_visibility_neighbour_frame_cut_pose_parts", "groups": {"wrist":
     {"weights": [15], "bias": b}, ...}, "threshold": t, "recall": 0.95, "fitted_on": "...",
     "frames": N}

Version 1 and 2 files (``"support_visibility_neighbour"``, three weights a group;
``"..._frame_cut"``, nine) are still read.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from . import skeleton as sk
from .json_file import read_json_file, write_json_file

__all__ = [
    "CUT_CAP_M",
    "FEATURES",
    "FEATURE_SETS",
    "FORMAT",
    "FRAME_FEATURES",
    "PART_CAP_M",
    "GROUPS",
    "JOINT_GROUP",
    "NUM_FEATURES",
    "VERSION",
    "JointConfidence",
    "JointConfidenceError",
    "confidence_features",
    "frame_features",
    "joint_confidence",
    "load_joint_confidence",
    "pose_part_features",
    "save_joint_confidence",
]

FORMAT = "depthmocap-joint-confidence"
VERSION = 3
# Each version's feature set and its number of features per joint.
FEATURE_SETS = {
    1: ("support_visibility_neighbour", 3),
    2: ("support_visibility_neighbour_frame_cut", 9),
    3: ("support_visibility_neighbour_frame_cut_pose_parts", 15),
}
FEATURES, NUM_FEATURES = FEATURE_SETS[VERSION]
# The frame's fit as :func:`frame_features` gives it, in order.
FRAME_FEATURES = ("overlap", "depth_error_cm", "surface_error_q97_dm", "kept_failed", "detected")
# Distances to the person's cut by the image's edge count up to this (metres): beyond it a
# joint is as far from the cut as a whole person is.
CUT_CAP_M = 0.5
# A joint further than this from every pixel of its parts (or with none) is as far as can be
# told (metres; ``shared.part_evidence``).
PART_CAP_M = 0.5
_PELVIS = sk.JOINT_NAMES.index("pelvis")


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


def frame_features(errors: Mapping[str, float], status: str) -> np.ndarray:
    """(5,) float64 the frame's fit (:data:`FRAME_FEATURES`) from an estimate's ``errors``
    (``PoseEstimate.errors``: the fit's signals and the hybrid's flags) and ``status``. A
    signal the frame lacks (NaN or absent) counts as 0."""

    def signal(name: str) -> float:
        value = float(errors.get(name, math.nan))
        return value if math.isfinite(value) else 0.0

    kept = any(math.isfinite(float(errors.get(k, math.nan)))
               for k in ("kept_over_detector", "detector_waited"))  # fmt: skip
    return np.array(
        [
            signal("overlap"),
            signal("depth_error_cm"),
            signal("surface_error_q97_mm") / 100.0,
            float(kept),
            float(status == "detected"),
        ]
    )


def confidence_features(
    support_cm2: torch.Tensor,
    limb_visibility: torch.Tensor,
    frame: torch.Tensor | None = None,
    cut_m: torch.Tensor | None = None,
    joints: torch.Tensor | None = None,
    parts: torch.Tensor | None = None,
) -> torch.Tensor:
    """The model's features (module docstring): version 1's three, with ``frame`` and
    ``cut_m`` version 2's nine, with ``joints`` and ``parts`` too version 3's fifteen.

    Args:
        support_cm2: (..., J) each named joint's confirmed area, J = ``len(JOINT_NAMES)``;
            NaN counts as none.
        limb_visibility: (..., 4) visible fraction of the left/right arm and leg in the
            model's rendering; NaN counts as hidden.
        frame: (..., 5) :func:`frame_features` of each frame; NaN counts as 0.
        cut_m: (..., J) each joint's distance to the person's cut by the image's edge
            (``shared.image_cut``; inf where the person is whole), capped at
            :data:`CUT_CAP_M`.
        joints: (..., J, 3) the output joints, camera metres.
        parts: (..., J, 2) each joint's distance to the forest's pixels of its parts and their
            count (``shared.part_evidence.part_distances``; inf / NaN: none).
    Returns:
        (..., J, 3), (..., J, 9) or (..., J, 15) float64.
    """
    support = torch.nan_to_num(support_cm2.double(), nan=0.0).clamp_min(0.0).log1p()
    shown = torch.nan_to_num(limb_visibility.double(), nan=0.0)
    limb = _LIMB.to(support.device)
    padded = torch.cat([shown, shown.new_ones(*shown.shape[:-1], 1)], -1)  # index -1: trunk
    visibility = padded[..., limb]
    neighbour = support[..., _NEIGHBOUR.to(support.device)]
    f = torch.stack([support, visibility, neighbour], -1)
    if (frame is None) != (cut_m is None):
        raise ValueError("version 2's features need both the frame's fit and the cut distances")
    if (joints is None) != (parts is None) or (joints is not None and frame is None):
        raise ValueError("version 3's features need the joints, their parts and version 2's")
    if frame is None:
        return f
    fit = torch.nan_to_num(torch.as_tensor(frame).to(f), nan=0.0)
    fit = fit[..., None, :].expand(*f.shape[:-1], fit.shape[-1])
    cut = torch.as_tensor(cut_m).to(f).nan_to_num(nan=0.0).clamp(0.0, CUT_CAP_M)
    f = torch.cat([f, fit, cut[..., None]], -1)
    if joints is None:
        return f
    return torch.cat([f, pose_part_features(joints, parts).to(f)], -1)


def pose_part_features(joints: torch.Tensor, parts: torch.Tensor) -> torch.Tensor:
    """(..., J, 6) version 3's added features: each joint's offset from the pelvis in the
    camera frame (x, y, z, length; where a limb is relative to the body says how unusual the
    pose is) and its parts' evidence, ``log(1 + 100 near)`` with ``near`` capped at
    :data:`PART_CAP_M`, and ``log(1 + count)``.

    Args:
        joints: (..., J, 3) output joints, metres. parts: (..., J, 2) (near_m, count).
    """
    joints = torch.as_tensor(joints).double()
    parts = torch.as_tensor(parts).to(joints)
    rel = torch.nan_to_num(joints - joints[..., _PELVIS : _PELVIS + 1, :], nan=0.0)
    near = torch.nan_to_num(parts[..., 0], nan=PART_CAP_M, posinf=PART_CAP_M).clamp(0, PART_CAP_M)
    count = torch.nan_to_num(parts[..., 1], nan=0.0).clamp_min(0.0)
    return torch.cat(
        [rel, rel.norm(dim=-1, keepdim=True), (100.0 * near).log1p()[..., None],
         count.log1p()[..., None]], -1,
    )  # fmt: skip


@dataclass
class JointConfidence:
    """Per-group logistic weights and the observed threshold (module docstring).

    Attributes:
        weights: (G, K) one row per group of :data:`GROUPS`, K the version's features.
        bias: (G,).
        threshold: a joint is observed when its confidence reaches this.
        recall: the share of in-view joints the threshold kept where it was fitted.
        fitted_on: what it was fitted on (free text, for the record).
        frames: how many frames it was fitted on.
        version: the file version whose feature set the weights read
            (:data:`FEATURE_SETS`; 1: three features, 2: nine, 3: fifteen).
    """

    weights: np.ndarray
    bias: np.ndarray
    threshold: float
    recall: float = float("nan")
    fitted_on: str = ""
    frames: int = 0
    version: int = VERSION
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.weights = np.asarray(self.weights, dtype=np.float64)
        self.bias = np.asarray(self.bias, dtype=np.float64)
        G = len(GROUPS)
        if self.version not in FEATURE_SETS:
            raise JointConfidenceError(f"no feature set for version {self.version!r}")
        K = FEATURE_SETS[self.version][1]
        if self.weights.shape != (G, K) or self.bias.shape != (G,):
            raise JointConfidenceError(
                f"weights must be ({G}, {K}) and bias ({G},), got "
                f"{self.weights.shape} and {self.bias.shape}"
            )
        finite = np.isfinite(self.weights).all() and np.isfinite(self.bias).all()
        if not finite or not (0.0 <= self.threshold <= 1.0):
            raise JointConfidenceError(
                f"weights must be finite and the threshold in [0, 1], got {self.threshold}"
            )

    def per_joint(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """((J, K), (J,)) float64 weights and biases of each named joint, on ``like``'s
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
            "version": self.version,
            "joint_names": list(sk.JOINT_NAMES),
            "features": FEATURE_SETS[self.version][0],
            "groups": groups,
            "threshold": round(float(self.threshold), 8),
            "recall": None if math.isnan(self.recall) else round(float(self.recall), 6),
            "fitted_on": self.fitted_on,
            "frames": int(self.frames),
        }


def joint_confidence(
    model: JointConfidence,
    support_cm2: torch.Tensor,
    limb_visibility: torch.Tensor,
    frame: torch.Tensor | None = None,
    cut_m: torch.Tensor | None = None,
    joints: torch.Tensor | None = None,
    parts: torch.Tensor | None = None,
) -> torch.Tensor:
    """(..., J) float64 confidence in [0, 1] of each named joint (module docstring); inputs
    as :func:`confidence_features`. A version 2 model needs ``frame`` and ``cut_m``, a
    version 3 model ``joints`` and ``parts`` too; an older model ignores what it does not
    read."""
    if model.version >= 2 and (frame is None or cut_m is None):
        raise ValueError("this joint confidence reads the frame's fit and the cut distances")
    if model.version >= 3 and (joints is None or parts is None):
        raise ValueError("this joint confidence reads the joints and their parts' evidence")
    if model.version == 1:
        frame = cut_m = None
    if model.version <= 2:
        joints = parts = None
    f = confidence_features(support_cm2, limb_visibility, frame, cut_m, joints, parts)
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
    version = data.get("version")
    if version not in FEATURE_SETS:
        raise JointConfidenceError(
            f"{path}: joint-confidence version {version!r}, this build reads "
            f"{', '.join(map(str, FEATURE_SETS))}"
        )
    if data.get("joint_names") != list(sk.JOINT_NAMES):
        raise JointConfidenceError(f"{path}: its joints are not this build's")
    features = FEATURE_SETS[version][0]
    if data.get("features") != features:
        raise JointConfidenceError(
            f"{path}: features {data.get('features')!r}, version {version} computes {features!r}"
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
            version,
        )
    except (KeyError, TypeError, ValueError) as err:
        raise JointConfidenceError(f"{path}: bad joint-confidence values ({err})") from None
