"""Reading ``poses.jsonl`` (the per-frame tracking result; written by ``runtime.export``).

Shared by the runtime and the evaluation (``train`` may not import ``runtime``). Only the
*last* line may be broken, and only if it has no newline (the writer was interrupted
mid-line); it is dropped and reported as ``truncated``. Any other malformed line raises
:class:`PosesFileError` naming the file and line.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .skeleton import JOINT_NAMES, NUM_DOFS

__all__ = ["STATUSES", "PosesFileError", "PosesData", "read_poses_jsonl", "poses_to_arrays"]

STATUSES: tuple[str, ...] = ("tracked", "detected", "lost")


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
