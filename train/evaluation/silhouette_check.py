"""Which side of a disagreement the depth image refutes: a joint the camera could see lies on or
inside the body, so it projects onto the person's pixels (a recording with the background
removed, as UTD-MHAD's, shows only the person). When a result and a reference skeleton
disagree by more than the failure threshold, the frame's worst joint is checked on both: a
joint projecting off the body is wrong whatever the other tracker says. When both project onto
the body the image alone cannot tell (the disagreement is in depth or along the body).
"""

from __future__ import annotations

import numpy as np
from depthmocap.shared.camera import Intrinsics

from .overlay_sheet import project

__all__ = ["SIDES", "on_body", "classify"]

SIDES = ("both_on_body", "reference_off_body", "ours_off_body", "both_off_body")


def on_body(body: np.ndarray, joint: np.ndarray, intr: Intrinsics, slack_px: int = 3) -> bool:
    """Whether the camera-frame ``joint`` (3,) projects within ``slack_px`` pixels of a body
    pixel of ``body`` (H, W) bool. Off the image or behind the camera: False."""
    uv = project(np.asarray(joint, dtype=np.float64)[None], intr)[0]
    if not np.isfinite(uv).all():
        return False
    u, v = (int(round(c)) for c in uv)
    h, w = body.shape
    window = body[max(v - slack_px, 0) : v + slack_px + 1, max(u - slack_px, 0) : u + slack_px + 1]
    return bool(0 <= u < w and 0 <= v < h and window.any())


def classify(reference_on: bool, ours_on: bool) -> str:
    """The :data:`SIDES` entry of one disagreement."""
    if reference_on and ours_on:
        return SIDES[0]
    if ours_on:
        return SIDES[1]
    return SIDES[2] if reference_on else SIDES[3]
