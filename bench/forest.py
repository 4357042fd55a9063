"""Speed of forest inference on one 320x240 person frame (never asserted).

The frame is :func:`bench.scenes.person_frame` unless ``frame`` is given. The detector needs
part centroids, not every pixel: ``stride=2`` (every 2nd row and column) is the intended
setting on a 2-core CPU, so it is timed beside the full frame; onnxruntime is timed when the
model carries its graph. With numba installed, the compiled walk (backend ``numba``, what the
runtime uses) is timed in turns with the torch walk, the reference it must equal, so that their
ratio holds on a noisy host.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from depthmocap.runtime.forest.inference import DEFAULT_MODEL, ForestClassifier, compiled_walk
from depthmocap.shared.forest_format import load_forest

from .scenes import person_frame
from .timing import alternating_median_ms, median_ms

__all__ = ["DEFAULT_MODEL", "benchmark_forest", "benchmark_forest_on", "forest_device_rows"]


def benchmark_forest(
    model_path: str | Path | None = None,
    threads: int = 2,
    repeats: int = 20,
    frame: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, float]:
    """Milliseconds per frame of the torch CPU backend and, with numba, of the numba backend
    (``numba_*``, timed in turns with torch; every pixel, every 2nd pixel, 5x5 smoothed), of
    onnxruntime, plus the person pixel count, the forest's size and ``numba_identical`` (1.0
    when numba's labels and posteriors equal torch's bit for bit on the frame); empty dict when
    there is no model file."""
    path = Path(model_path) if model_path is not None else DEFAULT_MODEL
    if not path.is_file():
        return {}
    forest = load_forest(path)
    depth, mask = frame if frame is not None else person_frame()
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        d, m = torch.from_numpy(depth), torch.from_numpy(mask)
        out = {
            "pixels": float(int((m & (d > 0)).sum())),
            "trees": float(forest.num_trees),
            "depth": float(forest.max_depth),
        }
        backends = ["torch"] + (["numba"] if compiled_walk() is not None else [])
        fns = {}
        for backend in backends:
            clf = ForestClassifier(forest, "cpu", backend=backend)
            # The detector's and the hybrid's labels (DetectorConfig.label_smoothing_window).
            smoothed = ForestClassifier(forest, "cpu", backend=backend, smooth_window=5)
            fns[f"{backend}_cpu_ms"] = lambda c=clf: c.labels(d, m)
            fns[f"{backend}_cpu_stride2_ms"] = lambda c=clf: c.labels(d, m, stride=2)
            fns[f"{backend}_cpu_smoothed_ms"] = lambda c=smoothed: c.labels(d, m)
            if backend == "numba":
                ref = ForestClassifier(forest, "cpu", backend="torch").pixel_posteriors(d, m)
                new = clf.pixel_posteriors(d, m)
                same = torch.equal(ref[0], new[0]) and torch.equal(ref[1], new[1])
                out["numba_identical"] = float(same)
        out.update(alternating_median_ms(fns, repeats))
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


def benchmark_forest_on(
    device: str | torch.device,
    model_path: str | Path | None = None,
    repeats: int = 20,
    frame: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, float]:
    """Milliseconds per frame of the torch backend on ``device`` (a GPU: what the whole hybrid
    runs there), synchronized: every person pixel (``all_ms``), every 2nd (``stride2_ms``),
    5x5 smoothed (``smoothed_ms``), timed in turns; and how its output compares with the
    torch walk on the CPU on the same frame: ``same_labels`` (share of the person's pixels
    given the same label) and ``posterior_diff`` (largest absolute posterior difference).
    Empty dict when there is no model file."""
    path = Path(model_path) if model_path is not None else DEFAULT_MODEL
    if not path.is_file():
        return {}
    forest = load_forest(path)
    depth, mask = frame if frame is not None else person_frame()
    d, m = torch.from_numpy(depth), torch.from_numpy(mask)
    clf = ForestClassifier(forest, device, backend="torch")
    smoothed = ForestClassifier(forest, device, backend="torch", smooth_window=5)
    dd, mm = d.to(clf.device), m.to(clf.device)  # the frame on the device, as the hybrid has it
    out = alternating_median_ms(
        {
            "all_ms": lambda: clf.labels(dd, mm),
            "stride2_ms": lambda: clf.labels(dd, mm, stride=2),
            "smoothed_ms": lambda: smoothed.labels(dd, mm),
        },
        repeats,
        device=clf.device,
    )
    reference = ForestClassifier(forest, "cpu", backend="torch")
    pix, post = clf.pixel_posteriors(dd, mm)
    ref_pix, ref_post = reference.pixel_posteriors(d, m)
    if pix.shape != ref_pix.shape or not torch.equal(pix.cpu(), ref_pix):
        raise RuntimeError(f"the forest on {device} classified other pixels than on the CPU")
    n = max(len(ref_pix), 1)
    out["same_labels"] = float((post.cpu().argmax(1) == ref_post.argmax(1)).sum()) / n
    diff = (post.cpu() - ref_post).abs()
    out["posterior_diff"] = float(diff.max()) if diff.numel() else 0.0
    out["pixels"] = float(len(ref_pix))
    return out


def forest_device_rows(fr: dict[str, float], name: str) -> list[tuple[str, float, str]]:
    """(what, ms, note) rows of :func:`benchmark_forest_on`'s figures on the device ``name``."""
    same = (
        f"labels as on the CPU on {100 * fr['same_labels']:.2f}% of pixels, posteriors within "
        f"{fr['posterior_diff']:.1e}; target <= 10 ms"
    )
    return [
        (f"torch {name}, every person pixel", fr["all_ms"], same),
        (f"torch {name}, every 2nd pixel (detector)", fr["stride2_ms"], ""),
        (
            f"torch {name}, 5x5 smoothed (detector, hybrid)",
            fr["smoothed_ms"],
            f"{fr['smoothed_ms'] / fr['all_ms']:.2f} of the raw forest's",
        ),
    ]


