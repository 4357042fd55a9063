"""Contact sheets of tracked frames beside a reference skeleton, for looking at where a result
and the reference disagree.

A tile is one of ``runtime-track --save-overlays``' images (depth in grey, the forest's labels
tinted, our skeleton in green with yellow joints, inferred joints as red rings) with the
reference's skeleton drawn over it in magenta and the worst joint of both ringed in white, cut
around the person and captioned. Pure numpy + OpenCV drawing; nothing is read here.
"""

from __future__ import annotations

import numpy as np
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.skeleton import JOINT_BONES

__all__ = ["project", "draw_reference", "crop_around", "caption", "tile_sheet"]

REFERENCE_BGR = (255, 0, 255)
WORST_BGR = (255, 255, 255)


def project(joints: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Pixel positions (J, 2) of camera-frame joints (J, 3); NaN where a joint is missing or
    not in front of the camera."""
    joints = np.asarray(joints, dtype=np.float64)
    z = np.where(joints[:, 2] > 1e-3, joints[:, 2], np.nan)
    return np.stack([intr.fx * joints[:, 0] / z + intr.cx, intr.fy * joints[:, 1] / z + intr.cy], 1)


def _pixel(p: np.ndarray) -> tuple[int, int] | None:
    return (int(round(p[0])), int(round(p[1]))) if np.isfinite(p).all() else None


def draw_reference(
    image: np.ndarray,
    reference_px: np.ndarray,
    names: tuple[str, ...],
    worst: str | None = None,
    tracked_px: np.ndarray | None = None,
) -> np.ndarray:
    """A copy of the BGR ``image`` with the reference's stick figure over it.

    Args:
        reference_px: (J, 2) pixels of the reference's joints named ``names`` (ours).
        worst: a joint to ring in white, on the reference and, given ``tracked_px`` (J, 2),
            on our skeleton too.
    """
    import cv2

    out = image.copy()
    pix = {n: _pixel(p) for n, p in zip(names, reference_px)}
    for a, b in JOINT_BONES:
        if pix.get(a) and pix.get(b):
            cv2.line(out, pix[a], pix[b], REFERENCE_BGR, 1, cv2.LINE_AA)
    for p in pix.values():
        if p:
            cv2.circle(out, p, 2, REFERENCE_BGR, -1, cv2.LINE_AA)
    if worst in names:
        j = names.index(worst)
        for points in (reference_px, tracked_px):
            p = _pixel(points[j]) if points is not None else None
            if p:
                cv2.circle(out, p, 6, WORST_BGR, 1, cv2.LINE_AA)
    return out


def crop_around(image: np.ndarray, points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The ``size`` = (width, height) window of ``image`` centred on the finite ``points``
    (N, 2) (the person), shifted to stay inside the image; zero-padded if the image is
    smaller."""
    h, w = image.shape[:2]
    cw, ch = size
    finite = points[np.isfinite(points).all(1)]
    cx, cy = finite.mean(0) if len(finite) else (w / 2, h / 2)
    u0 = int(np.clip(round(cx - cw / 2), 0, max(w - cw, 0)))
    v0 = int(np.clip(round(cy - ch / 2), 0, max(h - ch, 0)))
    out = np.zeros((ch, cw) + image.shape[2:], image.dtype)
    window = image[v0 : v0 + ch, u0 : u0 + cw]
    out[: window.shape[0], : window.shape[1]] = window
    return out


def caption(image: np.ndarray, lines: list[str], scale: int = 2) -> np.ndarray:
    """``image`` enlarged ``scale`` times (nearest pixel: the depth stays crisp) with ``lines``
    of text on a dark band above it."""
    import cv2

    big = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    band = np.zeros((14 * len(lines) + 4, big.shape[1], 3), np.uint8)
    for i, text in enumerate(lines):
        cv2.putText(band, text, (3, 13 + 14 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    (230, 230, 230), 1, cv2.LINE_AA)  # fmt: skip
    return np.concatenate([band, big], 0)


def tile_sheet(tiles: list[np.ndarray], columns: int) -> np.ndarray:
    """Equal-sized BGR tiles (H, W, 3) in rows of ``columns`` with a 2-pixel grey gap."""
    if not tiles:
        raise ValueError("no tiles")
    gap = 2
    h, w = tiles[0].shape[:2]
    rows = -(-len(tiles) // columns)
    sheet = np.full((rows * (h + gap) - gap, columns * (w + gap) - gap, 3), 90, np.uint8)
    for i, t in enumerate(tiles):
        r, c = divmod(i, columns)
        sheet[r * (h + gap) : r * (h + gap) + h, c * (w + gap) : c * (w + gap) + w] = t
    return sheet
