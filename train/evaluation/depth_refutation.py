"""Which side of a disagreement the depth image refutes.

The camera sees along each pixel's ray up to the first surface, so a body joint (inside the
body, behind its skin) can lie neither off the person's pixels (a recording with the
background removed, as UTD-MHAD's, shows only the person) nor in front of the surface the
camera sees at its pixel: that space is seen to be empty. A joint that does either is wrong
whatever the other tracker says. The tests are loose on purpose: a joint counts as on the
body within ``SLACK_PX`` pixels of a person pixel, and as in empty space only where its own
pixel has a depth reading and it lies more than ``FREE_SPACE_M`` in front of the nearest
surface seen within that window (a hand a few pixels wide, depth noise and the body's own
thickness all pass; a hole in the depth, where a part may have been cut out with the
background, proves nothing). A joint outside the image cannot be checked and is not
refuted. When neither side is refuted the image alone cannot tell which tracker is wrong
(the disagreement is inside the body or behind what the camera sees).
"""

from __future__ import annotations

import numpy as np
from depthmocap.shared.camera import Intrinsics

from .overlay_sheet import project

__all__ = [
    "FREE_SPACE_M",
    "HIDDEN_M",
    "PLACES",
    "SIDES",
    "SLACK_PX",
    "classify",
    "joint_places",
    "refuted",
]

SIDES = ("neither_refuted", "reference_refuted", "ours_refuted", "both_refuted")
# A joint within this many pixels of a person pixel is on the body (about 3 cm at 3 m).
SLACK_PX = 3
# A joint more than this in front of the nearest surface seen around its pixel is in empty
# space (m): several times Kinect v1's depth noise at 4 m, and more than a limb's radius.
FREE_SPACE_M = 0.10


# Where a joint lies against the depth image (:func:`joint_places`).
PLACES = ("outside", "off_body", "in_front", "on_surface", "hidden")
OUTSIDE, OFF_BODY, IN_FRONT, ON_SURFACE, HIDDEN = range(len(PLACES))
# A joint more than this behind the nearest surface seen around its pixel is hidden (m): more
# than a limb's thickness, so a joint inside a limb the camera sees is not.
HIDDEN_M = 0.15


def joint_places(
    depth_m: np.ndarray,
    joints: np.ndarray,
    intr: Intrinsics,
    slack_px: int = SLACK_PX,
    free_space_m: float = FREE_SPACE_M,
    hidden_m: float = HIDDEN_M,
) -> np.ndarray:
    """The :data:`PLACES` index of each of one frame's camera-frame ``joints`` (J, 3): (J,).

    ``outside``: outside the image, behind the camera or missing; ``off_body``: no person
    pixel (depth > 0 in ``depth_m``, (H, W) metres of the person only) within ``slack_px``
    of its pixel; ``in_front``: its own pixel has a depth and it lies more than
    ``free_space_m`` in front of the nearest depth in that window (a hole proves nothing);
    ``hidden``: more than ``hidden_m`` behind that nearest depth; else ``on_surface``.
    """
    joints = np.asarray(joints, dtype=np.float64)
    h, w = depth_m.shape
    places = np.full(len(joints), OUTSIDE, dtype=np.int64)
    uv = project(joints, intr)
    near = np.pad(np.where(depth_m > 0, depth_m, np.inf), slack_px, constant_values=np.inf)
    for j in np.flatnonzero(np.isfinite(uv).all(1)):
        u, v = (int(round(c)) for c in uv[j])
        if not (0 <= u < w and 0 <= v < h):
            continue
        nearest = near[v : v + 2 * slack_px + 1, u : u + 2 * slack_px + 1].min()
        z = joints[j, 2]
        if not np.isfinite(nearest):
            places[j] = OFF_BODY
        elif depth_m[v, u] > 0 and z < nearest - free_space_m:
            places[j] = IN_FRONT
        elif z > nearest + hidden_m:
            places[j] = HIDDEN
        else:
            places[j] = ON_SURFACE
    return places


def refuted(
    depth_m: np.ndarray,
    joints: np.ndarray,
    intr: Intrinsics,
    slack_px: int = SLACK_PX,
    free_space_m: float = FREE_SPACE_M,
) -> np.ndarray:
    """Which of one frame's camera-frame ``joints`` (J, 3) the depth image refutes: (J,) bool.

    A joint is refuted when it is behind the camera or not finite, when no person pixel
    (depth > 0) lies within ``slack_px`` of its pixel, or when its own pixel has a depth and
    it lies more than ``free_space_m`` in front of the nearest depth in that window
    (:func:`joint_places` ``off_body`` or ``in_front``). ``depth_m``: (H, W) metres of the
    person only, 0 elsewhere. Joints projecting outside the image are not refuted.
    """
    joints = np.asarray(joints, dtype=np.float64)
    places = joint_places(depth_m, joints, intr, slack_px, free_space_m)
    broken = ~np.isfinite(joints).all(1) | ~(joints[:, 2] > 1e-3)
    return broken | (places == OFF_BODY) | (places == IN_FRONT)


def classify(reference_refuted: bool, ours_refuted: bool) -> str:
    """The :data:`SIDES` entry of one disagreement."""
    return SIDES[int(bool(reference_refuted)) + 2 * int(bool(ours_refuted))]
