"""Evaluate a tracking result directory against a recording's ground truth, or, on a recording
without one, against its reference skeleton (another tracker: :mod:`.truth`).

Frame matching: result frame ``i`` is recording frame ``i``. The evaluated range is recording
frames ``0 .. last result frame``: frames inside it that the result lacks (dropped by the
stream, or before the tracker started) count as system failures with no pose; frames after
it (the run was interrupted or limited) are not evaluated and are reported as
``frames_unprocessed``. Joints are matched by name; names present on one side only are
listed and ignored. Metric definitions: :mod:`train.evaluation.metrics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.config import field_doc
from depthmocap.shared.kinematics import forward_kinematics
from depthmocap.shared.recording import Recording

from . import metrics as m
from .result_io import STATUSES, ResultFileError, TrackingResult, load_result
from .truth import REFERENCE, Truth, recording_truth
from .visibility import recording_joint_visibility

__all__ = [
    "EvalConfig",
    "Evaluation",
    "evaluate",
    "held_frames",
    "format_failed_frames",
    "EvaluationError",
    "ResultFileError",
]

SURFACE_KEY = "surface_error_q97_mm"
REFERENCE_NOTE = (
    "compared with a reference skeleton from {source}, NOT with ground truth: every distance "
    "is agreement with another tracker, not accuracy (read the offset-normalized figures)"
)


class EvaluationError(ValueError):
    """Recording and result that cannot be compared (mismatched frames or joints)."""


@dataclass
class EvalConfig:
    """Thresholds of the evaluation (metres)."""

    precision_threshold_m: float = field_doc(
        0.10, "a joint estimate within this distance is correct (Wei 7.2, precision at 10 cm)"
    )
    failure_threshold_m: float = field_doc(
        0.20, "a frame with any joint farther than this is a system failure"
    )


@dataclass
class Evaluation:
    """Everything the report and the plot need.

    Attributes:
        report: JSON-ready summary (NaN already turned into None).
        frame_errors_mm: (F,) mean joint error per evaluated frame, NaN without a pose.
        frame_status: (F,) status per evaluated frame, ``missing`` where the result lacks it.
        joint_names: the evaluated joints.
        per_joint_mm: (J,) raw mean error per joint; per_joint_norm_mm: offset-normalized.
        norm_errors_m: (F, J) offset-normalized joint errors, metres, NaN without a pose.
        truth: what the result was compared with (ground truth or a reference).
        observed: (F, J) the result's observed flags (1 observed, 0 inferred, NaN where the
            frame has none); None: not kept.
    """

    report: dict
    frame_errors_mm: np.ndarray
    frame_status: np.ndarray
    joint_names: tuple[str, ...]
    per_joint_mm: np.ndarray
    per_joint_norm_mm: np.ndarray
    norm_errors_m: np.ndarray
    truth: Truth
    observed: np.ndarray | None = None


def _segment_rotations(q: np.ndarray, joint_names: tuple[str, ...]) -> np.ndarray | None:
    """(F, J, 3, 3) frames of the named joints from poses q (F, 34); NaN rows where q is."""
    if not all(n in sk.JOINT_NAMES for n in joint_names):
        return None
    seg = sk.JOINT_SEGMENT[[sk.JOINT_NAMES.index(n) for n in joint_names]]
    valid = np.isfinite(q).all(1)
    rot = np.full((len(q), len(joint_names), 3, 3), np.nan)
    if valid.any():
        # Segment rotations depend on q only, not on the body's lengths.
        kin = forward_kinematics(torch.from_numpy(q[valid]), BodyShape.default(torch.float64))
        rot[valid] = kin.rotations.numpy()[:, seg]
    return rot


def _finite(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _per_joint(names, values, scale: float = 1.0) -> dict:
    return {n: _finite(float(v) * scale) for n, v in zip(names, values)}


def _failed_frames(errors: np.ndarray, failed: np.ndarray, names, visible=None) -> list[dict]:
    """Each failed frame with its worst joint and that joint's error (None without a pose),
    and, given ``visible`` (F, J) bool, whether the camera saw that joint."""
    out = []
    for f in np.flatnonzero(failed):
        row = errors[f]
        if np.isfinite(row).any():
            j = int(np.nanargmax(row))
            out.append(
                {"frame": int(f), "worst_joint": names[j], "error_mm": _finite(row[j] * 1e3)}
            )
            if visible is not None:
                out[-1]["worst_joint_visible"] = bool(visible[f, j])
        else:
            out.append({"frame": int(f), "worst_joint": None, "error_mm": None})
    return out


def format_failed_frames(frames: list[dict], limit: int | None = None) -> str:
    """``system_failure_frames`` as text: "60 l_wrist 21 cm (hidden), 7 no pose", at most
    ``limit`` of them (then "... and N more"); "(hidden)": the camera did not see that joint."""
    shown = [
        f"{f['frame']} {f['worst_joint']} {f['error_mm'] / 10:.0f} cm"
        f"{' (hidden)' if f.get('worst_joint_visible') is False else ''}"
        if f["worst_joint"] else f"{f['frame']} no pose"
        for f in frames[:limit]
    ]  # fmt: skip
    more = len(frames) - len(shown)
    return ", ".join(shown) + (f" ... and {more} more" if more > 0 else "")


def check_same_recording(summary: dict, rec: Recording, result_dir: str | Path) -> None:
    """Refuse to score a result against another recording than the one it was tracked from:
    its ``summary.json`` names the source, and the image size must match. (A recording moved
    since cannot be told apart; then only the size is checked.)

    Raises:
        EvaluationError: naming both.
    """
    source = summary.get("source") if isinstance(summary, dict) else None
    if isinstance(source, str) and source.startswith("recording:"):
        tracked = Path(source.partition(":")[2])
        if tracked.is_dir() and tracked.resolve() != rec.path.resolve():
            raise EvaluationError(
                f"{result_dir} was tracked from {tracked}, not {rec.path}: evaluate it against "
                "the recording it came from"
            )
    intr = summary.get("intrinsics") if isinstance(summary, dict) else None
    if isinstance(intr, dict):
        size = (intr.get("width"), intr.get("height"))
        if size != (rec.intrinsics.width, rec.intrinsics.height):
            raise EvaluationError(
                f"{result_dir} was tracked on {size[0]}x{size[1]} images, {rec.path} has "
                f"{rec.intrinsics.width}x{rec.intrinsics.height}: not the same recording"
            )


def _match(result: TrackingResult, rec: Recording, truth: Truth) -> tuple:
    gt_names = truth.joint_names
    if not result.joint_names and len(result.frame):
        raise EvaluationError(
            f"every one of the result's {len(result.frame)} frames is lost: there is no pose "
            f"to compare with the {truth.kind.replace('_', ' ')} (system failure 100%)"
        )
    names = tuple(n for n in gt_names if n in result.joint_names)
    if not names:
        raise EvaluationError(
            f"no joint names in common between the recording ({', '.join(gt_names)}) and the "
            f"result ({', '.join(result.joint_names) or 'none'})"
        )
    if len(result.frame) and int(result.frame[-1]) >= len(rec):
        raise EvaluationError(
            f"result has frame {int(result.frame[-1])} but the recording has only {len(rec)} "
            "frames (different recording?)"
        )
    ignored = sorted(set(gt_names) ^ set(result.joint_names))
    return names, ignored


def _timing(summary: dict) -> dict[str, float | None]:
    """The run's per-frame time (median, 95th percentile) and mean latency in ms, from
    ``summary.json``'s ``extra`` (None for results written before they were recorded)."""
    extra = summary.get("extra") if isinstance(summary, dict) else None
    extra = extra if isinstance(extra, dict) else {}
    frame = extra.get("frame_time_ms") if isinstance(extra.get("frame_time_ms"), dict) else {}
    latency = extra.get("latency_ms") if isinstance(extra.get("latency_ms"), dict) else {}

    def number(d: dict, key: str) -> float | None:
        v = d.get(key)
        return _finite(float(v)) if isinstance(v, (int, float)) else None

    return {
        "frame_time_p50_ms": number(frame, "p50"),
        "frame_time_p95_ms": number(frame, "p95"),
        "latency_mean_ms": number(latency, "mean"),
    }


