"""Per-pixel accuracy of a forest on labelled frames, and a confusion-matrix picture.

Sources of labelled frames (:func:`labelled_batches`): a training-set directory
(``manifest.json`` + shards), a recording with ``labels/`` (``meta.json``), or a directory of
such recordings (e.g. ``data/dev``, rendered from motions and bodies not used for training).

The forest classifies the ground-truth person pixels (``labels > 0`` with a reading): the
figures measure part classification, separately from segmentation. Metrics:

- ``pixel_accuracy``: correctly labelled person pixels / person pixels;
- ``mean_class_accuracy``: the mean over the body-part classes present of the per-class recall
  (the diagonal of the row-normalized confusion matrix), the figure of Shotton et al. 2011;
- ``confusion``: (C, C) counts, rows = truth, columns = prediction.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.forest_format import Forest
from depthmocap.shared.posterior_smoothing import smooth_posteriors
from depthmocap.shared.recording import Recording

from .predict import predict_posteriors

__all__ = ["labelled_batches", "evaluate_forest", "confusion_image", "save_confusion_png"]


def _recording_batches(
    path: Path, batch: int
) -> Iterator[tuple[np.ndarray, np.ndarray, Intrinsics]]:
    rec = Recording(path)
    if not rec.has_labels:
        raise ValueError(f"{path}: recording has no labels/ (cannot evaluate)")
    intr = rec.intrinsics
    for s in range(0, len(rec), batch):
        idx = range(s, min(len(rec), s + batch))
        depth = np.stack([rec.read_depth_mm(i) for i in idx])
        labels = np.stack([rec.read_labels(i) for i in idx])
        yield depth, labels, intr


def labelled_batches(
    path: str | Path, batch: int = 32, max_frames: int | None = None
) -> Iterator[tuple[np.ndarray, np.ndarray, Intrinsics]]:
    """Batches of (depth (B, H, W) uint16 mm, labels (B, H, W) uint8, intrinsics)."""
    path = Path(path)
    if (path / "manifest.json").is_file():
        from depthmocap.train.synth.trainset import TrainSet

        ts = TrainSet(path)

        def gen():
            for shard in ts:
                for s in range(0, len(shard), batch):
                    yield shard.depth[s : s + batch], shard.labels[s : s + batch], ts.intrinsics

        source = gen()
    elif (path / "meta.json").is_file():
        source = _recording_batches(path, batch)
    elif path.is_dir():
        recs = sorted(p.parent for p in path.glob("*/meta.json"))
        if not recs:
            raise ValueError(f"{path}: no training set, recording or recordings found")

        def gen():
            for r in recs:
                yield from _recording_batches(r, batch)

        source = gen()
    else:
        raise ValueError(f"{path}: no such directory")
    seen = 0
    for depth, labels, intr in source:
        if max_frames is not None:
            if seen >= max_frames:
                return
            depth, labels = depth[: max_frames - seen], labels[: max_frames - seen]
        seen += depth.shape[0]
        yield depth, labels, intr


def evaluate_forest(
    forest: Forest,
    path: str | Path,
    max_frames: int | None = None,
    device: str = "cpu",
    batch: int = 16,
    smooth_window: int = 1,
    smooth_depth_gate_m: float = 0.05,
) -> dict:
    """Confusion matrix and accuracies of ``forest`` on the labelled frames at ``path``;
    ``smooth_window`` > 1 scores the depth-gated smoothed posteriors the runtime uses
    (:func:`shared.posterior_smoothing.smooth_posteriors`)."""
    c = forest.num_classes
    conf = torch.zeros(c * c, dtype=torch.int64)
    frames = 0
    for depth_mm, labels, intr in labelled_batches(path, batch, max_frames):
        depth = torch.from_numpy(depth_mm.astype(np.float32) / 1000.0).to(device)
        lab = torch.from_numpy(labels).to(device)
        scale = forest.offset_scale(intr.fx, intr.fy)
        pix, probs = predict_posteriors(forest, depth, lab > 0, scale)
        probs = smooth_posteriors(pix, probs, depth, smooth_window, smooth_depth_gate_m)
        truth = lab[pix[:, 0], pix[:, 1], pix[:, 2]].to(torch.int64)
        conf += torch.bincount(truth * c + probs.argmax(1), minlength=c * c).cpu()
        frames += depth.shape[0]
    if frames == 0:
        raise ValueError(f"{path}: no frames to evaluate")
    conf = conf.view(c, c).numpy()
    per_class = np.full(c, np.nan)
    rows = conf.sum(1)
    present = rows > 0
    per_class[present] = np.diag(conf)[present] / rows[present]
    parts = present.copy()
    parts[0] = False
    return {
        "frames": frames,
        "pixels": int(conf.sum()),
        "pixel_accuracy": float(np.trace(conf) / max(conf.sum(), 1)),
        "mean_class_accuracy": float(np.mean(per_class[parts])) if parts.any() else float("nan"),
        "per_class_accuracy": {
            name: (None if np.isnan(a) else round(float(a), 4))
            for name, a in zip(forest.class_names, per_class)
        },
        "confusion": conf.tolist(),
    }


def confusion_image(conf: np.ndarray, class_names: list[str] | tuple[str, ...]) -> np.ndarray:
    """(H, W, 3) uint8 BGR picture of the row-normalized confusion matrix (truth = rows)."""
    import cv2

    conf = np.asarray(conf, dtype=np.float64)
    c = conf.shape[0]
    norm = conf / np.maximum(conf.sum(1, keepdims=True), 1)
    cell, margin = 28, 130
    size = margin + c * cell
    img = np.full((size + 10, size + 10, 3), 255, np.uint8)
    shade = (255 * (1 - norm)).astype(np.uint8)
    block = np.kron(shade, np.ones((cell, cell), np.uint8))
    img[margin : margin + c * cell, margin : margin + c * cell] = block[..., None]
    font = cv2.FONT_HERSHEY_SIMPLEX
    for i, name in enumerate(class_names):
        y = margin + i * cell + cell // 2 + 4
        cv2.putText(img, name[:16], (4, y), font, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
        for j in range(c):
            if norm[i, j] >= 0.005:
                colour = (255, 255, 255) if norm[i, j] > 0.5 else (0, 0, 0)
                org = (margin + j * cell + 2, margin + i * cell + cell // 2 + 4)
                text = f"{int(round(100 * norm[i, j]))}"
                cv2.putText(img, text, org, font, 0.33, colour, 1, cv2.LINE_AA)
    # Column names, rotated: draw horizontally on a strip and rotate it.
    strip = np.full((cell * c, margin, 3), 255, np.uint8)
    for j, name in enumerate(class_names):
        y = j * cell + cell // 2 + 4
        cv2.putText(strip, name[:16], (4, y), font, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    img[:margin, margin : margin + c * cell] = np.rot90(strip)
    cv2.putText(img, "truth \\ predicted", (4, 16), font, 0.4, (0, 0, 160), 1, cv2.LINE_AA)
    return img


def save_confusion_png(result: dict, class_names, path: str | Path) -> None:
    import cv2

    if not cv2.imwrite(str(path), confusion_image(np.array(result["confusion"]), class_names)):
        raise OSError(f"could not write {path}")


def save_metrics(result: dict, path: str | Path) -> None:
    Path(path).write_text(json.dumps(result, indent=1))
