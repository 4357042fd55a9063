"""``python -m depthmocap.train.mocap.fit_pose_prior``: fit the joint-angle prior
(:mod:`shared.pose_prior`) to the training split's motion capture.

Every clip is retargeted onto the skeleton (``train.mocap.retarget``, as the synthetic frames
are posed) at ``--fps`` and the 28 joint angles of all its frames pooled. The dev split
(``hdm05/dev``, the evaluation's actor) is not read: the prior must not know the motions it is
measured on.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from depthmocap.shared.pose_prior import PosePriorError, fit_pose_prior, save_pose_prior

__all__ = ["TRAIN_MOCAP", "main", "training_poses"]

# The training split's clips (the forest's, train.synth.trainset_builder).
TRAIN_MOCAP = ("../shared/data/mocap/cmu", "../shared/data/mocap/hdm05/train")


def training_poses(folders: list[str], fps: float) -> tuple[np.ndarray, int]:
    """Poses (N, 34) of every clip under ``folders`` at about ``fps``, and the clip count."""
    from depthmocap.train.mocap.motion_library import find_clips
    from depthmocap.train.synth.sequence import sequence_poses

    clips = find_clips(folders)
    if not clips:
        raise PosePriorError(f"no .bvh or .amc clips under {', '.join(folders)}")
    rng = np.random.default_rng(0)  # clips use none; the signature asks for it
    poses = [sequence_poses(str(p), fps, None, rng)[0] for p in clips]
    return np.concatenate(poses), len(clips)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="fit_pose_prior", description=__doc__.splitlines()[0])
    p.add_argument("--mocap", nargs="+", default=list(TRAIN_MOCAP), help="clip folders")
    p.add_argument("--fps", type=float, default=10.0, help="frames taken per second of a clip")
    p.add_argument("--out", default="models/pose_prior.json", help="the prior file written")
    args = p.parse_args(argv)
    try:
        q, clips = training_poses(args.mocap, args.fps)
        names = ", ".join(Path(f).name for f in args.mocap)
        prior = fit_pose_prior(q, clips, f"{clips} clips of {names} at {args.fps:g} frames/s")
    except (PosePriorError, OSError, ValueError) as err:
        print(f"fit_pose_prior: {err}", file=sys.stderr)
        return 2
    save_pose_prior(args.out, prior)
    print(f"{args.out}: {prior.frames} poses of {clips} clips")
    return 0


if __name__ == "__main__":
    sys.exit(main())
