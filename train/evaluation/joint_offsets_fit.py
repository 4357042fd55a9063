"""Fit the output-joint offsets (``shared.joint_offsets``) from tracked recordings.

    python -m depthmocap.train.evaluation.joint_offsets_fit \\
        --results out/tune/hybrid_default_body out/size/hybrid_default_body \\
        --recordings data/tune_broad data/size_tune --out models/joint_offsets.json

``--results`` holds one ``runtime-track`` output per recording (``NAME/poses.jsonl`` or
``NAME/result/poses.jsonl``, with the run's ``body.json``), ``--recordings`` the recordings
with ground truth of the same names (several pairs, in order, fit together). For every frame
with a pose, the model's joints are recomputed from its ``q`` and the run's body (so results
written with or without offsets fit the same), and each joint's offset to the ground truth is
taken into its segment's frame and divided by the body's stature ratio.

The offset of a joint is linear in the pose's features (``shared.joint_offsets.pose_features``):
a ridge regression per joint (``--ridge`` on the pose coefficients, none on the zero-pose
offset) over the frames whose offset for that joint is within ``--gate-m``: a frame whose
tracking failed is far off in any direction and would pull the fit. ``--constant`` fits one
offset per joint instead, the median over all frames (format version 1's model).
``--validate-results``/``--validate-recordings`` report the error on other recordings too.

Fit on recordings you do not report: the shipped file comes from the tuning set (the broad
protocol's spec with another seed; ``docs/protocol.md``), never from ``data/dev_broad``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.joint_offsets import (
    JointOffsets,
    apply_offsets,
    pose_features,
    save_joint_offsets,
)
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions

__all__ = ["fit_offsets", "fit_pose_offsets", "load_tracked", "main"]


def fit_offsets(
    model: np.ndarray, truth: np.ndarray, rotations: np.ndarray, scale: np.ndarray
) -> np.ndarray:
    """Median offset of each joint in its segment frame, for the reference stature.

    Args:
        model: (N, J, 3) the model's joints; truth: (N, J, 3) the ground truth's.
        rotations: (N, S, 3, 3) segment rotations (``Kinematics.rotations``); scale: (N,)
            stature ratios.
    Returns:
        (J, 3) metres.
    """
    rot = rotations[:, np.asarray(sk.JOINT_SEGMENT)]  # (N, J, 3, 3)
    local = np.einsum("njba,njb->nja", rot, truth - model) / scale[:, None, None]
    return np.median(local, axis=0)


def fit_pose_offsets(
    model: np.ndarray,
    truth: np.ndarray,
    rotations: np.ndarray,
    scale: np.ndarray,
    q: np.ndarray,
    ridge: float = 10.0,
    gate_m: float = 0.12,
) -> tuple[np.ndarray, np.ndarray]:
    """Offsets linear in the pose features, one ridge regression per joint.

    Args:
        model, truth, rotations, scale: as :func:`fit_offsets`; q: (N, 34) the poses.
        ridge: penalty on the pose coefficients (the zero-pose offset is not penalized).
        gate_m: a frame counts for a joint only if its offset (at the reference stature) is
            within this: frames where tracking failed are left out.
    Returns:
        ``offsets`` (J, 3) at the zero pose and ``coefficients`` (J, P, 3), metres.
    Raises:
        ValueError: a joint with fewer frames within the gate than coefficients.
    """
    rot = rotations[:, np.asarray(sk.JOINT_SEGMENT)]  # (N, J, 3, 3)
    local = np.einsum("njba,njb->nja", rot, truth - model) / scale[:, None, None]
    feats = pose_features(torch.from_numpy(np.asarray(q, dtype=np.float64))).numpy()
    X = np.concatenate([np.ones((len(feats), 1)), feats], axis=1)  # (N, 1 + P)
    penalty = ridge * np.eye(X.shape[1])
    penalty[0, 0] = 0.0
    offsets, coefficients = [], []
    for j, name in enumerate(sk.JOINT_NAMES):
        keep = np.linalg.norm(local[:, j], axis=-1) < gate_m
        if keep.sum() < X.shape[1]:
            raise ValueError(
                f"{name}: {int(keep.sum())} frames within {gate_m} m, need {X.shape[1]}"
            )
        A = X[keep]
        w = np.linalg.solve(A.T @ A + penalty, A.T @ local[keep, j])  # (1 + P, 3)
        offsets.append(w[0])
        coefficients.append(w[1:])
    return np.stack(offsets), np.stack(coefficients)


def moved_joints(data: dict[str, np.ndarray], offsets: JointOffsets) -> np.ndarray:
    """(N, J, 3) the model's joints of ``data`` (:func:`load_tracked`) moved by ``offsets``."""
    return apply_offsets(
        torch.from_numpy(data["model"]),
        torch.from_numpy(data["rotations"]),
        torch.from_numpy(data["q"]),
        offsets,
        torch.from_numpy(data["stature"]),
    ).numpy()


def _poses_file(folder: Path) -> Path | None:
    for candidate in (folder / "poses.jsonl", folder / "result" / "poses.jsonl"):
        if candidate.is_file():
            return candidate
    return None


