"""The Acclaim motion-capture format (ASF skeleton + AMC motion) of the CMU and HDM05 databases.

Semantics (those of the CMU amc viewer):

* Lengths: ``:units length s`` means one file unit is ``1/s`` inch, i.e. ``0.0254 / s`` metres
  (``length 0.45`` -> 0.05644 m). Bone lengths and the AMC root translation use this unit.
* Angles: ``:units angle deg|rad`` for the ASF; an AMC ``:DEGREES``/``:RADIANS`` header wins for
  the motion values.
* A bone's ``axis a1 a2 a3 ORDER`` pairs the angles with the letters of ORDER, applied in that
  order: ``axis 0 0 20 XYZ`` -> ``C = Rz(20) @ Ry(0) @ Rx(0)``. Its AMC values follow the ``dof``
  order and are applied in that order too: ``dof rx ry rz`` -> ``M = Rz @ Ry @ Rx``.
* Each bone rotates about its own axis frame: ``W_bone = W_parent @ C @ M @ C^-1``, so ``W`` is
  the rotation from the ASF rest pose (all dofs zero) to the current pose, and the bone runs from
  its start (its parent's end) to ``start + W_bone @ (direction * length)``.
* The root: translation and rotation values come in ``:root order`` (e.g. TX TY TZ RX RY RZ),
  rotations applied in that order (``M = Rz @ Ry @ Rx``); ``C`` comes from ``:root orientation``
  with the ``:root axis`` order. The AMC translation is the absolute root position; the
  ``:root position`` (zero in practice) only describes the rest pose and is not added.

Output joints of ``read_amc`` (parents precede children, depth-first over ``:hierarchy``):

* ``root`` at the root translation, orientation ``W_root``;
* one joint per bone, named after the bone, located at the bone's START (e.g. ``lfemur`` is the
  hip, ``ltibia`` the knee, ``lfoot`` the ankle), orientation ``W_bone``;
* for every leaf bone an extra joint ``<bone>_end`` at that bone's END (e.g. ``ltoes_end`` at the
  toe tip, ``head_end`` at the top of the head), orientation ``W_bone`` of its bone.

Positions are in metres in the ASF world frame (Y up for CMU and HDM05); ``offsets[j]`` is the
parent bone's ``direction * length`` in metres (zero for bones hanging off the root).

This module holds what the two readers share (:mod:`train.mocap.asf`, :mod:`train.mocap.amc`):
line tokenizing and the rotation convention.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import numpy as np
from depthmocap.train.mocap.clip import euler_to_matrix

__all__ = ["INCH_M", "ROOT", "applied_in_order", "content_lines", "read_lines", "to_radians"]

INCH_M = 0.0254
ROOT = "root"


def applied_in_order(angles: np.ndarray, order: str) -> np.ndarray:
    """Rotation applying ``angles[..., 0]`` about ``order[0]`` first, then the next, ...

    Args:
        angles: (..., K) radians. order: K axis letters.

    Returns:
        (..., 3, 3), e.g. ``Rz @ Ry @ Rx`` for order ``"XYZ"``.
    """
    return euler_to_matrix(np.asarray(angles)[..., ::-1], order[::-1])


def to_radians(values: np.ndarray | float, unit: str) -> np.ndarray:
    return np.deg2rad(values) if unit == "deg" else np.asarray(values, dtype=np.float64)


def read_lines(path: str | os.PathLike) -> list[str]:
    # latin-1 never fails: HDM05 headers hold Windows paths with umlauts; the numbers are ASCII.
    with open(path, encoding="latin-1") as handle:
        return handle.read().splitlines()


def content_lines(lines: list[str]) -> Iterator[tuple[int, list[str]]]:
    """(1-based line number, tokens) of non-empty lines with ``#`` comments removed."""
    for n, line in enumerate(lines, start=1):
        tokens = line.split("#", 1)[0].split()
        if tokens:
            yield n, tokens
