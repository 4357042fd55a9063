"""Fit the learned pose prior (``shared.pose_prior``) on the training motion capture.

Every frame of every training clip (the synthesis config's ``motion_folders``; the dev and
test clips are not among them) is retargeted to the tracking skeleton, as for the training
set, and each joint angle's mean and standard deviation over all frames are written. All
frames, not the synthesis's spread-out selection: the prior should weigh poses as often as
people take them.

    python -m depthmocap.train.mocap.pose_prior_fit --config configs/synth.yaml \\
        --out models/pose_prior.json
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from depthmocap.shared import skeleton as sk
from depthmocap.shared.pose_prior import PosePrior, save_pose_prior

__all__ = ["fit_pose_prior", "main"]


def fit_pose_prior(q: np.ndarray, fitted_on: str = "", min_std_rad: float = 0.05) -> PosePrior:
    """Per-angle mean and standard deviation of poses ``q`` (F, 34); each standard deviation
    is at least ``min_std_rad``, so that an angle the mocap never moves is not pinned."""
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != sk.NUM_DOFS or len(q) < 2:
        raise ValueError(f"need (F >= 2, {sk.NUM_DOFS}) poses, got {q.shape}")
    angles = q[:, sk.ANGLE_DOFS]
    std = np.maximum(angles.std(0), min_std_rad)
    return PosePrior(angles.mean(0), std, len(q), fitted_on)


def retargeted_library(folders: list[str], fps: float, log=print) -> np.ndarray:
    """Every frame of the mocap clips in ``folders`` as tracking-skeleton poses (F, 34)."""
    import torch
    from depthmocap.train.mocap.motion_library import mocap_library
    from depthmocap.train.mocap.retarget import body_from_named_joints, retarget_joints

    torch.set_num_threads(1)
    library = mocap_library(folders, fps)
    if not library:
        raise ValueError(f"no mocap clips in {folders}")
    log(f"retargeting {sum(len(s.joints) for s in library)} frames of {len(library)} clips")
    return np.concatenate(
        [retarget_joints(s.joints, body_from_named_joints(s.joints), passes=1)[0] for s in library]
    )


def main(argv: list[str] | None = None) -> int:
    from depthmocap.shared.config import ConfigError, load_config
    from depthmocap.train.synth.trainset_builder import SynthConfig

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--config",
        type=Path,
        default=Path("configs/synth.yaml"),
        help="synthesis config whose motion_folders and motion_fps are used",
    )
    p.add_argument("--out", type=Path, required=True, help="the pose-prior file to write")
    args = p.parse_args(argv)  # fmt: skip
    try:
        cfg = load_config(SynthConfig, args.config)
        q = retargeted_library(list(cfg.motion_folders), cfg.motion_fps)
    except (ConfigError, OSError, ValueError) as err:
        print(f"pose_prior_fit: {err}", file=sys.stderr)
        return 2
    prior = fit_pose_prior(q, ", ".join(str(f) for f in cfg.motion_folders))
    save_pose_prior(args.out, prior)
    print(f"wrote {args.out} ({prior.frames} frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
