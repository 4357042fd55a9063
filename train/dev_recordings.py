"""``python -m train.dev_recordings``: render the dev evaluation recordings (one per motion class
of the HDM05 dev actor) with ``train-synth --sequence``; skips recordings already there.

Each recording: one clip, its first ``--frames`` frames at 30 fps, a random anny body (seeded
by the clip's position in the list), a frontal camera, floor/background and Kinect noise. The
same bodies also hold the calibration T-pose for one second (``--calibration-out``), for
evaluating skeleton calibration and personalization against the known body.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from .synth_sequence import render_sequence

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


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    p = argparse.ArgumentParser(prog="train-dev-recordings", description=__doc__.splitlines()[0])
    p.add_argument("--clips", default="../shared/data/mocap/hdm05/dev", help="dev clip folder")
    p.add_argument("--out", default="data/dev", help="folder of recordings to write")
    p.add_argument("--frames", type=int, default=150, help="frames per recording")
    p.add_argument("--count", type=int, default=len(DEV_CLIPS), help="number of clips")
    p.add_argument(
        "--calibration-out",
        default="data/dev_calib",
        help="also render each dev body holding the calibration T-pose (1 s) here",
    )
    args = p.parse_args(argv)
    folder = Path(args.clips)
    if not folder.is_dir():
        print(f"error: {folder}: dev clips not found (../shared missing?)", file=sys.stderr)
        return 2
    for seed, name in enumerate(DEV_CLIPS[: args.count]):
        out = Path(args.out) / Path(name).stem
        if (out / "groundtruth.npz").is_file():
            continue
        render_sequence(
            str(folder / name), out, frames=args.frames, seed=100 + seed, overwrite=True
        )
        print(f"wrote {out}")
    for seed, name in enumerate(DEV_CLIPS[: args.count]):
        # Same seed -> same anny body as the dev recording of that name.
        out = Path(args.calibration_out) / Path(name).stem
        if args.calibration_out and not (out / "groundtruth.npz").is_file():
            render_sequence("t_pose", out, frames=30, seed=100 + seed, overwrite=True)
            print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
