"""``train-forest``: train the per-pixel body-part forest on a synthetic training set.

Examples::

    train-forest --data data/synth --out models/forest.npz --config configs/forest.yaml
    train-forest --data data/synth_tiny --out /tmp/forest.npz --preset tiny
    train-forest --data data/synth --out /tmp/f.npz --max-frames 2000 --trees 1 --eval-data data/dev
    train-forest --data data/synth data/synth_clothed --out /tmp/f.npz   # two sets read as one

Writes ``forest.npz`` (with the ONNX graph embedded for the onnxruntime backend), the config it
was trained with next to it (``forest.yaml``) and ``forest.metrics.json`` (training statistics,
plus accuracy and ``forest.confusion.png`` when ``--eval-data`` is given).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

from depthmocap.shared.config import (
    ConfigError,
    add_cli_args,
    config_from_args,
    load_config,
    save_config,
)
from depthmocap.shared.forest_format import ForestFormatError, save_forest
from depthmocap.shared.resources import CONFIGS_DIR

from .config import ForestConfig

PRESETS = {
    "full": CONFIGS_DIR / "forest.yaml",
    "tiny": CONFIGS_DIR / "forest_tiny.yaml",
}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train-forest", description=__doc__.splitlines()[0])
    p.add_argument(
        "--data",
        required=True,
        nargs="+",
        help="training-set directory (make synth); several are read as one, in order",
    )
    p.add_argument("--out", required=True, help="output forest.npz")
    p.add_argument("--config", help="YAML preset (default: built-in defaults)")
    p.add_argument("--preset", choices=sorted(PRESETS), help="a named preset instead of --config")
    p.add_argument("--max-frames", type=int, help="train on the first N frames only")
    p.add_argument("--eval-data", help="labelled frames to evaluate on after training")
    p.add_argument("--eval-frames", type=int, help="evaluate on at most N frames")
    p.add_argument("--onnx", help="also write a standalone ONNX file here")
    p.add_argument("--quiet", action="store_true", help="no per-level progress")
    add_cli_args(p, ForestConfig)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    command = "train-forest " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    try:
        if args.config and args.preset:
            raise ConfigError("give --config or --preset, not both")
        preset = PRESETS[args.preset] if args.preset else args.config
        cfg = config_from_args(ForestConfig, args, load_config(ForestConfig, preset))
        cfg.validate()
        from depthmocap.train.synth.trainset import open_trainsets

        from .evaluate import evaluate_forest, save_confusion_png
        from .onnx_export import embedded_graph, export_onnx
        from .trainer import train_forest

        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        trainset = open_trainsets(args.data)
        t0 = time.perf_counter()
        forest = train_forest(trainset, cfg, log=(lambda s: None) if args.quiet else print,
                              max_frames=args.max_frames)  # fmt: skip
        forest.stats["command"] = command
        forest.stats["data"] = " ".join(str(d) for d in args.data)
        forest.onnx_graph = embedded_graph(forest)
        save_forest(out, forest)
        save_config(cfg, out.with_suffix(".yaml"))
        if args.onnx:
            export_onnx(forest, args.onnx)
        metrics = {"training": forest.stats, "artifact_bytes": out.stat().st_size}
        print(
            f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB, {forest.num_trees} trees, "
            f"{forest.num_nodes} nodes, depth {forest.max_depth}) in "
            f"{time.perf_counter() - t0:.0f} s"
        )
        if args.eval_data:
            res = evaluate_forest(forest, args.eval_data, args.eval_frames)
            metrics["evaluation"] = {"data": str(args.eval_data), **res}
            save_confusion_png(res, forest.class_names, out.with_suffix(".confusion.png"))
            print(
                f"{args.eval_data}: {res['frames']} frames, pixel accuracy "
                f"{res['pixel_accuracy']:.3f}, mean per-class accuracy "
                f"{res['mean_class_accuracy']:.3f}"
            )
        out.with_suffix(".metrics.json").write_text(json.dumps(metrics, indent=1))
    except (ConfigError, ForestFormatError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
