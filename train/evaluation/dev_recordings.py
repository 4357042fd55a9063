"""``python -m depthmocap.train.evaluation.dev_recordings``: render the dev evaluation
recordings (one per motion class of the HDM05 dev actor) with ``train-synth --sequence``; skips
recordings already there.

Each recording: one clip, its first ``--frames`` frames at 30 fps, a random anny body (seeded
by the clip's position in the list), a frontal camera, floor/background and Kinect noise. The
same bodies also hold the calibration T-pose for one second (``--calibration-out``), for
evaluating skeleton calibration and personalization against the known body.

``--all-clips`` renders every dev take of the tracked motion classes instead (39 takes, 2,433
frames, against the default set's 545), for failure rates too small for ten clips to measure:
one failed frame of the default set moves the mean system failure by 0.1-0.5 points.

``--protocol broad`` renders the broad dev protocol instead (:mod:`train.evaluation.protocol`,
``docs/protocol.md``): every tracked dev take with three stratified bodies and cameras
(frontal, side, cut), its spec from ``--protocol-config`` (default ``configs/dev_broad.yaml``),
a ``manifest.json`` of what was rendered, and each body's T-pose in ``OUT_calib``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from depthmocap.train.synth.sequence import OutOfRangeError, render_sequence

# One clip per HDM05 motion class (lying down is outside what the tracker is for).
DEV_CLIPS = (
    "HDM_mm_depositFloorR_019_120.amc",
    "HDM_mm_elbowToKnee1RepsLelbowStart_019_120.amc",
    "HDM_mm_grabHighR_017_120.amc",
    "HDM_mm_hopBothLegs1hops_031_120.amc",
    # Takes 011 and 013 jog their circle out to 5 m: no camera that sees the whole body keeps
    # them within the Kinect v1's 4.5 m range.
    "HDM_mm_jogLeftCircle4StepsRstart_012_120.amc",
    "HDM_mm_kickLFront1Reps_019_120.amc",
    "HDM_mm_rotateArmsBothBackward1Reps_011_120.amc",
    "HDM_mm_sneak2StepsLStart_011_120.amc",
    "HDM_mm_squat1Reps_037_120.amc",
    "HDM_mm_throwBasketball_010_120.amc",
)
UNTRACKED_CLASSES = ("lieDownFloor",)


def all_dev_clips(folder: Path) -> list[str]:
    """Every take in ``folder`` of the motion classes the tracker is for, sorted by name."""
    return sorted(
        p.name
        for p in folder.glob("*.amc")
        if not any(f"_{c}" in p.name for c in UNTRACKED_CLASSES)
    )


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    p = argparse.ArgumentParser(prog="train-dev-recordings", description=__doc__.splitlines()[0])
    p.add_argument("--clips", default="../shared/data/mocap/hdm05/dev", help="dev clip folder")
    p.add_argument("--out", default="data/dev", help="folder of recordings to write")
    p.add_argument("--frames", type=int, default=150, help="frames per recording")
    p.add_argument("--count", type=int, default=None, help="number of clips (default: all)")
    p.add_argument(
        "--all-clips",
        action="store_true",
        help="every dev take of the tracked motion classes, skipping takes no camera keeps "
        "within the sensor's range",
    )
    p.add_argument(
        "--calibration-out",
        default=None,
        help="also render each dev body holding the calibration T-pose (1 s) here (default: "
        "OUT_calib, where the dev benchmark looks for it; '' for none)",
    )
    p.add_argument(
        "--protocol",
        choices=["dev", "broad"],
        default="dev",
        help="dev: the recordings above; broad: the frozen broad protocol (docs/protocol.md)",
    )
    p.add_argument(
        "--protocol-config",
        type=Path,
        default=None,
        help="YAML spec of the broad protocol (default: configs/dev_broad.yaml if present, "
        "else the built-in version-1 spec)",
    )
    args = p.parse_args(argv)
    folder = Path(args.clips)
    if args.protocol == "dev" and args.protocol_config is not None:
        p.error("--protocol-config needs --protocol broad")
    if args.protocol == "broad" and (args.all_clips or args.frames != 150):
        p.error("--all-clips and --frames are set by the broad protocol's spec")
    if not folder.is_dir():
        print(f"error: {folder}: dev clips not found (../shared missing?)", file=sys.stderr)
        return 2
    calibration_out = f"{args.out}_calib" if args.calibration_out is None else args.calibration_out
    if args.protocol == "broad":
        return _render_broad(args, folder, calibration_out)
    clips = all_dev_clips(folder) if args.all_clips else list(DEV_CLIPS)
    clips = clips[: args.count]
    recorded = []  # (seed, name) of the takes that have a recording
    for seed, name in enumerate(clips):
        out = Path(args.out) / Path(name).stem
        if not (out / "groundtruth.npz").is_file():
            try:
                render_sequence(
                    str(folder / name), out, frames=args.frames, seed=100 + seed,
                    overwrite=True, require_in_range=args.all_clips,
                )  # fmt: skip
            except OutOfRangeError as e:
                print(f"skipped: {e}")
                continue
            print(f"wrote {out}")
        recorded.append((seed, name))
    if not calibration_out:
        return 0
    for seed, name in recorded:
        # Same seed -> same anny body as the dev recording of that name.
        out = Path(calibration_out) / Path(name).stem
        if not (out / "groundtruth.npz").is_file():
            render_sequence("t_pose", out, frames=30, seed=100 + seed, overwrite=True)
            print(f"wrote {out}")
    return 0


def _render_broad(args: argparse.Namespace, folder: Path, calibration_out: str) -> int:
    from depthmocap.shared.config import ConfigError, load_config
    from depthmocap.train.evaluation.protocol import BroadProtocolConfig, render_protocol

    path = args.protocol_config
    if path is None and Path("configs/dev_broad.yaml").is_file():
        path = Path("configs/dev_broad.yaml")
    try:
        cfg = load_config(BroadProtocolConfig, path)
        cfg.validate()
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    calib = Path(calibration_out) if calibration_out else None
    render_protocol(cfg, folder, Path(args.out), calib, args.count)
    return 0


if __name__ == "__main__":
    sys.exit(main())
