"""Speed of forest inference on one 320x240 person frame (never asserted).

The frame is :func:`bench.scenes.person_frame` unless ``frame`` is given. The detector needs
part centroids, not every pixel: ``stride=2`` (every 2nd row and column) is the intended
setting on a 2-core CPU, so it is timed beside the full frame; onnxruntime is timed when the
model carries its graph.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from depthmocap.runtime.forest.inference import DEFAULT_MODEL, ForestClassifier
from depthmocap.shared.forest_format import load_forest

from .scenes import person_frame
from .timing import median_ms

__all__ = ["DEFAULT_MODEL", "benchmark_forest"]


def benchmark_forest(
    model_path: str | Path | None = None,
    threads: int = 2,
    repeats: int = 20,
    frame: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, float]:
    """Milliseconds per frame of the torch CPU backend (every pixel, every 2nd pixel, 5x5
    smoothed) and of onnxruntime, plus the person pixel count and the forest's size; empty
    dict when there is no model file."""
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
            "torch_cpu_ms": median_ms(lambda: clf.labels(d, m), repeats),
            "torch_cpu_stride2_ms": median_ms(lambda: clf.labels(d, m, stride=2), repeats),
        }
        # The detector's and the hybrid's labels (DetectorConfig.label_smoothing_window).
        smoothed = ForestClassifier(forest, "cpu", smooth_window=5)
        out["torch_cpu_smoothed_ms"] = median_ms(lambda: smoothed.labels(d, m), repeats)
        if forest.onnx_graph is not None:
            try:
                ort_clf = ForestClassifier(forest, backend="onnxruntime", threads=threads)
            except ValueError:
                ort_clf = None
            if ort_clf is not None:
                out["onnxruntime_ms"] = median_ms(lambda: ort_clf.labels(d, m), repeats)
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
