"""Acclaim skeleton (ASF) reader: bones, axes, dofs and the joint layout of the motions.

The format's semantics (units, axis frames, the root): :mod:`train.mocap.acclaim`; motions
for a skeleton read from here: :mod:`train.mocap.amc`.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depthmocap.train.mocap.acclaim import (
    INCH_M,
    ROOT,
    applied_in_order,
    content_lines,
    read_lines,
    to_radians,
)

__all__ = ["AsfBone", "AsfSkeleton", "read_asf"]

_ROTATION_DOFS = ("rx", "ry", "rz")
_ROOT_CHANNELS = ("tx", "ty", "tz", "rx", "ry", "rz")
_LIMIT_PAIR = re.compile(r"\(\s*([^\s()]+)\s+([^\s()]+)\s*\)")


@dataclass(frozen=True, eq=False)
class AsfBone:
    """One ``:bonedata`` entry.

    Attributes:
        name: bone name.
        id: the ``id`` field (None when absent).
        direction: (3,) unit direction of the bone in the ASF rest pose (world axes).
        length: bone length in metres.
        axis: (3,) axis-frame angles in radians, paired with the letters of ``axis_order``.
        axis_order: e.g. ``"XYZ"``, the order the axis angles are applied in.
        dofs: rotational degrees of freedom in AMC value order, e.g. ``("rx", "ry", "rz")``.
        limits: (len(dofs), 2) joint limits in radians (+-inf where unbounded or absent).
    """

    name: str
    id: int | None
    direction: np.ndarray
    length: float
    axis: np.ndarray
    axis_order: str
    dofs: tuple[str, ...]
    limits: np.ndarray

    @property
    def axis_matrix(self) -> np.ndarray:
        """(3, 3) C, the bone's axis frame in world: columns are its local x, y, z axes."""
        return applied_in_order(self.axis, self.axis_order)

    @property
    def vector(self) -> np.ndarray:
        """(3,) rest-pose bone vector ``direction * length`` in metres."""
        return self.direction * self.length


@dataclass(frozen=True, eq=False)
class AsfSkeleton:
    """A parsed ASF file.

    Attributes:
        name: the ``:name`` field.
        source: the file path.
        length_scale: metres per file length unit (``0.0254 / :units length``).
        angle_unit: ``"deg"`` or ``"rad"``, the unit of ASF angles and the AMC default.
        root_order: AMC channel order of the root, e.g. ``("tx", "ty", "tz", "rx", "ry", "rz")``.
        root_axis: order of the root orientation angles, e.g. ``"XYZ"``.
        root_position: (3,) rest root position in metres (not used by ``read_amc``).
        root_orientation: (3,) root axis-frame angles in radians.
        bones: bones in ``:bonedata`` order.
        parent: bone name -> parent name (``"root"`` for bones attached to the root).
        children: name -> child bone names in ``:hierarchy`` order (``"root"`` included).
    """

    name: str
    source: str
    length_scale: float
    angle_unit: str
    root_order: tuple[str, ...]
    root_axis: str
    root_position: np.ndarray
    root_orientation: np.ndarray
    bones: tuple[AsfBone, ...]
    parent: dict[str, str]
    children: dict[str, tuple[str, ...]]

    def bone(self, name: str) -> AsfBone:
        """The bone called ``name``."""
        for bone in self.bones:
            if bone.name == name:
                return bone
        raise ValueError(f"{self.source}: no bone named {name!r}")

    def joint_layout(self) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
        """Joints as output by ``read_amc``: names (J,), parents (J,), offsets (J, 3) in metres.

        Order: depth-first from ``root`` following ``:hierarchy`` order; each leaf bone is
        followed by its ``<bone>_end`` joint.
        """
        names: list[str] = []
        parents: list[int] = []
        offsets: list[np.ndarray] = []
        bones = {b.name: b for b in self.bones}

        def visit(name: str, parent_index: int, offset: np.ndarray) -> None:
            index = len(names)
            names.append(name)
            parents.append(parent_index)
            offsets.append(offset)
            # A child starts where this bone ends; the root has no extent.
            tip = np.zeros(3) if name == ROOT else bones[name].vector
            kids = self.children.get(name, ())
            for child in kids:
                visit(child, index, tip)
            if not kids and name != ROOT:
                names.append(f"{name}_end")
                parents.append(index)
                offsets.append(tip)

        visit(ROOT, -1, np.zeros(3))
        if len(set(names)) != len(names):
            clash = sorted({n for n in names if names.count(n) > 1})
            raise ValueError(f"{self.source}: bone names clash with end joints {clash}")
        return tuple(names), np.array(parents, dtype=np.int64), np.array(offsets)


