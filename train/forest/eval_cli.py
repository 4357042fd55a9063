"""``train-forest-eval``: per-pixel accuracy of a forest on labelled frames.

Examples::

    train-forest-eval --model models/forest.npz --data data/dev --out out/forest_eval
    train-forest-eval --model /tmp/forest.npz --data data/synth_tiny --max-frames 200
    train-forest-eval --model models/forest.npz --data data/dev --smooth-window 5

Writes ``forest_metrics.json`` and ``confusion.png`` to ``--out`` (when given) and prints the
pixel accuracy, the mean per-class accuracy and the per-class accuracies.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from depthmocap.shared.forest_format import ForestFormatError, load_forest
from depthmocap.shared.recording import RecordingError

from .evaluate import evaluate_forest, save_confusion_png, save_metrics


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train-forest-eval", description=__doc__.splitlines()[0])
    p.add_argument("--model", required=True, help="forest.npz")
    p.add_argument(
        "--data", required=True, help="training-set dir, recording with labels, or dir of them"
    )
    p.add_argument("--out", help="directory for forest_metrics.json and confusion.png")
    p.add_argument("--max-frames", type=int, help="evaluate at most this many frames")
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    p.add_argument(
        "--smooth-window",
        type=int,
        default=1,
        help="score posteriors smoothed over this odd box of pixels, as the detector and the "
        "hybrid use them (runtime default 5; 1: the raw forest)",
    )
    p.add_argument(
        "--smooth-gate", type=float, default=0.05, help="depth gate of the smoothing (m)"
    )
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    try:
        forest = load_forest(args.model)
        result = evaluate_forest(
            forest, args.data, args.max_frames, args.device,
            smooth_window=args.smooth_window, smooth_depth_gate_m=args.smooth_gate,
        )  # fmt: skip
        if args.out:
            out = Path(args.out)
            out.mkdir(parents=True, exist_ok=True)
            save_metrics(result, out / "forest_metrics.json")
            save_confusion_png(result, forest.class_names, out / "confusion.png")
    except (ForestFormatError, RecordingError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        f"{result['frames']} frames, {result['pixels']} person pixels: pixel accuracy "
        f"{result['pixel_accuracy']:.3f}, mean per-class accuracy "
        f"{result['mean_class_accuracy']:.3f}"
    )
    for name, acc in result["per_class_accuracy"].items():
        if acc is not None and name != forest.class_names[0]:
            print(f"  {name:<16s} {acc:.3f}")
    if args.out:
        print(f"wrote {Path(args.out) / 'forest_metrics.json'} and confusion.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
