"""Speed of forest inference on one 320x240 person frame (for ``make bench``; never asserted).

The frame is a person-sized silhouette drawn from ellipses at about 2.5 m (about 7,000 person
pixels at 320x240; the synthetic set averages about 4,000 at 1.5-4 m), unless ``frame`` is
given. Each figure is the median over ``repeats`` calls after a warm-up. The detector needs part
centroids, not every pixel: ``stride=2`` (every 2nd row and column) is the intended setting on
a 2-core CPU.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np
import torch

from shared.forest_format import load_forest

from .inference import DEFAULT_MODEL, ForestClassifier

__all__ = ["DEFAULT_MODEL", "person_frame", "benchmark_forest"]


def person_frame(width: int = 320, height: int = 240) -> tuple[np.ndarray, np.ndarray]:
    """A synthetic standing person: depth (H, W) float32 metres and mask (H, W) bool."""
    import cv2

    s = width / 320.0
    mask = np.zeros((height, width), np.uint8)
    cx = width // 2

    def ell(x, y, ax, ay, angle=0.0):
        pts = (int(cx + x * s), int(y * s)), (int(ax * s), int(ay * s))
        cv2.ellipse(mask, pts[0], pts[1], angle, 0, 360, 1, -1)

    ell(0, 45, 9, 11)  # head
    ell(0, 95, 22, 38)  # torso
    ell(-30, 95, 6, 30, 15)  # arms
    ell(30, 95, 6, 30, -15)
    ell(-11, 170, 9, 45, 3)  # legs
    ell(11, 170, 9, 45, -3)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    depth = 2.5 + 0.1 * np.cos((xx - cx) / (30 * s)) + 0.002 * (yy - height / 2) / s
    return (depth * mask).astype(np.float32), mask.astype(bool)


def _median_ms(fn, repeats: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def benchmark_forest(
    model_path: str | Path | None = None,
    threads: int = 2,
    repeats: int = 20,
    frame: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, float]:
    """Milliseconds per frame of the torch CPU backend (every pixel, every 2nd pixel) and of
    onnxruntime, plus the person pixel count; empty dict when there is no model file."""
    path = Path(model_path) if model_path is not None else DEFAULT_MODEL
    if not path.is_file():
        return {}
    forest = load_forest(path)
    depth, mask = frame if frame is not None else person_frame()
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        d, m = torch.from_numpy(depth), torch.from_numpy(mask)
        clf = ForestClassifier(forest, "cpu")
        out = {
            "pixels": float(int((m & (d > 0)).sum())),
            "trees": float(forest.num_trees),
            "depth": float(forest.max_depth),
            "torch_cpu_ms": _median_ms(lambda: clf.labels(d, m), repeats),
            "torch_cpu_stride2_ms": _median_ms(lambda: clf.labels(d, m, stride=2), repeats),
        }
        # The detector's and the hybrid's labels (DetectorConfig.label_smoothing_window).
        smoothed = ForestClassifier(forest, "cpu", smooth_window=5)
        out["torch_cpu_smoothed_ms"] = _median_ms(lambda: smoothed.labels(d, m), repeats)
        if forest.onnx_graph is not None:
            try:
                ort_clf = ForestClassifier(forest, backend="onnxruntime", threads=threads)
            except ValueError:
                ort_clf = None
            if ort_clf is not None:
                out["onnxruntime_ms"] = _median_ms(lambda: ort_clf.labels(d, m), repeats)
        return out
    finally:
        torch.set_num_threads(previous)


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", help="forest.npz (default: models/forest.npz)")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    result = benchmark_forest(args.model, args.threads)
    if not result:
        print("no forest model found")
    for key, value in result.items():
        print(f"  {key:<24s} {value:9.2f}")