def _floats(
    path: str, line: int, tokens: list[str], count: int, what: str, allow_inf: bool = False
) -> np.ndarray:
    if len(tokens) < count:
        raise ValueError(f"{path}:{line}: {what} needs {count} numbers, got {len(tokens)}")
    try:
        values = np.array([float(t) for t in tokens[:count]])
    except ValueError:
        raise ValueError(f"{path}:{line}: non-numeric value in {what}: {tokens[:count]}") from None
    if np.any(np.isnan(values)) or (not allow_inf and not np.all(np.isfinite(values))):
        raise ValueError(f"{path}:{line}: non-finite value in {what}: {tokens[:count]}")
    return values


def _axis_order(path: str, line: int, text: str) -> str:
    order = text.upper()
    if len(order) != 3 or sorted(order) != ["X", "Y", "Z"]:
        raise ValueError(f"{path}:{line}: axis order must be a permutation of XYZ, got {text!r}")
    return order


def _sections(path: str, lines: list[str]) -> dict[str, list[tuple[int, list[str]]]]:
    """Content lines grouped by ``:section``; the section line itself comes first."""
    sections: dict[str, list[tuple[int, list[str]]]] = {}
    current: list[tuple[int, list[str]]] | None = None
    for n, tokens in content_lines(lines):
        if tokens[0].startswith(":"):
            key = tokens[0][1:].lower()
            if key in sections and key in ("units", "root", "bonedata", "hierarchy"):
                raise ValueError(f"{path}:{n}: repeated section :{key}")
            current = sections.setdefault(key, [])
            current.append((n, tokens))
        elif current is None:
            raise ValueError(f"{path}:{n}: text before the first ':section': {' '.join(tokens)!r}")
        else:
            current.append((n, tokens))
    for key in ("root", "bonedata", "hierarchy"):
        if key not in sections:
            raise ValueError(f"{path}:{len(lines)}: missing :{key} section")
    return sections


def _parse_units(path: str, rows: list[tuple[int, list[str]]]) -> tuple[float, str]:
    """(file length value, angle unit) from ``:units`` (defaults: 1.0 i.e. inches, degrees)."""
    length, angle = 1.0, "deg"
    for n, tokens in rows[1:]:
        key = tokens[0].lower()
        if key == "length":
            length = float(_floats(path, n, tokens[1:], 1, "units length")[0])
            if length <= 0:
                raise ValueError(f"{path}:{n}: units length must be positive, got {length}")
        elif key == "angle":
            unit = tokens[1].lower() if len(tokens) > 1 else ""
            if unit in ("deg", "degree", "degrees"):
                angle = "deg"
            elif unit in ("rad", "radian", "radians"):
                angle = "rad"
            else:
                raise ValueError(f"{path}:{n}: angle unit must be deg or rad, got {unit!r}")
    return length, angle


def _parse_root(
    path: str, rows: list[tuple[int, list[str]]], angle: str, scale: float
) -> tuple[tuple[str, ...], str, np.ndarray, np.ndarray]:
    order: tuple[str, ...] = _ROOT_CHANNELS
    axis = "XYZ"
    position = np.zeros(3)
    orientation = np.zeros(3)
    for n, tokens in rows[1:]:
        key = tokens[0].lower()
        if key == "order":
            order = tuple(t.lower() for t in tokens[1:])
            unknown = [t for t in order if t not in _ROOT_CHANNELS]
            if unknown or len(set(order)) != len(order):
                raise ValueError(
                    f"{path}:{n}: root order must list distinct channels of "
                    f"{[c.upper() for c in _ROOT_CHANNELS]}, got {tokens[1:]}"
                )
        elif key == "axis":
            axis = _axis_order(path, n, tokens[1] if len(tokens) > 1 else "")
        elif key == "position":
            position = _floats(path, n, tokens[1:], 3, "root position") * scale
        elif key == "orientation":
            orientation = to_radians(_floats(path, n, tokens[1:], 3, "root orientation"), angle)
    return order, axis, position, orientation


