"""``poses.jsonl``, the per-frame tracking result: its writer and its reader in one place.

The runtime writes it (``runtime.export``), the evaluation reads it (``train`` may not import
``runtime``), so both sides of the format live in ``shared`` and cannot drift apart.

Each line is written whole and flushed as soon as its frame is done, so a run cut off by
Ctrl-C, a dropped camera or a crash leaves every finished frame readable. A record::

    {"frame": 12, "time": 0.4, "status": "tracked",
     "joints": {"head": [x, y, z], ...} | null,     # metres, camera frame (x right, y down,
                                                    #   z forward), names = skeleton.JOINT_NAMES
     "q": [34 floats] | null,                       # pose, layout of shared.skeleton
     "errors": {"depth_error_cm": 1.1, ...},        # fit figures; non-finite values -> null
     "observed": {"head": true, ...} | null}        # joints the depth image confirms

``status`` is ``tracked`` (the tracker's fit was accepted), ``detected`` (the detector
re-initialized the pose, Wei section 5) or ``lost`` (no usable pose). ``observed`` says, per
joint, whether the camera confirms it (true) or the model infers it from the motion and the
free space behind the visible surface (false, e.g. a far arm hidden behind the torso;
:mod:`runtime.tracker.joint_support`); null where the estimator cannot tell. Older files
have no ``observed`` key. Positions are rounded to micrometres and angles to 1e-7 rad: far
below any sensor accuracy, and it keeps the file small.

Every key, unit and ``errors`` name, and the JSON Schema of a line (``poses.schema.json``
beside this module): docs/format.md.

Reading: only the *last* line may be broken, and only if it has no newline (the writer was
interrupted mid-line); it is dropped and reported as ``truncated``. Any other malformed line
raises :class:`PosesFileError` naming the file and line.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .skeleton import JOINT_NAMES, NUM_DOFS

__all__ = [
    "STATUSES",
    "PosesFileError",
    "PosesData",
    "pose_record",
    "PosesJsonlWriter",
    "read_poses_jsonl",
    "poses_to_arrays",
]

# The one definition of the statuses a frame can have (runtime.estimator re-exports it).
STATUSES: tuple[str, ...] = ("tracked", "detected", "lost")


# --- writing -----------------------------------------------------------------------------------


def _finite_or_none(value: float, digits: int) -> float | None:
    value = float(value)
    return round(value, digits) if math.isfinite(value) else None


def pose_record(
    index: int,
    time: float,
    status: str,
    joints: np.ndarray | None,
    q: np.ndarray | None,
    errors: Mapping[str, float] | None = None,
    joint_names: Sequence[str] = JOINT_NAMES,
    observed: np.ndarray | None = None,
) -> dict:
    """The JSON-ready record of one frame.

    Args:
        index: stream frame index (>= 0).
        time: stream timestamp, seconds.
        status: one of :data:`STATUSES`.
        joints: (J, 3) named joints in camera metres, or None; rows with a non-finite
            coordinate are written as null.
        q: (34,) pose or None.
        errors: fit errors by name (floats; non-finite -> null).
        joint_names: the J names of ``joints``.
        observed: (J,) bool per joint (confirmed by the depth image), or None.
    """
    if status not in STATUSES:
        raise ValueError(f"status must be one of {STATUSES}, got {status!r}")
    if int(index) < 0:
        raise ValueError(f"frame index must be >= 0, got {index}")
    joints_out = None
    if joints is not None:
        j = np.asarray(joints, dtype=np.float64)
        if j.shape != (len(joint_names), 3):
            raise ValueError(f"joints must have shape ({len(joint_names)}, 3), got {j.shape}")
        finite = np.isfinite(j).all(1)
        joints_out = {
            name: [round(float(v), 6) for v in row] if ok else None
            for name, row, ok in zip(joint_names, j, finite)
        }
    q_out = None
    if q is not None:
        qa = np.asarray(q, dtype=np.float64)
        if qa.shape != (NUM_DOFS,):
            raise ValueError(f"q must have shape ({NUM_DOFS},), got {qa.shape}")
        q_out = [_finite_or_none(v, 7) for v in qa]
    errs = {str(k): _finite_or_none(v, 4) for k, v in (errors or {}).items()}
    observed_out = None
    if observed is not None:
        flags = np.asarray(observed)
        if flags.shape != (len(joint_names),) or flags.dtype != bool:
            raise ValueError(f"observed must be ({len(joint_names)},) bool, got {flags.shape}")
        observed_out = {name: bool(f) for name, f in zip(joint_names, flags)}
    return {
        "frame": int(index),
        "time": _finite_or_none(time, 6),
        "status": status,
        "joints": joints_out,
        "q": q_out,
        "errors": errs,
        "observed": observed_out,
    }


class PosesJsonlWriter:
    """Appends one line per frame to ``poses.jsonl`` (truncating an existing file).

    Args:
        path: file to write.
        fsync: also ``os.fsync`` after every frame (survives power loss; costs ~ms per frame
            on slow disks). The line is always flushed to the OS, which survives a crash of
            this process.
    """

    def __init__(self, path: str | Path, fsync: bool = False) -> None:
        self.path = Path(path)
        self.fsync = fsync
        self._file = open(self.path, "w", encoding="utf-8")  # noqa: SIM115 (lives until close)
        self.frames = 0

    def write(self, record: Mapping) -> None:
        """Write one record (see :func:`pose_record`) as a single flushed line."""
        if self._file is None:
            raise ValueError(f"{self.path}: writer is closed")
        line = json.dumps(record, separators=(",", ":"), allow_nan=False) + "\n"
        self._file.write(line)
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())
        self.frames += 1

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> PosesJsonlWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- reading -----------------------------------------------------------------------------------


class PosesFileError(ValueError):
    """A ``poses.jsonl`` that cannot be read: names the file, line and problem."""


def _check_record(rec: object, where: str) -> dict:
    if not isinstance(rec, dict):
        raise PosesFileError(f"{where}: expected a JSON object per line")
    for key in ("frame", "status", "joints", "q"):
        if key not in rec:
            raise PosesFileError(f"{where}: record lacks '{key}'")
    if not isinstance(rec["frame"], int) or isinstance(rec["frame"], bool) or rec["frame"] < 0:
        raise PosesFileError(f"{where}: 'frame' must be a non-negative integer")
    if rec["status"] not in STATUSES:
        raise PosesFileError(f"{where}: status {rec['status']!r} is not one of {STATUSES}")
    joints = rec["joints"]
    if joints is not None:
        if not isinstance(joints, dict):
            raise PosesFileError(f"{where}: 'joints' must be an object or null")
        for name, p in joints.items():
            if p is not None and (
                not isinstance(p, list)
                or len(p) != 3
                or not all(isinstance(v, (int, float)) for v in p)
            ):
                raise PosesFileError(f"{where}: joint {name!r} must be [x, y, z] or null")
    q = rec["q"]
    if q is not None and (not isinstance(q, list) or len(q) != NUM_DOFS):
        raise PosesFileError(f"{where}: 'q' must be a list of {NUM_DOFS} numbers or null")
    if not isinstance(rec.get("errors", {}), dict):
        raise PosesFileError(f"{where}: 'errors' must be an object")
    observed = rec.get("observed")
    if observed is not None and (
        not isinstance(observed, dict) or not all(isinstance(v, bool) for v in observed.values())
    ):
        raise PosesFileError(f"{where}: 'observed' must be an object of true/false or null")
    return rec


@dataclass
class PosesData:
    """Contents of a ``poses.jsonl``.

    Attributes:
        records: the per-frame dicts in file order.
        truncated: True when an unfinished last line (interrupted writer) was dropped.
    """

    records: list[dict]
    truncated: bool


def read_poses_jsonl(path: str | Path) -> PosesData:
    """Read and validate a ``poses.jsonl``.

    Frame indices must increase strictly. An unfinished last line (no newline and not valid
    JSON) is dropped and reported as ``truncated``; everything else that is malformed raises
    :class:`PosesFileError` (``<file>:<line>: problem``).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise PosesFileError(f"{path}: no such file") from None
    except UnicodeDecodeError as err:
        raise PosesFileError(f"{path}: not UTF-8 text ({err})") from None
    lines = text.split("\n")
    # After the final newline split() leaves "", or the unfinished tail of an interrupted write.
    tail = lines.pop()
    records: list[dict] = []
    truncated = False
    numbered = [(n + 1, line, True) for n, line in enumerate(lines)]
    if tail.strip():
        numbered.append((len(lines) + 1, tail, False))
    for lineno, line, complete in numbered:
        where = f"{path}:{lineno}"
        if not line.strip():
            raise PosesFileError(f"{where}: blank line")
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as err:
            if not complete:
                truncated = True
                break
            raise PosesFileError(f"{where}: not valid JSON ({err.msg})") from None
        rec = _check_record(rec, where)
        if records and rec["frame"] <= records[-1]["frame"]:
            raise PosesFileError(
                f"{where}: frame {rec['frame']} does not follow frame {records[-1]['frame']}"
            )
        records.append(rec)
    return PosesData(records, truncated)


