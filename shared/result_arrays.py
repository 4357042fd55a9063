"""A tracking result directory read into numpy arrays (``depthmocap.read_poses``)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .poses_format import PosesFileError, poses_to_arrays, read_poses_jsonl
from .skeleton import JOINT_NAMES

__all__ = ["Poses", "read_poses"]


@dataclass(frozen=True)
class Poses:
    """The poses of a result, one row per written frame (N frames, J = 16 named joints).

    Attributes:
        frame: (N,) int64 frame index in the source.
        time: (N,) seconds since the start of the source.
        status: (N,) str, "tracked", "detected" or "lost".
        joints: (N, J, 3) camera metres (x right, y down, z forward); NaN on lost frames.
        q: (N, 34) pose parameters (shared.skeleton layout); NaN on lost frames.
        observed: (N, J) 1.0 where the depth image confirms a joint, 0.0 where it is
            inferred, NaN where not said.
        joint_names: the J names, in column order.
        truncated: the run was cut off mid-line (its last, unfinished line was dropped).
        summary: ``summary.json`` of the result directory, None when there is none.
    """

    frame: np.ndarray
    time: np.ndarray
    status: np.ndarray
    joints: np.ndarray
    q: np.ndarray
    observed: np.ndarray
    joint_names: tuple[str, ...]
    truncated: bool
    summary: dict | None

    def __len__(self) -> int:
        return len(self.frame)

    def joint(self, name: str) -> np.ndarray:
        """(N, 3) trajectory of the joint ``name``."""
        return self.joints[:, self.joint_names.index(name)]


def read_poses(path: str | Path) -> Poses:
    """Read a result directory (or its ``poses.jsonl``) into arrays.

    Raises:
        PosesFileError: missing or malformed ``poses.jsonl`` or ``summary.json``.
    """
    path = Path(path)
    jsonl = path / "poses.jsonl" if path.is_dir() else path
    data = read_poses_jsonl(jsonl)
    arrays = poses_to_arrays(data.records, JOINT_NAMES)
    summary = None
    summary_path = jsonl.with_name("summary.json")
    if summary_path.is_file():
        try:
            summary = json.loads(summary_path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise PosesFileError(f"{summary_path}: not valid JSON ({err})") from None
    return Poses(
        **arrays, joint_names=tuple(JOINT_NAMES), truncated=data.truncated, summary=summary
    )
