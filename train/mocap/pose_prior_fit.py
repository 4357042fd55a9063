"""Fit the tracker's pose prior (``shared.pose_prior``) on the training split's motion capture.

    python -m depthmocap.train.mocap.pose_prior_fit --out models/pose_prior.json

Every clip under ``--mocap`` (default: the training split, ``../shared/data/mocap/hdm05/train``
and ``cmu``; never the dev split's performer) is retargeted onto the skeleton at ``--fps`` as
the renderer retargets it (:func:`train.mocap.retarget.retarget_joints`); frames the IK
reproduces worse than ``--max-rms-m`` are left out. Each pose is also taken mirrored (left and
right swapped): people are symmetric, the clips' one-handed motions are not. A Gaussian
mixture (``--components``, full covariances with ``--floor-rad`` squared added to their
diagonals so that no angle the clips hold still becomes a hard constraint) is fitted by EM.
The angles go to ``--cache`` so a refit with other settings skips the retargeting.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from depthmocap.shared import skeleton as sk
from depthmocap.shared.pose_prior import ANGLE_NAMES, PosePrior, save_pose_prior

__all__ = ["clip_angles", "fit_mixture", "main", "mirror_angles"]

DEFAULT_MOCAP = ("../shared/data/mocap/hdm05/train", "../shared/data/mocap/cmu")

# Mirroring the body in its sagittal plane keeps rotations about the lateral (x) axis and
# turns those about y and z the other way (skeleton._mirror: the right side's axes are the
# left's mirrored, so a limb's angles carry over unchanged to the other side).
_TRUNK_FLIPPED = ("head_y", "head_z", "lower_neck_z", "lower_back_y", "lower_back_z")


def mirror_angles(angles: np.ndarray) -> np.ndarray:
    """The mirror images (N, A) of poses' joint angles (N, A): left and right swapped."""
    out = np.array(angles, dtype=np.float64, copy=True)
    for a, name in enumerate(ANGLE_NAMES):
        if name.startswith("l_"):
            b = ANGLE_NAMES.index("r_" + name[2:])
            out[:, a], out[:, b] = angles[:, b], angles[:, a]
        elif name in _TRUNK_FLIPPED:
            out[:, a] = -angles[:, a]
    return out


def clip_angles(path: Path, fps: float, max_rms_m: float) -> np.ndarray:
    """Joint angles (F, A) of one clip's frames at ``fps`` that the IK reproduces to within
    ``max_rms_m``."""
    from .motion_library import load_clip_joints
    from .retarget import body_from_named_joints, retarget_joints

    seq = load_clip_joints(path, fps)
    q, rms = retarget_joints(seq.joints, body_from_named_joints(seq.joints), passes=2)
    return np.asarray(q[rms <= max_rms_m, sk.ANGLE_DOFS], np.float64)


def _component_costs(x: np.ndarray, means, covariances, weights) -> np.ndarray:
    """(N, C) negative log-likelihoods of each point under each weighted component."""
    N, A = x.shape
    out = np.empty((N, len(weights)))
    for c in range(len(weights)):
        chol = np.linalg.cholesky(covariances[c])
        z = np.linalg.solve(chol, (x - means[c]).T)
        logdet = 2.0 * np.log(np.diag(chol)).sum()
        out[:, c] = 0.5 * (z * z).sum(0) + 0.5 * (logdet + A * np.log(2 * np.pi))
        out[:, c] -= np.log(weights[c])
    return out


def fit_mixture(
    x: np.ndarray,
    components: int,
    floor_rad: float,
    seed: int = 0,
    iterations: int = 200,
    tolerance: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """EM for a full-covariance Gaussian mixture on ``x`` (N, A).

    Starts from k-means++ seeds; each covariance gets ``floor_rad ** 2`` on its diagonal.
    Returns weights (C,), means (C, A), covariances (C, A, A) and the mean negative
    log-likelihood per point.
    """
    rng = np.random.default_rng(seed)
    N, A = x.shape
    if N < components * (A + 1):
        raise ValueError(f"{N} poses are too few for {components} components of {A} angles")
    centres = [x[rng.integers(N)]]
    for _ in range(1, components):
        d2 = np.min([((x - c) ** 2).sum(1) for c in centres], axis=0)
        centres.append(x[rng.choice(N, p=d2 / d2.sum())])
    means = np.array(centres)
    floor = floor_rad**2 * np.eye(A)
    covariances = np.repeat((np.cov(x.T) + floor)[None], components, 0)
    weights = np.full(components, 1.0 / components)
    last = np.inf
    for _ in range(iterations):
        cost = _component_costs(x, means, covariances, weights)
        best = cost.min(1, keepdims=True)
        resp = np.exp(best - cost)
        total = resp.sum(1, keepdims=True)
        nll = float((best[:, 0] - np.log(total[:, 0])).mean())
        resp /= total
        mass = resp.sum(0) + 1e-12
        weights = mass / N
        means = (resp.T @ x) / mass[:, None]
        for c in range(components):
            d = x - means[c]
            covariances[c] = (resp[:, c, None] * d).T @ d / mass[c] + floor
        if last - nll < tolerance:
            break
        last = nll
    covariances = 0.5 * (covariances + np.swapaxes(covariances, 1, 2))
    return weights / weights.sum(), means, covariances, nll


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mocap", nargs="+", default=list(DEFAULT_MOCAP), help="clip folders")
    ap.add_argument("--out", type=Path, default=Path("models/pose_prior.json"))
    ap.add_argument("--cache", type=Path, default=None, help="angles file (.npz) to reuse")
    ap.add_argument("--fps", type=float, default=10.0, help="frames per second taken")
    ap.add_argument("--max-rms-m", type=float, default=0.03, help="IK fit a frame needs")
    ap.add_argument("--components", type=int, default=16)
    ap.add_argument("--floor-rad", type=float, default=0.1)
    ap.add_argument("--no-mirror", action="store_true", help="do not add mirrored poses")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.cache is not None and args.cache.is_file():
        angles = np.load(args.cache)["angles"]
        print(f"{args.cache}: {len(angles)} poses")
    else:
        from .motion_library import find_clips

        clips = find_clips(args.mocap)
        if not clips:
            print(f"no clips under {', '.join(args.mocap)}", file=sys.stderr)
            return 1
        parts = []
        for i, clip in enumerate(clips):
            parts.append(clip_angles(clip, args.fps, args.max_rms_m))
            print(f"[{i + 1}/{len(clips)}] {clip.name}: {len(parts[-1])} poses", flush=True)
        angles = np.concatenate(parts)
        if args.cache is not None:
            args.cache.parent.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(args.cache, angles=angles)
    x = angles if args.no_mirror else np.concatenate([angles, mirror_angles(angles)])
    weights, means, covariances, nll = fit_mixture(
        x, args.components, args.floor_rad, seed=args.seed
    )
    prior = PosePrior(
        weights, means, covariances,
        fitted_on=(
            f"{' '.join(args.mocap)} at {args.fps:g} fps, IK within {args.max_rms_m:g} m, "
            f"{'' if args.no_mirror else 'mirrored too, '}{args.components} components, "
            f"floor {args.floor_rad:g} rad, seed {args.seed}"
        ),
        frames=len(x),
    )  # fmt: skip
    save_pose_prior(args.out, prior)
    print(f"{args.out}: {args.components} components on {len(x)} poses, nll {nll:.2f} per pose")
    return 0


if __name__ == "__main__":
    sys.exit(main())
