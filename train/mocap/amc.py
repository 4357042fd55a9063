"""Acclaim motion (AMC) reader: one clip of an ASF skeleton, as global joint poses in metres.

The format's semantics and the joints of the output: :mod:`train.mocap.acclaim`.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from depthmocap.train.mocap.acclaim import (
    ROOT,
    applied_in_order,
    content_lines,
    read_lines,
    to_radians,
)
from depthmocap.train.mocap.asf import AsfSkeleton, read_asf
from depthmocap.train.mocap.clip import MotionClip, forward_kinematics

__all__ = ["read_amc"]


def _parse_amc(
    path: str, lines: list[str], expected: dict[str, int], max_frames: int | None
) -> tuple[dict[str, np.ndarray], str | None]:
    """Per-bone (F, n_values) arrays of an AMC file, and the angle unit its header declares."""
    values: dict[str, list[list[float]]] = {name: [] for name in expected}
    unit: str | None = None
    frame_number: int | None = None
    frame_line = 0
    seen: set[str] = set()
    count = 0

    def close_frame() -> None:
        missing = sorted(set(expected) - seen)
        if frame_number is not None and missing:
            raise ValueError(f"{path}:{frame_line}: frame {frame_number} lacks bones {missing}")

    for n, tokens in content_lines(lines):
        head = tokens[0]
        if head.startswith(":"):
            if frame_number is not None:
                raise ValueError(f"{path}:{n}: header keyword {head!r} after the first frame")
            if head.upper() == ":DEGREES":
                unit = "deg"
            elif head.upper() == ":RADIANS":
                unit = "rad"
            continue
        if len(tokens) == 1 and head.isdigit():
            close_frame()
            number = int(head)
            if frame_number is not None and number != frame_number + 1:
                raise ValueError(
                    f"{path}:{n}: frame number {number} does not follow {frame_number}"
                )
            if max_frames is not None and count >= max_frames:
                frame_number = None  # the last kept frame was already checked
                break
            frame_number, frame_line, seen = number, n, set()
            count += 1
            continue
        if frame_number is None:
            raise ValueError(f"{path}:{n}: bone data before the first frame number: {head!r}")
        if head not in expected:
            raise ValueError(f"{path}:{n}: bone {head!r} is not animated by the skeleton")
        if head in seen:
            raise ValueError(f"{path}:{n}: bone {head!r} appears twice in frame {frame_number}")
        if len(tokens) - 1 != expected[head]:
            raise ValueError(
                f"{path}:{n}: bone {head!r} has {len(tokens) - 1} values, expected {expected[head]}"
            )
        try:
            row = [float(t) for t in tokens[1:]]
        except ValueError:
            raise ValueError(f"{path}:{n}: non-numeric value for {head!r}: {tokens[1:]}") from None
        if not all(math.isfinite(v) for v in row):
            raise ValueError(f"{path}:{n}: non-finite value for {head!r}: {tokens[1:]}")
        seen.add(head)
        values[head].append(row)
    close_frame()
    arrays = {
        name: np.array(rows, dtype=np.float64).reshape(count, expected[name])
        for name, rows in values.items()
    }
    return arrays, unit


def read_amc(
    path: str | os.PathLike,
    skeleton: AsfSkeleton | str | os.PathLike,
    fps: float = 120.0,
    *,
    max_frames: int | None = None,
) -> MotionClip:
    """Read an AMC motion for an ASF skeleton and evaluate its forward kinematics.

    Args:
        path: the .amc file.
        skeleton: the parsed ASF (or a path to one).
        fps: frame rate (AMC files do not store it; HDM05 and CMU use 120).
        max_frames: read at most this many frames from the start.

    Returns:
        A MotionClip with the joints of ``skeleton.joint_layout()`` (:mod:`train.mocap.acclaim`):
        rotations (F, J, 3, 3) rest-to-current world rotations, positions (F, J, 3) in metres.

    Raises:
        ValueError: ``<file>:<line>:`` on malformed input (non-numeric values, wrong value
            counts, unknown or missing bones, non-consecutive frame numbers).
    """
    if not isinstance(skeleton, AsfSkeleton):
        skeleton = read_asf(skeleton)
    if max_frames is not None and max_frames < 0:
        raise ValueError(f"max_frames must be >= 0, got {max_frames}")
    path_str = str(path)
    expected = {ROOT: len(skeleton.root_order)}
    expected.update({b.name: len(b.dofs) for b in skeleton.bones if b.dofs})
    data, header_unit = _parse_amc(path_str, read_lines(path), expected, max_frames)
    unit = header_unit or skeleton.angle_unit

    names, parents, offsets = skeleton.joint_layout()
    num_frames = data[ROOT].shape[0]
    local_rot = np.broadcast_to(np.eye(3), (num_frames, len(names), 3, 3)).copy()
    local_trans = np.broadcast_to(offsets, (num_frames, len(names), 3)).copy()

    # Root: channels by name in the declared order; rotations applied in that order.
    root_values = data[ROOT]
    order = skeleton.root_order
    for k, channel in enumerate(("tx", "ty", "tz")):
        if channel in order:
            local_trans[:, 0, k] = root_values[:, order.index(channel)] * skeleton.length_scale
    rot_columns = [k for k, c in enumerate(order) if c.startswith("r")]
    root_motion = applied_in_order(
        to_radians(root_values[:, rot_columns], unit), "".join(order[k][1] for k in rot_columns)
    )
    root_axis = applied_in_order(skeleton.root_orientation, skeleton.root_axis)
    local_rot[:, 0] = root_axis @ root_motion @ root_axis.T

    bones = {b.name: b for b in skeleton.bones}
    for j, name in enumerate(names):
        bone = bones.get(name)
        if bone is None or not bone.dofs:  # root, end joints and fixed bones
            continue
        axis = bone.axis_matrix
        motion = applied_in_order(to_radians(data[name], unit), "".join(d[1] for d in bone.dofs))
        # Rotate about the bone's own axis frame, expressed in world rest coordinates.
        local_rot[:, j] = axis @ motion @ axis.T

    rotations, positions = forward_kinematics(parents, local_rot, local_trans)
    return MotionClip(
        joint_names=names,
        parents=parents,
        rotations=rotations,
        positions=positions,
        fps=fps,
        source=str(Path(path_str)),
        offsets=offsets,
    )
