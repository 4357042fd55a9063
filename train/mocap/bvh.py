"""Biovision hierarchy (BVH) reader.

Supports any rig: several ROOTs, any channel order per joint (e.g. ``Zrotation Yrotation
Xrotation``), and position channels on any joint. Semantics:

* A joint's local rotation is the product of its rotation channels in the order they are listed
  (``Zrotation Yrotation Xrotation`` -> ``Rz @ Ry @ Rx``), angles in degrees.
* Position channels are ADDED to the joint's OFFSET by default (``position_channels="add"``).
  The CMU re-exports in this project need this: their root ``CC_Base_Hip`` has OFFSET
  ``0 105.2 0`` and Yposition values near 7, i.e. a displacement from the rest offset (reading
  them as absolute puts the hips 7 cm above the floor). Exporters that repeat the OFFSET inside
  the channels of every joint (Blender/Mixamo style) need ``position_channels="replace"``.
  Both agree whenever the OFFSET is zero, as for most roots.
* ``End Site`` blocks are skipped by default. With ``include_end_sites=True`` each becomes a leaf
  joint named ``<parent>_end`` (``_end2``, ... for further sites on the same joint) whose offset is
  the End Site OFFSET and whose orientation equals its parent's.
* Output positions are in metres: every OFFSET and position channel is multiplied by ``scale``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .clip import MotionClip, euler_to_matrix, forward_kinematics

# Metres per file unit for the names accepted by ``read_bvh(scale=...)``.
UNIT_SCALES: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}

# "auto" picks the unit that makes the skeleton's longest leaf-to-leaf chain (toe to fingertip
# for a human, about 2 m) closest to this length; cm and inch differ by 2.54x, so a human rig
# between about 1.3 m and 3.2 m along that chain is classified correctly.
_AUTO_REFERENCE_SPAN_M = 2.0

_CHANNELS = {
    "xposition": ("pos", 0),
    "yposition": ("pos", 1),
    "zposition": ("pos", 2),
    "xrotation": ("rot", "x"),
    "yrotation": ("rot", "y"),
    "zrotation": ("rot", "z"),
}


@dataclass
class _Joint:
    name: str
    parent: int
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    channels: tuple[str, ...] = ()
    is_end_site: bool = False
    end_sites: int = field(default=0, repr=False)


class _Tokens:
    """Whitespace tokens of the HIERARCHY section with their 1-based line numbers."""

    def __init__(self, path: str, lines: list[str], start: int, stop: int) -> None:
        self.path = path
        self.items: list[tuple[str, int]] = [
            (tok, n + 1) for n in range(start, stop) for tok in lines[n].split()
        ]
        self.pos = 0
        self.end_line = stop

    def error(self, message: str, line: int | None = None) -> ValueError:
        if line is None:
            line = self.items[self.pos][1] if self.pos < len(self.items) else self.end_line
        return ValueError(f"{self.path}:{line}: {message}")

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.error(f"unexpected end of HIERARCHY, expected {what}")
        item = self.items[self.pos]
        self.pos += 1
        return item

    def expect(self, word: str) -> int:
        tok, line = self.next(repr(word))
        if tok.upper() != word.upper():
            raise self.error(f"expected {word!r}, got {tok!r}", line)
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise self.error(f"expected a number for {what}, got {tok!r}", line) from None
        if not math.isfinite(value):
            raise self.error(f"{what} is not finite: {tok!r}", line)
        return value


def _parse_joint(tokens: _Tokens, joints: list[_Joint], parent: int, keyword: str) -> None:
    """Parse one ROOT/JOINT/End Site block (keyword already consumed) into ``joints``."""
    if keyword == "END":
        site_line = tokens.expect("Site")
        if parent < 0:
            raise tokens.error("End Site outside of a joint", site_line)
        owner = joints[parent]
        owner.end_sites += 1
        suffix = "_end" if owner.end_sites == 1 else f"_end{owner.end_sites}"
        joint = _Joint(name=owner.name + suffix, parent=parent, is_end_site=True)
    else:
        name, line = tokens.next("a joint name")
        if name in ("{", "}"):
            raise tokens.error(f"{keyword} without a name", line)
        joint = _Joint(name=name, parent=parent)
    index = len(joints)
    joints.append(joint)

    tokens.expect("{")
    tokens.expect("OFFSET")
    joint.offset = tuple(tokens.number(f"OFFSET of {joint.name!r}") for _ in range(3))
    if joint.is_end_site:
        tokens.expect("}")
        return

    tok, line = tokens.next("CHANNELS")
    if tok.upper() != "CHANNELS":
        raise tokens.error(f"expected CHANNELS for joint {joint.name!r}, got {tok!r}", line)
    count_tok, line = tokens.next("the channel count")
    if not count_tok.isdigit():
        raise tokens.error(
            f"channel count of {joint.name!r} is not an integer: {count_tok!r}", line
        )
    channels = []
    for _ in range(int(count_tok)):
        chan, line = tokens.next(f"a channel name of {joint.name!r}")
        if chan.lower() not in _CHANNELS:
            raise tokens.error(f"unknown channel {chan!r} for joint {joint.name!r}", line)
        channels.append(chan.lower())
    if len(set(channels)) != len(channels):
        raise tokens.error(f"repeated channel for joint {joint.name!r}: {channels}", line)
    joint.channels = tuple(channels)

    while True:
        tok, line = tokens.next("JOINT, End Site or '}'")
        upper = tok.upper()
        if upper == "}":
            return
        if upper not in ("JOINT", "END"):
            raise tokens.error(
                f"expected JOINT, End Site or '}}' in {joint.name!r}, got {tok!r}", line
            )
        _parse_joint(tokens, joints, index, upper)


def _find_line(path: str, lines: list[str], keyword: str, start: int = 0) -> int:
    """Index of the first line at or after ``start`` whose first token is ``keyword``."""
    for n in range(start, len(lines)):
        parts = lines[n].split(None, 1)
        if parts and parts[0].upper() == keyword:
            return n
    raise ValueError(f"{path}:{len(lines)}: missing {keyword} section")


def _parse_header_value(path: str, lines: list[str], n: int, label: str) -> str:
    """The text after ``label`` (e.g. ``Frames:``) on line index ``n``."""
    if n >= len(lines):
        raise ValueError(f"{path}:{n + 1}: unexpected end of file, expected '{label}'")
    text = lines[n].strip()
    # Normalise spacing so "Frame Time:" and "Frame  Time :" both match.
    key, sep, value = text.partition(":")
    if not sep or " ".join(key.split()).lower() != label.lower():
        raise ValueError(f"{path}:{n + 1}: expected '{label}: <value>', got {text!r}")
    return value.strip()


def _parse_motion_header(path: str, lines: list[str], motion: int) -> tuple[int, float, int]:
    """(frame count, frame time, index of the first data line) after the MOTION line ``motion``.

    Also checks that exactly ``Frames:`` data lines follow, so a truncated or padded file fails
    even when only the first few frames are read.
    """
    frames_text = _parse_header_value(path, lines, motion + 1, "Frames")
    if not frames_text.isdigit():
        raise ValueError(f"{path}:{motion + 2}: frame count is not an integer: {frames_text!r}")
    num_frames = int(frames_text)
    time_text = _parse_header_value(path, lines, motion + 2, "Frame Time")
    try:
        frame_time = float(time_text)
    except ValueError:
        frame_time = float("nan")
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise ValueError(f"{path}:{motion + 3}: invalid frame time {time_text!r}")

    data_start = motion + 3
    # Trailing blank lines are common; blank lines between frames would shift frame numbers.
    data_end = len(lines)
    while data_end > data_start and not lines[data_end - 1].strip():
        data_end -= 1
    if data_end - data_start != num_frames:
        raise ValueError(
            f"{path}:{data_end}: 'Frames: {num_frames}' but the file has "
            f"{data_end - data_start} frame lines"
        )
    blank = next((n for n in range(data_start, data_end) if not lines[n].strip()), None)
    if blank is not None:
        raise ValueError(f"{path}:{blank + 1}: blank line inside the frame data")
    return num_frames, frame_time, data_start


def _parse_frames(
    path: str, lines: list[str], first: int, count: int, num_channels: int
) -> np.ndarray:
    """(count, num_channels) channel values of the data lines starting at line index ``first``."""
    rows = [lines[first + k].split() for k in range(count)]
    for k, row in enumerate(rows):
        if len(row) != num_channels:
            raise ValueError(
                f"{path}:{first + k + 1}: frame {k} has {len(row)} values, "
                f"expected {num_channels} (one per channel in HIERARCHY)"
            )
    if count == 0:
        return np.zeros((0, num_channels))
    try:
        values = np.array(rows, dtype=np.float64)
    except ValueError:
        # Slow path only to name the offending line.
        for k, row in enumerate(rows):
            for tok in row:
                try:
                    float(tok)
                except ValueError:
                    raise ValueError(
                        f"{path}:{first + k + 1}: non-numeric value {tok!r} in frame {k}"
                    ) from None
        raise
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        k = int(bad[0])
        raise ValueError(f"{path}:{first + k + 1}: non-finite value in frame {k}")
    return values


def _fps_from_frame_time(frame_time: float) -> float:
    """Frame rate, snapped to an integer when the file rounded the frame time (1/60 -> 0.016667)."""
    fps = 1.0 / frame_time
    nearest = round(fps)
    return float(nearest) if nearest > 0 and abs(fps - nearest) < 1e-4 * fps else fps


def _tree_span(parents: np.ndarray, offsets: np.ndarray) -> float:
    """Longest path between any two joints along the bones (sum of offset lengths)."""
    lengths = np.linalg.norm(offsets, axis=1)
    depth = np.zeros(len(parents))  # longest downward path from each joint
    best = 0.0
    for j in range(len(parents) - 1, -1, -1):  # children have larger indices
        p = parents[j]
        if p >= 0:
            down = depth[j] + lengths[j]
            best = max(best, depth[p] + down)
            depth[p] = max(depth[p], down)
    return float(max(best, depth.max()))


def _resolve_scale(
    scale: float | str, parents: np.ndarray, offsets: np.ndarray, path: str
) -> float:
    if isinstance(scale, str):
        key = scale.lower()
        if key == "auto":
            span = _tree_span(parents, offsets)
            if span <= 0:
                raise ValueError(f"{path}: cannot guess units of a skeleton with zero size")
            return min(
                UNIT_SCALES.values(),
                key=lambda s: abs(math.log(span * s / _AUTO_REFERENCE_SPAN_M)),
            )
        if key not in UNIT_SCALES:
            raise ValueError(
                f"unknown unit {scale!r}; expected a number (metres per unit), 'auto' or one of "
                f"{sorted(UNIT_SCALES)}"
            )
        return UNIT_SCALES[key]
    value = float(scale)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"scale must be a positive number of metres per file unit, got {scale!r}")
    return value


def _local_transforms(
    joints: list[_Joint], values: np.ndarray, scale: float, replace: bool
) -> tuple[np.ndarray, np.ndarray]:
    """(F, J, 3, 3) local rotations and (F, J, 3) local translations (metres) per joint.

    ``values`` is (F, C) with the channels of all joints in file order; ``replace`` makes
    position channels replace the OFFSET instead of adding to it.
    """
    num_frames, num_joints = values.shape[0], len(joints)
    rotations = np.broadcast_to(np.eye(3), (num_frames, num_joints, 3, 3)).copy()
    translations = np.empty((num_frames, num_joints, 3))
    column = 0
    for j, joint in enumerate(joints):
        translations[:, j] = np.asarray(joint.offset) * scale
        rot_axes, rot_columns = "", []
        for chan in joint.channels:
            kind, which = _CHANNELS[chan]
            if kind == "pos" and replace:
                translations[:, j, which] = values[:, column] * scale
            elif kind == "pos":
                translations[:, j, which] += values[:, column] * scale
            else:
                rot_axes += which
                rot_columns.append(column)
            column += 1
        if rot_axes:
            rotations[:, j] = euler_to_matrix(np.deg2rad(values[:, rot_columns]), rot_axes)
    return rotations, translations


def read_bvh(
    path: str | os.PathLike,
    scale: float | str = 0.01,
    *,
    max_frames: int | None = None,
    include_end_sites: bool = False,
    position_channels: str = "add",
) -> MotionClip:
    """Read a BVH file and evaluate its forward kinematics.

    Args:
        path: the .bvh file.
        scale: metres per file unit (default 0.01: centimetres), or a unit name: ``"m"``,
            ``"cm"``, ``"mm"``, ``"in"``, or ``"auto"`` (guess from the size of a human rig).
        max_frames: read at most this many frames from the start (the whole file is still
            checked for the declared frame count).
        include_end_sites: add each End Site as a leaf joint ``<parent>_end``.
        position_channels: ``"add"`` (channel values displace the OFFSET) or ``"replace"``
            (channel values are the joint's translation); see the module docstring.

    Returns:
        A MotionClip with one joint per ROOT/JOINT (plus end sites if asked) in file order:
        rotations (F, J, 3, 3) global joint orientations, positions (F, J, 3) in metres in the
        file's world frame, offsets (J, 3) the scaled OFFSETs, fps = 1 / Frame Time.

    Raises:
        ValueError: with ``<file>:<line>:`` for malformed files (missing sections, bad channel
            counts per frame line, a frame count that disagrees with ``Frames:``, non-numeric
            values).
    """
    path_str = str(path)
    if max_frames is not None and max_frames < 0:
        raise ValueError(f"max_frames must be >= 0, got {max_frames}")
    if position_channels not in ("add", "replace"):
        raise ValueError(f"position_channels must be 'add' or 'replace', got {position_channels!r}")
    with open(path, encoding="latin-1") as handle:
        lines = handle.read().splitlines()

    first = next((n for n, line in enumerate(lines) if line.strip()), None)
    if first is None or lines[first].split()[0].upper() != "HIERARCHY":
        where = f"{path_str}:{(first or 0) + 1}"
        raise ValueError(f"{where}: missing HIERARCHY section (it must come first)")
    motion = _find_line(path_str, lines, "MOTION", first + 1)
    if len(lines[motion].split()) != 1:
        raise ValueError(f"{path_str}:{motion + 1}: unexpected text after MOTION")

    tokens = _Tokens(path_str, lines, first + 1, motion)
    joints: list[_Joint] = []
    while tokens.peek() is not None:
        tok, line = tokens.next("ROOT")
        if tok.upper() != "ROOT":
            raise tokens.error(f"expected ROOT, got {tok!r}", line)
        _parse_joint(tokens, joints, -1, "ROOT")
    if not joints:
        raise ValueError(f"{path_str}:{first + 1}: HIERARCHY defines no ROOT joint")
    names = [j.name for j in joints]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ValueError(f"{path_str}: duplicate joint names {dupes}")

    num_frames, frame_time, data_start = _parse_motion_header(path_str, lines, motion)

    kept = [j for j in joints if include_end_sites or not j.is_end_site]
    # Re-index parents after dropping end sites (they are leaves, so no parent disappears).
    new_index = {id(j): k for k, j in enumerate(kept)}
    parents = np.array(
        [-1 if j.parent < 0 else new_index[id(joints[j.parent])] for j in kept], dtype=np.int64
    )

    count = num_frames if max_frames is None else min(num_frames, max_frames)
    num_channels = sum(len(j.channels) for j in joints)
    values = _parse_frames(path_str, lines, data_start, count, num_channels)

    raw_offsets = np.array([j.offset for j in kept], dtype=np.float64)
    metres = _resolve_scale(scale, parents, raw_offsets, path_str)
    local_rot, local_trans = _local_transforms(
        kept, values, metres, replace=position_channels == "replace"
    )
    rotations, positions = forward_kinematics(parents, local_rot, local_trans)
    return MotionClip(
        joint_names=tuple(j.name for j in kept),
        parents=parents,
        rotations=rotations,
        positions=positions,
        fps=_fps_from_frame_time(frame_time),
        source=str(Path(path_str)),
        offsets=raw_offsets * metres,
    )
