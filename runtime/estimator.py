"""The seam between ``runtime-track`` and the pose estimators (tracker, detector, hybrid).

Every estimator turns one depth frame plus the person mask into a :class:`PoseEstimate`.
:func:`make_estimator` builds one by mode name, importing its module only when asked, so the
tool starts (and reports a clear error) even where a mode's module is missing.

Contract of a mode module (``runtime.hybrid``, ``runtime.tracker``, ``runtime.detector``): it
defines ``create_estimator(*, model_path, body, intrinsics, device, config) -> PoseEstimator``
(``config``: a mode-specific mapping or None). It raises a ``ValueError`` subclass with a
one-line message for bad input such as an unreadable model.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

import numpy as np
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.poses_format import STATUSES

if TYPE_CHECKING:
    from collections.abc import Callable

    import torch
    from depthmocap.runtime.frame import Frame
    from depthmocap.runtime.streams.base import DepthFrame
    from depthmocap.shared.joint_confidence import JointConfidence

__all__ = [
    "PoseEstimate",
    "PoseEstimator",
    "EstimatorUnavailable",
    "MODES",
    "MODE_MODULES",
    "MODES_NEEDING_MODEL",
    "STATUSES",
    "make_estimator",
    "estimate_frame",
    "prepare_frame",
    "evidence_of",
    "lost",
    "observed_of",
]

Status = Literal["tracked", "detected", "lost"]
MODE_MODULES = {
    "hybrid": "depthmocap.runtime.hybrid",
    "tracker": "depthmocap.runtime.tracker",
    "detector": "depthmocap.runtime.detector",
    "shotton": "depthmocap.runtime.detector.meanshift_baseline",
}
MODES: tuple[str, ...] = tuple(MODE_MODULES)
# The tracker alone starts from a default pose; the others run the forest every frame.
MODES_NEEDING_MODEL = frozenset({"hybrid", "detector", "shotton"})


class EstimatorUnavailable(ValueError):
    """A mode that is unknown or whose module is not part of this installation."""


@dataclass
class PoseEstimate:
    """What an estimator says about one frame.

    Attributes:
        q: (34,) float64 pose in camera coordinates (shared.skeleton layout), None if lost.
        joints: (16, 3) named joints (shared.skeleton.JOINT_NAMES) in camera metres, or None.
        status: "tracked" (tracker from the previous pose), "detected" (detector result) or
            "lost" (no person, or no pose good enough).
        errors: fit figures by name, each in the unit its name says (e.g.
            ``depth_error_cm``, ``overlap`` 0-1, ``ik_rms_m``); docs/format.md lists them.
        labels: optional (H, W) uint8 body-part labels (shared.labels) the estimator computed;
            only used for overlay images.
        observed: optional (16,) bool, the named joints the depth image confirms; the
            others are inferred (:mod:`runtime.tracker.joint_support`, or with a joint
            confidence model :mod:`shared.joint_confidence`). None: unknown.
        joint_support_cm2: optional (16,) the evidence behind ``observed``: each joint's
            surface area the depth image confirms (:mod:`runtime.tracker.joint_support`).
        limb_visibility: optional (4,) visible fraction of the left/right arm and leg in the
            fitted model's rendering.
    """

    q: np.ndarray | None
    joints: np.ndarray | None
    status: Status
    errors: dict[str, float] = field(default_factory=dict)
    labels: np.ndarray | None = None
    observed: np.ndarray | None = None
    joint_support_cm2: np.ndarray | None = None
    limb_visibility: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, got {self.status!r}")
        if self.q is not None:
            self.q = np.asarray(self.q, dtype=np.float64)
            if self.q.shape != (34,):
                raise ValueError(f"q must be (34,), got {self.q.shape}")
        if self.joints is not None:
            self.joints = np.asarray(self.joints, dtype=np.float64)
            if self.joints.shape != (16, 3):
                raise ValueError(f"joints must be (16, 3), got {self.joints.shape}")
        for name, size in (("joint_support_cm2", 16), ("limb_visibility", 4)):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value, dtype=np.float64)
                if value.shape != (size,):
                    raise ValueError(f"{name} must be ({size},), got {value.shape}")
                setattr(self, name, value)
        if self.observed is not None:
            self.observed = np.asarray(self.observed, dtype=bool)
            if self.observed.shape != (16,):
                raise ValueError(f"observed must be (16,), got {self.observed.shape}")

    def observed_or_all(self) -> np.ndarray:
        """(16,) bool observed flags, all True when the estimator gave none (for drawing)."""
        return np.ones(16, dtype=bool) if self.observed is None else self.observed


def observed_of(
    fit,
    confidence: JointConfidence | None = None,
    frame_fit: np.ndarray | None = None,
    cut_m: np.ndarray | torch.Tensor | None = None,
    joints: np.ndarray | torch.Tensor | None = None,
    parts: np.ndarray | torch.Tensor | None = None,
) -> np.ndarray | None:
    """The (16,) bool observed-joint flags of a tracker fit, or None when there is no fit or
    it has none: with ``confidence``, the joints whose confidence reaches its threshold
    (:mod:`shared.joint_confidence`, read from the fit's support and limb visibility, for
    a version 2 model also the frame's fit ``frame_fit`` (5,) and the joints' distances to the
    person's cut by the image's edge ``cut_m`` (16,), for version 3 also the output
    ``joints`` (16, 3) and their parts' evidence ``parts`` (16, 2)); without, the fit's own
    area test (``TrackResult.observed``)."""
    support = getattr(fit, "joint_support_cm2", None)
    shown = getattr(fit, "limb_visibility", None)
    if confidence is not None and support is not None and shown is not None:
        import torch
        from depthmocap.shared.joint_confidence import joint_confidence

        extra = (
            None if x is None else torch.as_tensor(x, device=support.device)
            for x in (frame_fit, cut_m, joints, parts)
        )  # a version 1 model reads none; version 2 the first two; version 3 all
        p = joint_confidence(confidence, support.detach(), shown.detach(), *extra)
        return (p >= confidence.threshold).cpu().numpy()
    flags = getattr(fit, "observed", None)
    return None if flags is None else flags.detach().cpu().numpy().astype(bool)


def evidence_of(fit) -> dict[str, np.ndarray | None]:
    """A fit's per-joint support and per-limb visibility as ``PoseEstimate`` keyword
    arguments (each None where the fit has none, or there is no fit)."""
    return {
        name: None if value is None else value.detach().cpu().double().numpy()
        for name in ("joint_support_cm2", "limb_visibility")
        for value in (getattr(fit, name, None),)
    }


def lost(**errors: float) -> PoseEstimate:
    """A 'lost' estimate (no pose) with optional error figures."""
    return PoseEstimate(None, None, "lost", dict(errors))


@runtime_checkable
class PoseEstimator(Protocol):
    """A per-frame pose estimator with state (the previous pose) between frames."""

    def reset(self) -> None:
        """Forget the past: the next frame is estimated from scratch. ``runtime-track`` calls
        it after a frame without a person (:func:`estimate_frame`)."""

    def estimate(self, frame: Frame) -> PoseEstimate:
        """Pose of the person in ``frame`` (a :class:`runtime.frame.Frame` whose mask is not
        empty: :func:`estimate_frame` handles frames without a person)."""


def prepare_frame(
    estimator: PoseEstimator,
    frame: DepthFrame,
    segment: Callable[[torch.Tensor, Intrinsics], torch.Tensor],
    device: str | torch.device = "cpu",
) -> Frame:
    """``frame`` in metres with the person's mask (``segment``), and what ``estimator``
    computes of it before the estimate (its optional ``prefetch``: the forest's labels), so
    that a reader thread can prepare the next frame while this one is estimated
    (``runtime-track``'s loop and ``Tracker.track_stream``). A frame without a person is
    not prefetched."""
    import torch
    from depthmocap.runtime.frame import Frame  # the frame module imports heavier things

    with torch.inference_mode():  # see estimate_frame
        prepared = Frame.from_depth(frame, device=device, segment=segment)
        prefetch = getattr(estimator, "prefetch", None)
        if prefetch is not None and prepared.has_person:
            prefetch(prepared)
    return prepared


def estimate_frame(estimator: PoseEstimator, frame: Frame) -> PoseEstimate:
    """The estimate of ``frame``: "lost" without asking the estimator when the segmentation
    found no one (the estimator then forgets its track, so the person is picked up afresh),
    the estimator's otherwise. The one place that rule lives.

    Runs in torch's inference mode: nothing here needs autograd, and its thousands of small
    tensor ops a frame then skip the version counters and view tracking (a tracker fit ~10%
    faster, the same results); the tensors an estimate keeps (its last poses) are inference
    tensors, read-only outside it."""
    import torch

    if not frame.has_person:
        estimator.reset()
        return lost()
    with torch.inference_mode():
        return estimator.estimate(frame)


def make_estimator(
    mode: str,
    model_path: str | Path | None,
    body: BodyShape,
    intrinsics: Intrinsics,
    device: str = "cpu",
    config: dict[str, Any] | None = None,
) -> PoseEstimator:
    """Build the estimator of ``mode`` ("hybrid", "tracker" or "detector").

    Raises:
        EstimatorUnavailable: unknown mode, or its module / factory is not installed.
        ValueError subclasses from the mode (missing or unreadable model, ...).
    """
    if mode not in MODE_MODULES:
        raise EstimatorUnavailable(f"unknown mode '{mode}' (choose from {', '.join(MODES)})")
    name = MODE_MODULES[mode]
    try:
        module = importlib.import_module(name)
    except ModuleNotFoundError as err:
        if err.name and not name.startswith(err.name):
            raise EstimatorUnavailable(
                f"mode '{mode}' needs the package '{err.name}' (pip install 'depthmocap[runtime]')"
            ) from None
        raise EstimatorUnavailable(
            f"mode '{mode}' is not available in this build ({name} is missing)"
        ) from None
    factory = getattr(module, "create_estimator", None)
    if factory is None:
        raise EstimatorUnavailable(
            f"mode '{mode}' is not available in this build ({name} has no create_estimator)"
        )
    return factory(
        model_path=None if model_path is None else Path(model_path),
        body=body,
        intrinsics=intrinsics,
        device=device,
        config=config,
    )