def _parse_dofs(path: str, line: int, tokens: list[str]) -> tuple[str, ...]:
    dofs = tuple(t.lower() for t in tokens)
    if any(d not in _ROTATION_DOFS for d in dofs) or len(set(dofs)) != len(dofs):
        raise ValueError(f"{path}:{line}: unsupported dof list {tokens} (only distinct rx, ry, rz)")
    return dofs


def _parse_limits(
    path: str, name: str, limit_rows: list[tuple[int, str]], num_dofs: int, angle: str
) -> np.ndarray:
    """(num_dofs, 2) limits in radians from the ``(lo hi)`` pairs of a bone's limits rows."""
    limits = np.tile([-np.inf, np.inf], (num_dofs, 1))
    if not limit_rows:
        return limits
    pairs = [(n, m) for n, text in limit_rows for m in _LIMIT_PAIR.finditer(text)]
    if len(pairs) != num_dofs:
        raise ValueError(
            f"{path}:{limit_rows[0][0]}: bone {name!r} has {num_dofs} dofs but "
            f"{len(pairs)} limit pairs"
        )
    for k, (n, match) in enumerate(pairs):
        values = _floats(path, n, list(match.groups()), 2, "limits", allow_inf=True)
        limits[k] = to_radians(values, angle)
    return limits


def _parse_bone(path: str, rows: list[tuple[int, list[str]]], angle: str, scale: float) -> AsfBone:
    """One ``begin`` ... ``end`` block (without those two lines)."""
    first_line = rows[0][0] if rows else 0
    name: str | None = None
    bone_id: int | None = None
    direction: np.ndarray | None = None
    length: float | None = None
    axis: np.ndarray | None = None
    axis_order = "XYZ"
    dofs: tuple[str, ...] = ()
    limit_rows: list[tuple[int, str]] = []
    for n, tokens in rows:
        key, args = tokens[0].lower(), tokens[1:]
        if key.startswith("("):  # continuation of a multi-line `limits`
            if not limit_rows:
                raise ValueError(f"{path}:{n}: limits row without a 'limits' keyword")
            limit_rows.append((n, " ".join(tokens)))
        elif key == "limits":
            limit_rows.append((n, " ".join(args)))
        elif key == "id":
            bone_id = int(_floats(path, n, args, 1, "id")[0])
        elif key == "name":
            if not args:
                raise ValueError(f"{path}:{n}: bone name missing")
            name = args[0]
        elif key == "direction":
            direction = _floats(path, n, args, 3, "direction")
        elif key == "length":
            length = float(_floats(path, n, args, 1, "length")[0])
        elif key == "axis":
            axis = to_radians(_floats(path, n, args, 3, "axis"), angle)
            axis_order = _axis_order(path, n, args[3] if len(args) > 3 else "")
        elif key == "dof":
            dofs = _parse_dofs(path, n, args)
        # bodymass, cofmass and unknown keys do not affect kinematics.

    required = {"name": name, "direction": direction, "length": length, "axis": axis}
    missing = [key for key, value in required.items() if value is None]
    if missing or name is None or direction is None or length is None or axis is None:
        raise ValueError(f"{path}:{first_line}: bone block without {missing}")
    norm = float(np.linalg.norm(direction))
    if length < 0:
        raise ValueError(f"{path}:{first_line}: bone {name!r} has negative length {length}")
    if norm == 0 and length > 0:
        raise ValueError(f"{path}:{first_line}: bone {name!r} has a zero direction")
    return AsfBone(
        name=name,
        id=bone_id,
        # Normalise: the ASF stores the unit direction and the length separately.
        direction=direction / norm if norm > 0 else direction,
        length=length * scale,
        axis=axis,
        axis_order=axis_order,
        dofs=dofs,
        limits=_parse_limits(path, name, limit_rows, len(dofs), angle),
    )