def held_frames(written: np.ndarray) -> np.ndarray:
    """For each frame, the last written frame at or before it (-1 before the first).

    Args:
        written: (F,) bool, the frames the result has.

    Returns:
        (F,) int64 frame indices.
    """
    index = np.where(written, np.arange(len(written)), -1)
    return np.maximum.accumulate(index) if len(index) else index.astype(np.int64)


def evaluate(
    recording: str | Path,
    result_dir: str | Path,
    cfg: EvalConfig | None = None,
    hold_skipped: bool = False,
) -> Evaluation:
    """Compare ``result_dir`` (runtime-track output) with ``recording``'s ground truth, or
    with its reference skeleton when it has no ground truth (``report["truth"]`` says which).

    ``hold_skipped``: score a frame the result skipped (``runtime-track --realtime``: the
    camera's newest frame wins) with the last pose written before it, as ``motion.bvh``
    repeats it and a consumer reading poses at the camera's rate sees it; otherwise it is a
    frame without a pose (a system failure). ``report["frames_held"]`` counts them.

    Raises:
        RecordingError, ResultFileError, EvaluationError: with the file and the problem.
    """
    cfg = EvalConfig() if cfg is None else cfg
    rec = Recording(recording)
    truth = recording_truth(rec)
    result = load_result(result_dir)
    check_same_recording(result.summary, rec, result_dir)
    names, ignored = _match(result, rec, truth)
    notes: list[str] = []
    if not len(result.frame):
        raise EvaluationError(f"{result_dir}: the result has no frames to evaluate")
    n_eval = int(result.frame[-1]) + 1
    gt_joints = np.asarray(truth.joints, dtype=np.float64)[:n_eval][
        :, [truth.joint_names.index(n) for n in names]
    ]
    pred = np.full_like(gt_joints, np.nan)
    res_idx = [result.joint_names.index(n) for n in names]
    pred[result.frame] = result.joints[:, res_idx]
    status = np.full(n_eval, "missing", dtype="<U8")
    status[result.frame] = result.status
    pred_q = np.full((n_eval, sk.NUM_DOFS), np.nan)
    pred_q[result.frame] = result.q

    observed = np.full(pred.shape[:2], np.nan)
    res_observed = result.observed[:, res_idx]
    observed[result.frame] = res_observed
    frames_held = 0
    if hold_skipped:
        source = held_frames(status != "missing")
        held = (status == "missing") & (source >= 0)
        pred[held], pred_q[held], observed[held] = (
            pred[source[held]], pred_q[source[held]], observed[source[held]]
        )  # fmt: skip
        frames_held = int(held.sum())
        if frames_held:
            notes.append(f"{frames_held} skipped frames scored with the last pose written")
    errors = m.joint_errors(pred, gt_joints)
    rotations, offset_frame = None, "camera"
    if truth.q is not None and np.isfinite(truth.q[:n_eval]).all():
        rotations = _segment_rotations(truth.q[:n_eval], names)
        offset_frame = "ground_truth_q" if rotations is not None else offset_frame
    if rotations is None and np.isfinite(pred_q).all(1).any():
        rotations = _segment_rotations(pred_q, names)
        offset_frame = "predicted_q" if rotations is not None else offset_frame
    if offset_frame == "camera":
        notes.append("offset normalization in the camera frame (no pose q to define joint frames)")
    norm_errors = m.offset_normalized_errors(pred, gt_joints, rotations)

    surface = result.errors.get(SURFACE_KEY)
    surface_mm = m.sequence_surface_error_mm(surface) if surface is not None else math.nan
    surface_frames = int(np.isfinite(surface).sum()) if surface is not None else 0
    if surface_frames == 0:
        notes.append(f"surface error not available: the result has no errors['{SURFACE_KEY}']")
    if result.truncated:
        notes.append("poses.jsonl ended in an unfinished line (interrupted run); it was dropped")
    if not result.summary.get("complete", False):
        notes.append("summary.json is missing or not marked complete (interrupted run?)")

    failures = m.system_failures(errors, cfg.failure_threshold_m)
    visible = recording_joint_visibility(rec, gt_joints, names)
    failures_seen = (
        m.system_failures(errors, cfg.failure_threshold_m, visible) if visible is not None else None
    )
    said = bool(np.isfinite(observed).any())
    # A joint the result says nothing about (a frame written without flags) counts: only a
    # joint it calls inferred may be left out.
    counted = np.where(np.isfinite(observed), observed > 0.5, True)
    failures_observed = (
        m.system_failures(errors, cfg.failure_threshold_m, counted) if said else None
    )
    flagged_pct = flag_recall = flag_precision = math.nan
    if said and visible is not None:
        flagged_pct, flag_recall, flag_precision = m.observed_flag_agreement(observed, visible)
    elif said:
        flagged_pct = m.percent(observed[np.isfinite(observed)] > 0.5)
    per_joint = m.per_joint_error_mm(errors)
    per_joint_norm = m.per_joint_error_mm(norm_errors)
    frame_mm = m.per_frame_error_mm(errors)
    failures_norm = m.system_failures(norm_errors, cfg.failure_threshold_m)
    report = {
        "recording": str(recording),
        "result": str(result_dir),
        "truth": truth.kind,
        "truth_source": truth.source,
        "frames": n_eval,
        "frames_with_pose": int(np.isfinite(errors).any(1).sum()),
        "frames_missing": int((status == "missing").sum()),
        "frames_held": frames_held,
        "frames_unprocessed": len(rec) - n_eval,
        "mean_joint_error_mm": _finite(m.mean_error_mm(errors)),
        "mean_joint_error_offset_normalized_mm": _finite(m.mean_error_mm(norm_errors)),
        "per_joint_error_mm": _per_joint(names, per_joint),
        "per_joint_error_offset_normalized_mm": _per_joint(names, per_joint_norm),
        "precision_10cm": _finite(m.precision_at(errors, cfg.precision_threshold_m)),
        "per_joint_precision_10cm": _per_joint(
            names, m.per_joint_precision_at(errors, cfg.precision_threshold_m)
        ),
        "precision_10cm_offset_normalized": _finite(
            m.precision_at(norm_errors, cfg.precision_threshold_m)
        ),
        "per_joint_precision_10cm_offset_normalized": _per_joint(
            names, m.per_joint_precision_at(norm_errors, cfg.precision_threshold_m)
        ),
        "surface_error_q97_mm": _finite(surface_mm),
        "surface_error_frames": surface_frames,
        "tracking_failure_pct": _finite(m.tracking_failure_pct(result.status)),
        "detector_frames_pct": _finite(m.detector_frames_pct(result.status)),
        "system_failure_pct": _finite(m.percent(failures)),
        "system_failure_frames": _failed_frames(errors, failures, names, visible),
        "system_failure_offset_normalized_pct": _finite(m.percent(failures_norm)),
        "per_joint_failure_offset_normalized_pct": _per_joint(
            names, m.per_joint_failure_pct(norm_errors, cfg.failure_threshold_m)
        ),
        "system_failure_offset_normalized_frames": _failed_frames(
            norm_errors, failures_norm, names, visible
        ),
        "system_failure_visible_pct": (
            _finite(m.percent(failures_seen)) if failures_seen is not None else None
        ),
        "system_failure_observed_pct": (
            _finite(m.percent(failures_observed)) if failures_observed is not None else None
        ),
        "observed_joints_pct": _finite(flagged_pct),
        "observed_flag_recall_pct": _finite(flag_recall),
        "observed_flag_precision_pct": _finite(flag_precision),
        "status_counts": {s: int((result.status == s).sum()) for s in STATUSES},
        "fps": _finite(result.summary.get("fps") or math.nan),
        "stream_fps": _finite(result.summary.get("stream_fps") or rec.fps),
        **_timing(result.summary),
        "offset_frame": offset_frame,
        "joints": list(names),
        "joints_ignored": ignored,
        "reference_joints_without_counterpart": list(truth.unmapped),
        "thresholds": {
            "precision_m": cfg.precision_threshold_m,
            "system_failure_m": cfg.failure_threshold_m,
        },
        "notes": notes,
    }
    if not math.isclose(cfg.precision_threshold_m, 0.10):
        notes.append(f"precision_10cm was measured at {cfg.precision_threshold_m} m")
    if truth.kind == REFERENCE:
        notes.insert(0, REFERENCE_NOTE.format(source=truth.source))
    return Evaluation(
        report, frame_mm, status, names, per_joint, per_joint_norm, norm_errors, truth, observed
    )
