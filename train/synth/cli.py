"""``train-synth``: build the sharded training set, or render one clip as a recording.

Examples::

    train-synth --out data/synth                       # configs/synth.yaml (make synth)
    train-synth --config configs/synth_tiny.yaml --out /tmp/tiny
    train-synth --sequence --motion walk --out /tmp/rec --frames 60 --seed 3
    train-synth --sequence --motion HDM_mm_squat1Reps_037_120.amc --asf HDM_mm.asf --out rec
    train-synth --calibration-views --out /tmp/subject --seed 4   # runtime-personalize input
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from depthmocap.shared.config import ConfigError, add_cli_args, config_from_args, load_config
from depthmocap.train.synth.trainset_builder import SynthConfig


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train-synth", description=__doc__.splitlines()[0])
    p.add_argument("--config", help="YAML preset (default: the built-in defaults)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    seq = p.add_argument_group("sequence mode")
    seq.add_argument("--sequence", action="store_true", help="render one motion as a recording")
    seq.add_argument("--motion", help="clip file (.bvh/.amc) or built-in motion name")
    seq.add_argument("--asf", help="ASF skeleton of an .amc clip (default: found beside it)")
    seq.add_argument("--fps", type=float, default=30.0, help="frame rate of the recording")
    seq.add_argument("--overwrite", action="store_true", help="replace an existing recording")
    cal = p.add_argument_group("calibration views (personalization, Helten III)")
    cal.add_argument(
        "--calibration-views",
        action="store_true",
        help="render a random body's front and back calibration views with its true shape",
    )
    # --frames (from the config) also limits a sequence; unset there means the whole clip.
    add_cli_args(p, SynthConfig)
    return p


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    args = build_parser().parse_args(argv)
    try:
        cfg = config_from_args(SynthConfig, args, load_config(SynthConfig, args.config))
        cfg.validate()
        if args.calibration_views:
            from depthmocap.train.synth.calibration_views import render_calibration_views

            path = render_calibration_views(args.out, seed=cfg.seed, overwrite=args.overwrite)
            print(f"calibration views written to {path}")
            return 0
        if args.sequence:
            from depthmocap.train.synth.sequence import render_sequence

            if not args.motion:
                raise ValueError("--sequence needs --motion CLIP")
            path = render_sequence(
                args.motion, args.out, asf=args.asf, frames=args.frames, seed=cfg.seed,
                fps=args.fps, width=cfg.width, cfg=cfg.scene, progress=not args.quiet,
                overwrite=args.overwrite,
            )  # fmt: skip
            print(f"recording written to {path}")
            return 0
        from depthmocap.train.synth.trainset_builder import synthesize_set

        m = synthesize_set(cfg, Path(args.out), progress=not args.quiet)
        print(
            f"{m['frames']} frames in {len(m['shards'])} shards at {args.out} "
            f"({m.get('frames_per_second')} frames/s rendering, {m.get('workers')} workers)"
        )
        return 0
    except (ConfigError, ValueError, FileNotFoundError, FileExistsError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: finished shards are kept; run again to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
