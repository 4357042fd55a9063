"""Accuracy and robustness metrics of a tracking result against ground truth (pure numpy).

Definitions (F frames, J joints; a missing prediction is NaN and is never "correct"):

* **Joint error** (Helten et al. 2013, IV-C "Joint Tracking Error"; Wei et al. 2012, 7.2
  "average 3D joint position discrepancy"): Euclidean distance between predicted and
  ground-truth joint per frame and joint; the mean is over all (frame, joint) pairs that have
  a prediction. Reported raw (``mean_joint_error_mm``, nothing subtracted).
* **Offset-normalized joint error** (Helten IV-C): trackers and ground truth put "the knee" at
  slightly different anatomical points, so for each joint the *average local displacement*
  of the tracked joint relative to the ground-truth joint, "within the local coordinate frame
  of the ground truth joint", is subtracted from the tracked joint before measuring. With
  ``d_fj = R_fj^T (p_fj - g_fj)`` (R_fj: joint frame -> camera) the offset is ``o_j = mean_f
  d_fj`` and the error ``|p_fj - R_fj o_j - g_fj| = |d_fj - o_j|``. Frames: the ground truth's
  segment frames when its pose q is known (the paper's choice), else the predicted pose's
  (segment rotations do not depend on the body, only on q), else the camera frame (a plain
  global mean offset). A joint's frame is that of the segment it belongs to
  (``skeleton.JOINT_SEGMENT``: the knee turns with the shank, the wrist with the forearm).
* **Precision at 10 cm** (Wei 7.2 after Ganapathi et al. 2010): a joint estimate within
  10 cm of the ground truth is a true positive, otherwise a false positive; precision is
  TP / (TP + FP), per joint and over all joint estimates. Frames without a pose produce no
  estimate, so they do not enter precision; they count in the system-failure rate instead.
* **Tracking failure %** (Wei 7.4): "percentage of the total frames which were switched to
  the detector", "re-initialized by the detector": result frames whose status is not
  ``tracked`` (``detected``: re-initialized by the detector; ``lost``: the tracker's fit was
  rejected or there was no person, and the detector found nothing), except the
  initializations: the first frame and the first after a lost one, where no tracker ran. On
  Wei's minutes-long sequences they are negligible; on a 2-second clip the first frame alone
  is 1.6%. ``detector_frames_pct`` counts them too.
* **System failure %** (Wei 7.4): frames in which "neither tracking process nor detection
  process is able to estimate the pose reliably". Wei labelled them by hand; with ground
  truth we label a frame failed when it has no pose, or when any of its joints is more than
  ``failure_threshold_m`` (default 20 cm, twice the 10 cm "perfectly tracked" tolerance, so
  that anatomical offsets and noise never trip it) from the ground truth: one limb visibly in
  the wrong place is what a person marking failures would flag. Where the recording has
  part labels, ``system_failure_visible_pct`` counts only the joints the camera sees
  (:mod:`train.evaluation.visibility`; Wei 7.4: a segment out of view "is often ambiguous and
  cannot be reliably estimated"), as a diagnostic beside the rate over all joints.
  ``system_failure_observed_pct`` counts only the joints the *result* reports as observed
  (``poses.jsonl``'s per-joint ``observed`` flags, :mod:`runtime.tracker.joint_support`):
  the system's own claim, made without ground truth, like the Kinect SDK's tracked and
  inferred joints; a joint of a frame written without flags counts.
  :func:`observed_flag_agreement` says how well those flags match the joints the camera
  sees, so that a system cannot pass by calling every joint inferred.
* **After offset normalization** the same precision and failure counts are taken on the
  normalized errors (``precision_10cm_offset_normalized``,
  ``system_failure_offset_normalized_pct``, and per joint the share of its estimates beyond
  the threshold, :func:`per_joint_failure_pct`). They are the figures to read against a
  *reference* skeleton from another tracker (:mod:`train.evaluation.truth`), whose joints
  sit at other anatomical points than ours: raw distances there mix definition and error.
* **Surface error, 97% quantile** (Helten IV-C "Surface Tracking Error"): per frame, the 97%
  quantile over all foreground depth points of the distance to the tracked body surface
  (the tracker reports it per frame as ``errors["surface_error_q97_mm"]``); the sequence value
  is the mean over frames, as in Helten's Table I.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "joint_errors",
    "mean_error_mm",
    "per_frame_error_mm",
    "per_joint_error_mm",
    "local_offsets",
    "offset_normalized_errors",
    "precision_at",
    "per_joint_precision_at",
    "per_joint_failure_pct",
    "system_failures",
    "observed_flag_agreement",
    "initializations",
    "tracking_failure_pct",
    "detector_frames_pct",
    "percent",
    "distance_quantile",
    "sequence_surface_error_mm",
]


def _check_pair(pred: np.ndarray, gt: np.ndarray) -> None:
    if pred.shape != gt.shape or pred.ndim != 3 or pred.shape[-1] != 3:
        raise ValueError(f"pred and gt must both be (F, J, 3), got {pred.shape} and {gt.shape}")


def joint_errors(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Distances (F, J) in metres between (F, J, 3) predictions and ground truth.

    NaN where either side has a non-finite coordinate (no prediction).
    """
    pred, gt = np.asarray(pred, dtype=np.float64), np.asarray(gt, dtype=np.float64)
    _check_pair(pred, gt)
    return np.linalg.norm(pred - gt, axis=-1)


