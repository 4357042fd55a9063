"""``poses.jsonl``: the per-frame tracking result, one JSON object per line.

Each line is written whole and flushed as soon as its frame is done, so a run cut off by
Ctrl-C, a dropped camera or a crash leaves every finished frame readable. A record::

    {"frame": 12, "time": 0.4, "status": "tracked",
     "joints": {"head": [x, y, z], ...} | null,     # metres, camera frame (x right, y down,
                                                    #   z forward), names = skeleton.JOINT_NAMES
     "q": [34 floats] | null,                       # pose, layout of shared.skeleton
     "errors": {"depth_mm": 11.2, ...},             # fit errors; non-finite values -> null
     "observed": {"head": true, ...} | null}        # joints the depth image confirms

``status`` is ``tracked`` (the tracker's fit was accepted), ``detected`` (the detector
re-initialized the pose, Wei section 5) or ``lost`` (no usable pose). ``observed`` says, per
joint, whether the camera confirms it (true) or the model infers it from the motion and the
free space behind the visible surface (false, e.g. a far arm hidden behind the torso;
:mod:`runtime.tracker.joint_support`); null where the estimator cannot tell. Older files
have no ``observed`` key. Positions are rounded
to micrometres and angles to 1e-7 rad: far below any sensor accuracy, and it keeps the file
small.

:func:`shared.poses_format.read_poses_jsonl` reads a file back (re-exported here).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from shared.poses_format import (
    STATUSES,
    PosesData,
    PosesFileError,
    poses_to_arrays,
    read_poses_jsonl,
)
from shared.skeleton import JOINT_NAMES, NUM_DOFS

__all__ = [
    "STATUSES",
    "PosesFileError",
    "PosesJsonlWriter",
    "PosesData",
    "pose_record",
    "read_poses_jsonl",
    "poses_to_arrays",
]


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
