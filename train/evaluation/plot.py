"""Evaluation plot drawn with OpenCV only (no plotting library is a project dependency).

Top panel: mean joint error per frame (mm), the background of each frame coloured by its
status (tracked, detected, lost, missing), the 10 cm line dashed. Bottom panel: mean error per
joint, raw (dark) and offset-normalized (light) bars side by side.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

__all__ = ["STATUS_COLOURS", "render_plot", "save_plot"]

# BGR
STATUS_COLOURS = {
    "tracked": (205, 235, 205),
    "detected": (160, 210, 250),
    "lost": (170, 170, 245),
    "missing": (215, 215, 215),
}
_WHITE, _BLACK, _GREY = (255, 255, 255), (0, 0, 0), (110, 110, 110)
_RAW, _NORM, _CURVE = (140, 80, 30), (230, 180, 120), (40, 40, 40)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _text(img, s: str, xy, scale: float = 0.45, colour=_BLACK) -> None:
    cv2.putText(img, s, (int(xy[0]), int(xy[1])), _FONT, scale, colour, 1, cv2.LINE_AA)


def _nice_max(v: float) -> float:
    """A round axis maximum at or above ``v`` (at least 100 mm so the 10 cm line shows)."""
    v = max(float(v), 100.0)
    step = 10 ** np.floor(np.log10(v))
    return float(np.ceil(v / step) * step)


def _curve_panel(img, box, frame_mm: np.ndarray, status: np.ndarray, threshold_mm: float):
    x0, y0, x1, y1 = box
    n = len(frame_mm)
    finite = frame_mm[np.isfinite(frame_mm)]
    ymax = _nice_max(np.quantile(finite, 0.99) * 1.1 if finite.size else 0.0)
    xs = x0 + (np.arange(n) + 0.5) * (x1 - x0) / max(n, 1)
    edges = x0 + np.arange(n + 1) * (x1 - x0) / max(n, 1)
    # Status bands: one rectangle per run of equal status.
    if n:
        change = np.flatnonzero(status[1:] != status[:-1]) + 1
        starts, stops = np.r_[0, change], np.r_[change, n]
        for a, b in zip(starts, stops):
            colour = STATUS_COLOURS.get(str(status[a]), _WHITE)
            cv2.rectangle(img, (int(edges[a]), y0), (int(edges[b]) - 1, y1), colour, -1)

    def y_of(v):
        return y1 - np.clip(v, 0, ymax) / ymax * (y1 - y0)

    for k in range(5):
        v = ymax * k / 4
        y = int(y_of(v))
        cv2.line(img, (x0 - 4, y), (x0, y), _BLACK, 1)
        _text(img, f"{v:.0f}", (x0 - 48, y + 4), 0.4)
    yt = int(y_of(threshold_mm))
    for xa in range(x0, x1, 12):
        cv2.line(img, (xa, yt), (min(xa + 6, x1), yt), _GREY, 1)
    # Polyline through frames with a pose; gaps break the line.
    ok = np.isfinite(frame_mm)
    pts = np.stack([xs, y_of(np.where(ok, frame_mm, 0))], 1).round().astype(np.int32)
    breaks = np.flatnonzero(np.diff(ok.astype(np.int8)) != 0) + 1
    for seg_idx, seg in zip(np.split(np.arange(n), breaks), np.split(ok, breaks)):
        if seg.size and seg[0]:
            cv2.polylines(img, [pts[seg_idx][:, None]], False, _CURVE, 1, cv2.LINE_AA)
    cv2.rectangle(img, (x0, y0), (x1, y1), _BLACK, 1)
    _text(img, "mean joint error per frame (mm)", (x0, y0 - 10), 0.5)
    _text(img, "frame", (x1 - 40, y1 + 30), 0.4)
    for k in range(5):
        f = int(round((n - 1) * k / 4)) if n else 0
        _text(img, str(f), (x0 + (f + 0.5) * (x1 - x0) / max(n, 1) - 8, y1 + 16), 0.4)
    lx = x0 + 260
    for name, colour in STATUS_COLOURS.items():
        cv2.rectangle(img, (lx, y0 - 20), (lx + 12, y0 - 8), colour, -1)
        _text(img, name, (lx + 16, y0 - 9), 0.4)
        lx += 100


def _bar_panel(img, box, names, raw_mm: np.ndarray, norm_mm: np.ndarray):
    x0, y0, x1, y1 = box
    j = len(names)
    vals = np.concatenate([raw_mm, norm_mm])
    vmax = _nice_max(np.nanmax(vals) if np.isfinite(vals).any() else 0.0)
    row = (y1 - y0) / max(j, 1)
    label_w = 90
    bx0 = x0 + label_w

    def w_of(v):
        return 0 if not np.isfinite(v) else int(np.clip(v, 0, vmax) / vmax * (x1 - bx0))

    for k, name in enumerate(names):
        ya = y0 + k * row
        _text(img, name, (x0, ya + row * 0.7), 0.4)
        h = max(int(row * 0.38), 1)
        cv2.rectangle(img, (bx0, int(ya + 2)), (bx0 + w_of(raw_mm[k]), int(ya + 2) + h), _RAW, -1)
        yb = int(ya + 2) + h
        cv2.rectangle(img, (bx0, yb), (bx0 + w_of(norm_mm[k]), yb + h), _NORM, -1)
    for k in range(5):
        v = vmax * k / 4
        x = bx0 + int(v / vmax * (x1 - bx0))
        cv2.line(img, (x, y1), (x, y1 + 4), _BLACK, 1)
        _text(img, f"{v:.0f}", (x - 10, y1 + 18), 0.4)
    cv2.rectangle(img, (bx0, y0), (x1, y1), _BLACK, 1)
    _text(img, "mean error per joint (mm)", (x0, y0 - 10), 0.5)
    for lx, colour, label in ((x0 + 310, _RAW, "raw"), (x0 + 410, _NORM, "offset-normalized")):
        cv2.rectangle(img, (lx, y0 - 20), (lx + 12, y0 - 8), colour, -1)
        _text(img, label, (lx + 16, y0 - 9), 0.4)


def render_plot(
    frame_mm: np.ndarray,
    status: np.ndarray,
    joint_names,
    per_joint_mm: np.ndarray,
    per_joint_norm_mm: np.ndarray,
    title: str = "",
    threshold_mm: float = 100.0,
    width: int = 1000,
) -> np.ndarray:
    """The evaluation figure as a (H, W, 3) uint8 BGR image.

    Args:
        frame_mm: (F,) per-frame mean joint error, NaN for frames without a pose.
        status: (F,) status names (``tracked``/``detected``/``lost``/``missing``).
        joint_names: J names; per_joint_mm, per_joint_norm_mm: (J,).
    """
    frame_mm = np.asarray(frame_mm, dtype=np.float64)
    status = np.asarray(status)
    j = len(joint_names)
    curve_h, bar_h = 280, max(22 * j, 100)
    height = 60 + curve_h + 80 + bar_h + 40
    img = np.full((height, width, 3), 255, np.uint8)
    _text(img, title, (20, 24), 0.55)
    _curve_panel(img, (70, 70, width - 20, 70 + curve_h), frame_mm, status, threshold_mm)
    top = 70 + curve_h + 80
    _bar_panel(
        img,
        (20, top, width - 20, top + bar_h),
        list(joint_names),
        np.asarray(per_joint_mm, dtype=np.float64),
        np.asarray(per_joint_norm_mm, dtype=np.float64),
    )
    return img


def save_plot(path: str | Path, image: np.ndarray) -> None:
    """Write the figure as PNG; ``OSError`` if it cannot be written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise OSError(f"could not write {path}")