def load_tracked(results: Path, recordings: Path, reference: BodyShape) -> dict[str, np.ndarray]:
    """Every posed frame of every result in ``results`` with its recording's ground truth.

    Returns:
        ``model``, ``truth`` (N, J, 3), ``rotations`` (N, S, 3, 3), ``scale`` (N,) (body
        stature over ``reference``'s), ``stature`` (N,) metres, ``q`` (N, 34), ``recording``
        (N,) index into ``names``, ``names``.
    """
    model, truth, rots, scale, which, names, poses_q, statures = [], [], [], [], [], [], [], []
    for folder in sorted(p for p in results.iterdir() if p.is_dir()):
        poses = _poses_file(folder)
        gt_file = recordings / folder.name / "groundtruth.npz"
        if poses is None or not gt_file.is_file():
            continue
        body_file = poses.parent / "body.json"
        body = BodyShape.load(body_file) if body_file.is_file() else BodyShape.default()
        rows = [json.loads(line) for line in poses.read_text().splitlines() if line.strip()]
        rows = [r for r in rows if r.get("q") is not None]
        if not rows:
            continue
        gt = np.load(gt_file)
        order = [list(gt["joint_names"]).index(n) for n in sk.JOINT_NAMES]
        q = torch.tensor([r["q"] for r in rows], dtype=torch.float64)
        kin = forward_kinematics(q, body.to(torch.float64))
        model.append(named_joint_positions(kin).numpy())
        truth.append(gt["joints"][[r["frame"] for r in rows]][:, order])
        rots.append(kin.rotations.numpy())
        poses_q.append(q.numpy())
        ratio = float(body.stature()) / float(reference.stature())
        scale.append(np.full(len(rows), ratio))
        statures.append(np.full(len(rows), float(body.stature())))
        which.append(np.full(len(rows), len(names)))
        names.append(folder.name)
    if not names:
        raise FileNotFoundError(
            f"no results in {results} with ground truth of the same name in {recordings}"
        )
    return {
        "model": np.concatenate(model),
        "truth": np.concatenate(truth),
        "rotations": np.concatenate(rots),
        "scale": np.concatenate(scale),
        "stature": np.concatenate(statures),
        "q": np.concatenate(poses_q),
        "recording": np.concatenate(which),
        "names": np.asarray(names),
    }


def _load_pairs(results: list[Path], recordings: list[Path], reference: BodyShape) -> dict:
    parts = [load_tracked(r, c, reference) for r, c in zip(results, recordings, strict=True)]
    data = {k: np.concatenate([p[k] for p in parts]) for k in parts[0] if k != "names"}
    data["names"] = np.concatenate([p["names"] for p in parts])
    return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.joint_offsets_fit",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("--results", type=Path, nargs="+", required=True, help="runtime-track outputs")
    p.add_argument("--recordings", type=Path, nargs="+", required=True, help="their recordings")
    p.add_argument("--out", type=Path, required=True, help="the joint-offsets file to write")
    p.add_argument("--constant", action="store_true", help="one median offset per joint")
    p.add_argument("--ridge", type=float, default=10.0, help="penalty on the pose coefficients")
    p.add_argument("--gate-m", type=float, default=0.12, help="frames farther off are left out")
    p.add_argument("--validate-results", type=Path, nargs="*", default=[])
    p.add_argument("--validate-recordings", type=Path, nargs="*", default=[])
    args = p.parse_args(argv)
    pairs = [("--results", args.results, "--recordings", args.recordings)]
    pairs.append(
        ("--validate-results", args.validate_results,
         "--validate-recordings", args.validate_recordings)
    )  # fmt: skip
    for flag_a, a, flag_b, b in pairs:
        if len(a) != len(b):
            p.error(f"{flag_a} and {flag_b} pair up: got {len(a)} and {len(b)} folders")
        for flag, folder in [(flag_a, f) for f in a] + [(flag_b, f) for f in b]:
            if not folder.is_dir():
                p.error(f"{flag} {folder}: no such folder")
    reference = BodyShape.default(torch.float64)
    try:
        data = _load_pairs(args.results, args.recordings, reference)
        held = (
            _load_pairs(args.validate_results, args.validate_recordings, reference)
            if args.validate_results
            else None
        )
        if args.constant:
            offsets = fit_offsets(data["model"], data["truth"], data["rotations"], data["scale"])
            coefficients = None
        else:
            offsets, coefficients = fit_pose_offsets(
                data["model"], data["truth"], data["rotations"], data["scale"], data["q"],
                args.ridge, args.gate_m,
            )  # fmt: skip
    except (FileNotFoundError, ValueError, KeyError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    fitted_on = "; ".join(f"{r} against {c}" for r, c in zip(args.results, args.recordings))
    result = JointOffsets(
        offsets,
        float(reference.stature()),
        fitted_on=fitted_on,
        frames=len(data["q"]),
        pose_coefficients_m=coefficients,
    )
    save_joint_offsets(args.out, result)
    print(f"{len(data['names'])} recordings, {len(data['q'])} frames -> {args.out}")
    for label, part in (("on them", data), ("held out", held)):
        if part is None:
            continue
        before = np.linalg.norm(part["model"] - part["truth"], axis=-1)
        after = np.linalg.norm(moved_joints(part, result) - part["truth"], axis=-1)
        print(
            f"mean joint error {label} ({len(part['q'])} frames): {1e3 * before.mean():.1f} -> "
            f"{1e3 * after.mean():.1f} mm"
        )
        if label == "on them":
            for j, name in enumerate(sk.JOINT_NAMES):
                size = 1e3 * np.linalg.norm(offsets[j])
                print(
                    f"  {name:<11s} offset at the zero pose {size:5.1f} mm   "
                    f"{1e3 * before[:, j].mean():6.1f} -> {1e3 * after[:, j].mean():6.1f} mm"
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
