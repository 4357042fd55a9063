"""3D pose detector of Wei section 4.2 (mode "detector") and the Shotton 2011 baseline.

Mode "detector" runs the forest and :func:`detect_pose` on every frame with tracker refinement,
independently of the previous frames: status "detected", or "lost" when too few body pixels
are labelled. The forest itself (``runtime.forest.inference.ForestClassifier``) is loaded by
:func:`load_forest_labeler`, shared with the hybrid and the Shotton baseline.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import as_config

from .bone_ransac import BoneFit, bone_reach, fit_bones
from .centroids import ClassCentroids, class_centroids, part_markers
from .config import DetectorConfig, MeanShiftConfig
from .detect import DetectionResult, Detector, DetectorError, Refine, detect_pose, labels_from

__all__ = [
    "DetectorConfig",
    "MeanShiftConfig",
    "DetectorError",
    "DetectionResult",
    "Detector",
    "Refine",
    "detect_pose",
    "labels_from",
    "BoneFit",
    "fit_bones",
    "bone_reach",
    "ClassCentroids",
    "class_centroids",
    "part_markers",
    "Labeler",
    "load_forest_labeler",
    "forest_label_source",
    "DetectorEstimator",
    "create_estimator",
]

# (depth_m (H, W), mask (H, W) bool) -> (H, W) int part labels or (C, H, W) posteriors, or
# the labels with each one's posterior ((H, W) int, (H, W) float).
Labeler = Callable[[torch.Tensor, torch.Tensor], torch.Tensor | tuple[torch.Tensor, torch.Tensor]]


def load_forest_labeler(
    model_path: str | Path | None,
    device: str | torch.device = "cpu",
    intrinsics: Intrinsics | None = None,
    posteriors: bool = False,
    smooth_window: int = 1,
    smooth_depth_gate_m: float = 0.05,
    confidence: bool = False,
) -> Labeler:
    """Per-pixel part labels (or (C, H, W) posteriors) from the forest at ``model_path``.

    ``confidence``: the labels with each label's posterior, a pair (the tracker's label
    gate, ``TrackerConfig.label_min_posterior``); not with ``posteriors``.

    ``intrinsics``: the stream's camera (feature offsets are rescaled to its focal length).
    ``smooth_window``, ``smooth_depth_gate_m``: depth-gated smoothing of the posteriors
    (:func:`shared.posterior_smoothing.smooth_posteriors`; a window of 1 is off).

    Raises:
        DetectorError: no model given, the forest runtime missing, or bad smoothing settings;
            the forest loader's ``ForestFormatError`` (a ValueError) for a missing or corrupt
            file.
    """
    if model_path is None:
        raise DetectorError("this mode needs a forest model (--model forest.npz)")
    from depthmocap.shared.forest_format import load_forest_shared
    from depthmocap.shared.labels import PART_NAMES

    forest = load_forest_shared(model_path, expected_classes=PART_NAMES)
    try:
        from depthmocap.runtime.forest.inference import ForestClassifier
    except ImportError as err:
        raise DetectorError(f"forest inference is not available in this build ({err})") from None
    try:
        clf = ForestClassifier(
            forest,
            device,
            intrinsics=intrinsics,
            smooth_window=smooth_window,
            smooth_depth_gate_m=smooth_depth_gate_m,
        )
    except ValueError as err:
        raise DetectorError(str(err)) from None
    if posteriors and confidence:
        raise DetectorError("a labeler gives posteriors or labels with their confidence")
    if confidence:
        return clf.labels_and_confidence
    return clf.posteriors if posteriors else clf.labels


def forest_label_source(labeler: Labeler):
    """A frame's part labels from the forest ``labeler`` (arg-max of its posteriors), as a
    ``runtime.frame.LabelSource``; with each label's posterior when the labeler gives it."""

    def labels(frame) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        out = labeler(frame.depth_m, frame.mask)
        if isinstance(out, tuple):
            return labels_from(out[0]), out[1]
        return labels_from(out)

    return labels


class DetectorEstimator:
    """Mode "detector": forest labels -> :class:`Detector` on every frame (no memory), refined
    by a few iterations of ``tracker`` (None: no refinement)."""

    def __init__(self, labeler: Labeler, detector: Detector, tracker=None) -> None:
        self.labels, self.detector, self.tracker = forest_label_source(labeler), detector, tracker

    def reset(self) -> None:
        """Every frame is detected from scratch; only the random sequence restarts."""
        self.detector.reset()

    def estimate(self, frame):
        from depthmocap.runtime.estimator import PoseEstimate, lost, observed_of

        labels = frame.labels(self.labels)
        refine = None
        k = self.detector.cfg.refine_iterations
        if self.tracker is not None and k > 0:
            obs = frame.observation(self.tracker, labels)

            def refine(starts):
                return self.tracker.fit_starts(obs, starts, k)

        det = self.detector.detect(frame.depth_m, labels, frame.mask, refine=refine)
        if not det.found:
            return lost(labelled_pixels=float(det.labelled_pixels))
        errors = {"ik_rms_m": det.ik_rms, "labelled_pixels": float(det.labelled_pixels)}
        if det.refined is not None:
            errors.update(det.refined.signals.as_errors())
        return PoseEstimate(
            det.q.detach().cpu().double().numpy(),
            det.joints.detach().cpu().double().numpy(),
            "detected",
            errors,
            det.labels.cpu().numpy().astype(np.uint8),
            observed=observed_of(det.refined),
        )


def create_estimator(
    *,
    model_path: Path | None,
    body: BodyShape,
    intrinsics: Intrinsics,
    device: str = "cpu",
    config: Mapping[str, Any] | DetectorConfig | None = None,
) -> DetectorEstimator:
    """Mode "detector" for ``make_estimator`` (``config``: DetectorConfig keys)."""
    cfg = as_config(DetectorConfig, config, "detector config", DetectorError)
    labeler = load_forest_labeler(
        model_path,
        device,
        intrinsics,
        smooth_window=cfg.label_smoothing_window,
    )
    from depthmocap.runtime.tracker import Tracker

    tracker = Tracker(body, intrinsics, device=device) if cfg.refine_iterations > 0 else None
    return DetectorEstimator(labeler, Detector(body, intrinsics, cfg, device=device), tracker)
