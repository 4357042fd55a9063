"""Reading a tracking result directory (``poses.jsonl``, ``body.json``, ``summary.json``).

The format is written by ``runtime.export``; ``poses.jsonl`` is parsed by
:mod:`shared.poses_format` (only an unfinished last line, from an interrupted run, is dropped;
anything else malformed is an error).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depthmocap.shared.body import BodyShape
from depthmocap.shared.poses_format import (
    STATUSES,
    PosesFileError,
    poses_to_arrays,
    read_poses_jsonl,
)

__all__ = ["ResultFileError", "TrackingResult", "load_result", "STATUSES"]


class ResultFileError(ValueError):
    """A result directory or file that cannot be evaluated; names the file."""


@dataclass
class TrackingResult:
    """A result directory, as arrays over its N written frames.

    Attributes:
        frame: (N,) stream frame indices, strictly increasing.
        status: (N,) ``tracked`` / ``detected`` / ``lost``.
        joint_names: the J joint names found in the file.
        joints: (N, J, 3) camera metres, NaN where null.
        q: (N, 34) poses, NaN where null.
        errors: per-frame fit errors by name, each (N,), NaN where absent.
        body: the body of ``body.json``, or None if the file is absent.
        summary: ``summary.json`` contents ({} if absent).
        truncated: an unfinished last line was dropped.
        observed: (N, J) 1.0 where the result says the depth image confirms the joint, 0.0
            where it says the joint is inferred, NaN where it says nothing (older files).
    """

    frame: np.ndarray
    status: np.ndarray
    joint_names: tuple[str, ...]
    joints: np.ndarray
    q: np.ndarray
    errors: dict[str, np.ndarray]
    body: BodyShape | None
    summary: dict
    truncated: bool
    observed: np.ndarray


def _to_arrays(records: list[dict], path: Path) -> tuple:
    names: list[str] = []
    for rec in records:
        for name in rec["joints"] or {}:
            if name not in names:
                names.append(name)
    arrays = poses_to_arrays(records, names)
    error_names = sorted({k for rec in records for k in rec.get("errors") or {}})
    errors = {k: np.full(len(records), np.nan) for k in error_names}
    for i, rec in enumerate(records):
        for k, v in (rec.get("errors") or {}).items():
            errors[k][i] = np.nan if v is None else v
    status = arrays["status"].astype("<U8")
    return (
        arrays["frame"], status, tuple(names), arrays["joints"], arrays["q"], errors,
        arrays["observed"],
    )  # fmt: skip


def load_result(result_dir: str | Path) -> TrackingResult:
    """Load a result directory; :class:`ResultFileError` on anything missing or malformed."""
    result_dir = Path(result_dir)
    if not result_dir.is_dir():
        raise ResultFileError(f"{result_dir}: no such result directory")
    poses_path = result_dir / "poses.jsonl"
    try:
        data = read_poses_jsonl(poses_path)
    except PosesFileError as err:
        raise ResultFileError(str(err)) from None
    records, truncated = data.records, data.truncated
    frame, status, names, joints, q, errors, observed = _to_arrays(records, poses_path)

    body = None
    if (result_dir / "body.json").is_file():
        try:
            body = BodyShape.load(result_dir / "body.json")
        except ValueError as err:
            raise ResultFileError(str(err)) from None
    summary: dict = {}
    summary_path = result_dir / "summary.json"
    if summary_path.is_file():
        try:
            summary = json.loads(summary_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise ResultFileError(f"{summary_path}: not valid JSON ({err})") from None
        if not isinstance(summary, dict):
            raise ResultFileError(f"{summary_path}: expected a JSON object")
    return TrackingResult(
        frame, status, names, joints, q, errors, body, summary, truncated, observed
    )
