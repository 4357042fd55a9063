"""``make bench`` / ``runtime-bench``: speed figures of the runtime's hot paths, printed, never
asserted.

Each figure is the median over repeats after a warm-up (:mod:`bench.timing`); ratios compare
against a baseline measured in the same run, because these machines are noisy.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from .kinematics import kinematics_rows

__all__ = ["main"]


def _print_rows(rows: list[tuple[str, float, str]]) -> None:
    for what, ms, note in rows:
        print(f"  {what:<45s} {ms:9.3f} ms  {note}")


def _print_segmentation() -> None:
    from .segmentation import benchmark_segmentation

    seg = benchmark_segmentation()
    print("\n== person segmentation (CPU, numpy/OpenCV), 320x240 demo frames ==")
    print(f"  {'segment_person, one frame':<45s} {seg['segment_person_ms']:9.3f} ms")


def _print_forest(threads: int) -> None:
    from .forest import benchmark_forest, forest_rows

    fr = benchmark_forest(threads=threads)
    if not fr:
        return
    print(
        f"\n== forest inference (models/forest.npz: {fr['trees']:.0f} trees, depth "
        f"{fr['depth']:.0f}), {fr['pixels']:.0f} person pixels of a 320x240 frame =="
    )
    _print_rows(forest_rows(fr))


def _print_forest_on(device: str, name: str) -> None:
    from .forest import benchmark_forest_on, forest_device_rows

    fr = benchmark_forest_on(device)
    if not fr:
        return
    print(f"\n== forest inference on {name} (torch), {fr['pixels']:.0f} person pixels ==")
    _print_rows(forest_device_rows(fr, name))


def _print_tracker(device: str, name: str) -> None:
    from .tracker import tracker_rows
    from .tracker_terms import collision_cost, joint_support_cost

    print(f"\n== tracker on {name} (cylinder-model walk, 320x240 in; working resolution ==")
    print("   and window from the person's size)")
    _print_rows(tracker_rows(device) + [collision_cost(device), joint_support_cost(device)])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=1000, help="poses per FK call")
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch CPU threads (default 1, runtime-track's: the whole hybrid's second thread "
        "prepares the next frame)",
    )
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda", "all"])
    parser.add_argument(
        "--recordings",
        type=Path,
        help="also time the tracker on each recording with ground truth in this folder "
        "(make dev-recordings: anny bodies and sensor noise)",
    )
    parser.add_argument(
        "--hybrid-source",
        default="demo",
        help="source of the whole-hybrid timing (any runtime-track --input; default: the "
        "built-in demo, so it needs no data)",
    )
    parser.add_argument(
        "--hybrid-frames",
        type=int,
        default=120,
        help="frames of the whole-hybrid timing (0: skip it)",
    )
    parser.add_argument(
        "--hybrid-recordings",
        type=Path,
        help="also time the whole hybrid end to end on every recording in this folder "
        "(pooled median, 95th percentile, mean, replayed latency; then each recording)",
    )
    args = parser.parse_args(argv)
    if args.hybrid_frames < 0:
        parser.error(f"--hybrid-frames must be >= 0, got {args.hybrid_frames}")
    for flag, folder in (("--recordings", args.recordings),
                         ("--hybrid-recordings", args.hybrid_recordings)):  # fmt: skip
        if folder is not None and not folder.is_dir():
            parser.error(f"{flag} {folder}: no such folder")
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: torch sees no CUDA device (--device all: CUDA when present)")
    torch.set_num_threads(args.threads)
    devices = ["cpu", "cuda"] if args.device == "all" else [args.device]
    devices = [d for d in devices if d == "cpu" or torch.cuda.is_available()]
    print(
        f"torch {torch.__version__}, {args.threads} CPU threads "
        "(the whole hybrid: one more thread prepares the next frame)"
    )
    for dev in devices:
        name = torch.cuda.get_device_name() if dev == "cuda" else "CPU"
        print(f"\n== kinematics on {name} ==")
        _print_rows(kinematics_rows(args.batch, dev))
        if dev == "cpu":
            _print_segmentation()
            _print_forest(args.threads)
        else:
            _print_forest_on(dev, name)
        _print_tracker(dev, name)
        if args.hybrid_frames:
            from .hybrid import hybrid_rows

            print(
                f"\n== the whole hybrid on {name} (shipped preset, default body), "
                f"{args.hybrid_source}: per frame, as runtime-track runs it without its files =="
            )
            _print_rows(hybrid_rows(args.hybrid_source, dev, args.hybrid_frames))
        if args.hybrid_recordings is not None:
            from .hybrid import recordings_rows

            print(
                f"\n== the whole hybrid on {name} (shipped preset, default body), every "
                f"recording in {args.hybrid_recordings}, end to end per frame =="
            )
            _print_rows(recordings_rows(args.hybrid_recordings, dev))
        if args.recordings is not None:
            from .tracker import recording_rows

            where = f"recordings in {args.recordings}"
            print(f"\n== tracker on {name}, {where} (ground-truth start) ==")
            _print_rows(recording_rows(args.recordings, dev))


if __name__ == "__main__":
    main()
