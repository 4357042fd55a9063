"""Overlay images of a result: depth, part labels and the skeleton (``--save-overlays``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from depthmocap.shared.skeleton import JOINT_BONES, JOINT_NAMES

if TYPE_CHECKING:
    from depthmocap.runtime.estimator import PoseEstimate
    from depthmocap.runtime.frame import Frame

__all__ = ["draw_overlay"]


def draw_overlay(frame: Frame, est: PoseEstimate) -> np.ndarray:
    """BGR image of ``frame``: depth in grey, the part labels (or the person mask) tinted,
    the skeleton with inferred joints as red rings."""
    import cv2
    from depthmocap.shared.labels import PART_COLORS

    depth = frame.depth_m.detach().cpu().numpy()
    valid = depth > 0
    lo, hi = np.percentile(depth[valid], [2, 98]) if valid.any() else (0.0, 1.0)
    grey = np.clip(255 * (1 - (depth - lo) / max(hi - lo, 1e-3)), 40, 255).astype(np.uint8)
    img = cv2.cvtColor(np.where(valid, grey, 0).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    m = frame.mask.detach().cpu().numpy().astype(bool)
    if est.labels is not None and est.labels.shape == m.shape:
        tint = PART_COLORS[est.labels][..., ::-1]
        show = est.labels > 0
    else:
        tint = np.broadcast_to(np.array([60, 60, 220], np.uint8), img.shape)
        show = m
    img[show] = (0.5 * img[show] + 0.5 * tint[show]).astype(np.uint8)
    if est.joints is not None and np.isfinite(est.joints).all():
        intr = frame.intrinsics
        z = np.maximum(est.joints[:, 2], 1e-3)
        uv = np.stack(
            [intr.fx * est.joints[:, 0] / z + intr.cx, intr.fy * est.joints[:, 1] / z + intr.cy], 1
        )
        pix = {n: tuple(int(round(c)) for c in uv[i]) for i, n in enumerate(JOINT_NAMES)}
        for a, b in JOINT_BONES:
            cv2.line(img, pix[a], pix[b], (0, 255, 0), 1, cv2.LINE_AA)
        for p, ok in zip(pix.values(), est.observed_or_all()):
            # Inferred joints (the camera does not confirm them) as open red rings.
            if ok:
                cv2.circle(img, p, 2, (0, 255, 255), -1, cv2.LINE_AA)
            else:
                cv2.circle(img, p, 3, (0, 0, 255), 1, cv2.LINE_AA)
    return img