def _blocks(
    path: str, rows: list[tuple[int, list[str]]], section: str
) -> Iterator[list[tuple[int, list[str]]]]:
    """The lines between each ``begin`` and ``end`` of a section (section line excluded)."""
    block: list[tuple[int, list[str]]] | None = None
    for n, tokens in rows[1:]:
        key = tokens[0].lower()
        if key == "begin":
            if block is not None:
                raise ValueError(f"{path}:{n}: 'begin' inside an open block in :{section}")
            block = []
        elif key == "end":
            if block is None:
                raise ValueError(f"{path}:{n}: 'end' without 'begin' in :{section}")
            yield block
            block = None
        elif block is None:
            raise ValueError(f"{path}:{n}: text outside begin/end in :{section}")
        else:
            block.append((n, tokens))
    if block is not None:
        raise ValueError(f"{path}:{rows[0][0]}: :{section} has a 'begin' without 'end'")


def _parse_hierarchy(
    path: str, rows: list[tuple[int, list[str]]], bone_names: set[str]
) -> tuple[dict[str, str], dict[str, tuple[str, ...]]]:
    parent: dict[str, str] = {}
    children: dict[str, tuple[str, ...]] = {}
    for block in _blocks(path, rows, "hierarchy"):
        for n, tokens in block:
            for name in tokens:
                if name != ROOT and name not in bone_names:
                    raise ValueError(f"{path}:{n}: unknown bone {name!r} in :hierarchy")
            head, kids = tokens[0], tokens[1:]
            for kid in kids:
                if kid == ROOT or kid in parent:
                    raise ValueError(f"{path}:{n}: bone {kid!r} is given a second parent")
                parent[kid] = head
            children[head] = children.get(head, ()) + tuple(kids)
    # Every bone must hang off the root; an unreachable bone would also hide a cycle.
    reached, stack = set(), [ROOT]
    while stack:
        name = stack.pop()
        reached.add(name)
        stack.extend(children.get(name, ()))
    missing = sorted(bone_names - reached)
    if missing:
        raise ValueError(f"{path}: bones not connected to root by :hierarchy: {missing}")
    return parent, children


def read_asf(path: str | os.PathLike, *, scale: float | None = None) -> AsfSkeleton:
    """Read an ASF skeleton.

    Args:
        path: the .asf file.
        scale: metres per file length unit; by default ``0.0254 / (:units length)``.

    Returns:
        The skeleton with lengths in metres and angles in radians.

    Raises:
        ValueError: ``<file>:<line>:`` on malformed input (missing sections, bad numbers,
            unknown bones in the hierarchy, unsupported dofs, ...).
    """
    path_str = str(path)
    sections = _sections(path_str, read_lines(path))
    length_value, angle = _parse_units(path_str, sections.get("units", [(0, [":units"])]))
    metres = INCH_M / length_value if scale is None else float(scale)
    if not (math.isfinite(metres) and metres > 0):
        raise ValueError(f"scale must be a positive number of metres per unit, got {scale!r}")
    order, axis, position, orientation = _parse_root(path_str, sections["root"], angle, metres)

    bones = tuple(
        _parse_bone(path_str, block, angle, metres)
        for block in _blocks(path_str, sections["bonedata"], "bonedata")
    )
    names = [b.name for b in bones]
    dupes = sorted({n for n in names if names.count(n) > 1} | ({ROOT} & set(names)))
    if dupes:
        raise ValueError(f"{path_str}: duplicate or reserved bone names {dupes}")
    parent, children = _parse_hierarchy(path_str, sections["hierarchy"], set(names))
    name_rows = sections.get("name", [])
    return AsfSkeleton(
        name=name_rows[0][1][1] if name_rows and len(name_rows[0][1]) > 1 else "",
        source=str(Path(path_str)),
        length_scale=metres,
        angle_unit=angle,
        root_order=order,
        root_axis=axis,
        root_position=position,
        root_orientation=orientation,
        bones=bones,
        parent=parent,
        children=children,
    )