def poses_to_arrays(
    records: Sequence[Mapping], joint_names: Sequence[str] = JOINT_NAMES
) -> dict[str, np.ndarray]:
    """Stack records into arrays; missing values are NaN.

    Returns:
        ``frame`` (N,) int64, ``time`` (N,), ``status`` (N,) str, ``joints`` (N, J, 3) metres
        for ``joint_names`` (NaN where absent), ``q`` (N, 34), ``observed`` (N, J) 1.0 for a
        joint the depth image confirms, 0.0 for an inferred one, NaN where not said.
    """
    n, nj = len(records), len(joint_names)
    joints = np.full((n, nj, 3), np.nan)
    q = np.full((n, NUM_DOFS), np.nan)
    observed = np.full((n, nj), np.nan)
    for i, rec in enumerate(records):
        if rec.get("observed"):
            for k, name in enumerate(joint_names):
                flag = rec["observed"].get(name)
                if flag is not None:
                    observed[i, k] = float(flag)
        if rec.get("joints"):
            for k, name in enumerate(joint_names):
                p = rec["joints"].get(name)
                if p is not None:
                    joints[i, k] = p
        if rec.get("q") is not None:
            q[i] = [np.nan if v is None else v for v in rec["q"]]
    return {
        "frame": np.array([r["frame"] for r in records], dtype=np.int64),
        "time": np.array([np.nan if r.get("time") is None else r["time"] for r in records]),
        "status": np.array([r["status"] for r in records], dtype=str),
        "joints": joints,
        "q": q,
        "observed": observed,
    }