def _nanmean(x: np.ndarray, axis=None) -> np.ndarray | float:
    """Mean over finite entries; NaN (no warning) where there are none."""
    finite = np.isfinite(x)
    count = finite.sum(axis)
    total = np.where(finite, x, 0.0).sum(axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        return total / np.where(count > 0, count, np.nan)


def mean_error_mm(errors: np.ndarray) -> float:
    """Mean of all finite errors (metres in), millimetres out; NaN if none."""
    return float(_nanmean(np.asarray(errors)) * 1e3)


def per_frame_error_mm(errors: np.ndarray) -> np.ndarray:
    """Mean error of each frame over its joints (F, J) -> (F,) millimetres, NaN without pose."""
    return _nanmean(np.asarray(errors), axis=1) * 1e3


def per_joint_error_mm(errors: np.ndarray) -> np.ndarray:
    """Mean error of each joint over frames (F, J) -> (J,) millimetres."""
    return _nanmean(np.asarray(errors), axis=0) * 1e3


def local_offsets(pred: np.ndarray, gt: np.ndarray, rotations: np.ndarray | None) -> np.ndarray:
    """Mean local displacement of each predicted joint from the ground truth: (J, 3) metres.

    Args:
        pred, gt: (F, J, 3) camera-frame positions; NaN rows are ignored.
        rotations: (F, J, 3, 3) joint frame -> camera, or None for the camera frame.
    """
    d = _local_displacements(pred, gt, rotations)
    return _nanmean(d, axis=0) if len(d) else np.full(d.shape[1:], np.nan)


def _local_displacements(pred, gt, rotations) -> np.ndarray:
    pred, gt = np.asarray(pred, dtype=np.float64), np.asarray(gt, dtype=np.float64)
    _check_pair(pred, gt)
    d = pred - gt
    if rotations is not None:
        rotations = np.asarray(rotations, dtype=np.float64)
        if rotations.shape != pred.shape + (3,):
            raise ValueError(f"rotations must be {pred.shape + (3,)}, got {rotations.shape}")
        d = (np.swapaxes(rotations, -1, -2) @ d[..., None])[..., 0]
    # A frame counts for a joint only if all three components exist.
    return np.where(np.isfinite(d).all(-1, keepdims=True), d, np.nan)


def offset_normalized_errors(
    pred: np.ndarray, gt: np.ndarray, rotations: np.ndarray | None
) -> np.ndarray:
    """Joint errors (F, J) after removing each joint's mean local offset (Helten IV-C).

    Args:
        pred, gt: (F, J, 3) camera-frame positions (NaN = missing prediction).
        rotations: (F, J, 3, 3) local frame of each joint (joint -> camera), or None to
            remove a constant camera-frame offset.
    Returns:
        (F, J) metres, NaN where the prediction is missing.
    """
    d = _local_displacements(pred, gt, rotations)
    offsets = _nanmean(d, axis=0)
    return np.linalg.norm(d - offsets, axis=-1)


def precision_at(errors: np.ndarray, threshold_m: float = 0.10) -> float:
    """Fraction of joint estimates (finite errors) within ``threshold_m``; NaN if none."""
    errors = np.asarray(errors)
    finite = np.isfinite(errors)
    n = int(finite.sum())
    return float((errors[finite] <= threshold_m).sum() / n) if n else float("nan")


def per_joint_precision_at(errors: np.ndarray, threshold_m: float = 0.10) -> np.ndarray:
    """Precision of each joint over frames: (F, J) -> (J,), NaN for joints never estimated."""
    errors = np.asarray(errors)
    finite = np.isfinite(errors)
    hits = (np.where(finite, errors, np.inf) <= threshold_m).sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return hits / np.where(finite.sum(0) > 0, finite.sum(0), np.nan)


def per_joint_failure_pct(errors: np.ndarray, failure_threshold_m: float = 0.20) -> np.ndarray:
    """Percentage of each joint's estimates beyond the threshold: (F, J) -> (J,), NaN for
    joints never estimated (frames without a pose are not counted: see system failures)."""
    return 100.0 * (1.0 - per_joint_precision_at(errors, failure_threshold_m))


def system_failures(
    errors: np.ndarray, failure_threshold_m: float = 0.20, counted: np.ndarray | None = None
) -> np.ndarray:
    """Failed frames (F,) bool: no joint estimated, or any joint beyond the threshold.

    Args:
        errors: (F, J) joint errors, NaN rows for frames without a pose.
        counted: (F, J) bool, the joints whose errors count (e.g. only those the camera
            sees, :mod:`train.evaluation.visibility`); None: all. A frame without a pose
            fails either way.
    """
    errors = np.asarray(errors)
    no_pose = ~np.isfinite(errors).any(1)
    far = np.where(np.isfinite(errors), errors, 0.0) > failure_threshold_m
    if counted is not None:
        far &= np.asarray(counted, dtype=bool)
    return no_pose | far.any(1)


def observed_flag_agreement(
    observed: np.ndarray, visible: np.ndarray
) -> tuple[float, float, float]:
    """How a result's per-joint observed flags match the joints the camera sees.

    Args:
        observed: (F, J) 1.0 observed, 0.0 inferred, NaN not said (frames without a pose).
        visible: (F, J) bool, the joints the camera sees (ground truth).
    Returns:
        Over the flagged entries, in percent: the share flagged observed; recall, the share
        of the visible joints flagged observed; precision, the share of the joints flagged
        observed that are visible. NaN where a share has nothing to count.
    """
    observed = np.asarray(observed, dtype=np.float64)
    said = np.isfinite(observed)
    flag = said & (observed > 0.5)
    visible = np.asarray(visible, dtype=bool) & said
    return (
        percent(flag[said]) if said.any() else float("nan"),
        percent(flag[visible]) if visible.any() else float("nan"),
        percent(visible[flag]) if flag.any() else float("nan"),
    )


def initializations(status: np.ndarray) -> np.ndarray:
    """(F,) bool: detected frames that start a track, where no tracker ran before them: the
    first frame, and the first one after a lost frame (the estimator forgot its past)."""
    status = np.asarray(status)
    before = np.concatenate([np.array(["lost"]), status[:-1]])
    return (status == "detected") & (before == "lost")


def tracking_failure_pct(status: np.ndarray) -> float:
    """Percentage of frames switched to the detector after the tracker failed: status not
    ``tracked``, initializations (:func:`initializations`) excepted."""
    status = np.asarray(status)
    return percent((status != "tracked") & ~initializations(status))


def detector_frames_pct(status: np.ndarray) -> float:
    """Percentage of frames not reconstructed by the tracker (status != ``tracked``),
    initializations included."""
    return percent(np.asarray(status) != "tracked")


def percent(mask: np.ndarray) -> float:
    """100 * mean of a boolean mask; NaN for an empty mask."""
    mask = np.asarray(mask, dtype=bool)
    return float(100.0 * mask.mean()) if mask.size else float("nan")


def distance_quantile(distances: np.ndarray, q: float = 0.97) -> float:
    """Helten's per-frame surface error: the ``q`` quantile of point-to-surface distances.

    Args:
        distances: (N,) distances of the frame's foreground points to the tracked surface.
    """
    distances = np.asarray(distances, dtype=np.float64)
    distances = distances[np.isfinite(distances)]
    return float(np.quantile(distances, q)) if distances.size else float("nan")


def sequence_surface_error_mm(per_frame_mm: np.ndarray) -> float:
    """Mean over frames of the per-frame 97% quantile (Helten Table I); NaN if none given."""
    return float(_nanmean(np.asarray(per_frame_mm, dtype=np.float64)))
