"""Hybrid tracking and detection (Wei section 5): mode "hybrid" of ``runtime-track``.

- :mod:`.config`: the settings tree (failure tests, keep-better, arm search, both estimators);
- :mod:`.policy`: the switching decisions as pure functions;
- :mod:`.arm_search` and :mod:`.arm_labels`: refitting a hidden or misplaced arm;
- :mod:`.estimator`: :class:`HybridEstimator`, the per-stream state around them.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from depthmocap.runtime.detector import Detector, forest_label_source, load_forest_labeler
from depthmocap.runtime.frame import LabelSource
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import as_config
from depthmocap.shared.joint_confidence import JointConfidence
from depthmocap.shared.joint_offsets import JointOffsets

from .config import (
    ArmSearchConfig,
    FailureThresholds,
    HybridConfig,
    HybridError,
    KeepBetterConfig,
    MisplacedArmConfig,
)
from .estimator import HybridEstimator, TrackState
from .policy import Decision, Detection, TrackVerdict, choose, judge_track

__all__ = [
    "ArmSearchConfig",
    "Decision",
    "Detection",
    "FailureThresholds",
    "HybridConfig",
    "HybridError",
    "HybridEstimator",
    "KeepBetterConfig",
    "MisplacedArmConfig",
    "TrackState",
    "TrackVerdict",
    "choose",
    "create_estimator",
    "judge_track",
    "recording_labels",
]


def hybrid_config(config: Mapping[str, Any] | HybridConfig | None) -> HybridConfig:
    """``config`` (a preset's mapping, or a config) as a :class:`HybridConfig`: the keys it
    names change the shipped defaults, the others stay (``null`` switches a section off).

    Raises:
        HybridError: unknown keys, wrong types or values out of range.
    """
    return as_config(HybridConfig, config, "hybrid config", HybridError, over_defaults=True)


def create_estimator(
    *,
    model_path: Path | None,
    body: BodyShape,
    intrinsics: Intrinsics,
    device: str = "cpu",
    config: Mapping[str, Any] | HybridConfig | None = None,
) -> HybridEstimator:
    """Mode "hybrid" for ``runtime.estimator.make_estimator`` (``config``: HybridConfig keys)."""
    cfg = hybrid_config(config)
    from depthmocap.runtime.tracker import Tracker, TrackerError

    if cfg.labels_from_recording:
        labels = recording_labels(Path(cfg.labels_from_recording))
    else:
        labeler = load_forest_labeler(
            model_path,
            device,
            intrinsics,
            smooth_window=cfg.detector.label_smoothing_window,
            confidence=cfg.tracker.label_min_posterior > 0,
        )
        labels = forest_label_source(labeler)
    try:
        tracker = Tracker(body, intrinsics, cfg.tracker, device=device)
    except TrackerError as err:
        raise HybridError(str(err)) from None
    detector = Detector(body, intrinsics, cfg.detector, device=device)
    offsets = None if cfg.joint_offsets is None else load_offsets(cfg.joint_offsets)
    confidence = None if cfg.joint_confidence is None else load_confidence(cfg.joint_confidence)
    return HybridEstimator(labels, detector, tracker, cfg, offsets, confidence=confidence)


def load_offsets(name: str) -> JointOffsets:
    """The joint-offsets file ``name`` (relative: under the shipped models/ folder).

    Raises:
        HybridError: missing, unreadable, or of another format or version.
    """
    from depthmocap.shared.joint_offsets import JointOffsetsError, load_joint_offsets

    return _load_model_file(name, "joint_offsets", load_joint_offsets, JointOffsetsError)


def load_confidence(name: str) -> JointConfidence:
    """The joint-confidence file ``name`` (relative: under the shipped models/ folder).

    Raises:
        HybridError: missing, unreadable, or of another format or version.
    """
    from depthmocap.shared.joint_confidence import JointConfidenceError, load_joint_confidence

    return _load_model_file(name, "joint_confidence", load_joint_confidence, JointConfidenceError)


def _load_model_file(name: str, key: str, load, error: type[Exception]):
    """``load`` of the file ``name`` under the shipped models/ folder (or absolute), its
    ``error`` reported as a :class:`HybridError` naming the setting ``key``."""
    from depthmocap.shared.resources import model_file

    try:
        return load(model_file(name))
    except error as err:
        raise HybridError(f"{key}: {err}") from None


def recording_labels(path: Path) -> LabelSource:
    """The ground-truth part labels of the synthetic recording at ``path`` as a label source:
    a frame's (H, W) int64 part classes (``shared.labels``), zero off the person's mask.

    Raises:
        HybridError: not a readable recording, no labels/, or (when called) a frame the
            recording does not have or cannot read.
    """
    from depthmocap.shared.recording import Recording

    try:
        rec = Recording(path)
    except (OSError, ValueError) as err:
        raise HybridError(f"labels_from_recording: {err}") from None
    if not rec.has_labels:
        raise HybridError(f"labels_from_recording: {path} has no labels/")

    def labels(frame) -> torch.Tensor:
        try:
            image = torch.from_numpy(rec.read_labels(frame.index).astype(np.int64))
        except (OSError, ValueError, IndexError) as err:
            raise HybridError(f"labels_from_recording, frame {frame.index}: {err}") from None
        if image.shape != frame.mask.shape:
            raise HybridError(
                f"frame {frame.index}: labels {tuple(image.shape)} do not match the frame "
                f"{tuple(frame.mask.shape)}"
            )
        return image.to(device=frame.device) * frame.mask

    return labels