def forest_rows(fr: dict[str, float]) -> list[tuple[str, float, str]]:
    """(what, ms, note) rows of :func:`benchmark_forest`'s figures; numba's notes give its
    ratio to the torch walk timed in the same run."""
    rows = []
    for kind, what in (
        ("cpu", "every person pixel"),
        ("cpu_stride2", "every 2nd pixel (detector)"),
        ("cpu_smoothed", "5x5 smoothed (detector, hybrid)"),
    ):
        torch_ms = fr[f"torch_{kind}_ms"]
        note = {"cpu": "target <= 10 ms", "cpu_stride2": ""}.get(kind)
        if note is None:
            note = f"{torch_ms / fr['torch_cpu_ms']:.2f} of the raw forest's"
        rows.append((f"torch CPU, {what}", torch_ms, note))
        if f"numba_{kind}_ms" in fr:
            ms = fr[f"numba_{kind}_ms"]
            note = f"{ms / torch_ms:.2f} of torch's ({torch_ms / ms:.1f}x faster)"
            if kind == "cpu":
                same = "identical" if fr.get("numba_identical") == 1.0 else "DIFFERENT"
                note += f", output {same}; target <= 10 ms"
            rows.append((f"numba CPU, {what}", ms, note))
    if "onnxruntime_ms" in fr:
        rows.append(("onnxruntime CPU, every person pixel", fr["onnxruntime_ms"], ""))
    return rows


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", help="forest.npz (default: models/forest.npz)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    result = benchmark_forest(args.model, args.threads, args.repeats)
    if not result:
        print("no forest model found")
    else:
        print(
            f"{result['pixels']:.0f} person pixels, {result['trees']:.0f} trees of depth "
            f"{result['depth']:.0f}, torch {torch.__version__} on {args.threads} threads, "
            f"medians of {args.repeats} (torch and numba in turns)"
        )
        for what, ms, note in forest_rows(result):
            print(f"  {what:<42s} {ms:9.3f} ms  {note}")
