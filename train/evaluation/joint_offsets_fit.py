"""Fit the output-joint offsets (``shared.joint_offsets``) from tracked recordings.

    python -m depthmocap.train.evaluation.joint_offsets_fit \\
        --results out/tune/hybrid_default_body --recordings data/tune_broad \\
        --out models/joint_offsets.json

``--results`` holds one ``runtime-track`` output per recording (``NAME/poses.jsonl`` or
``NAME/result/poses.jsonl``, with the run's ``body.json``), ``--recordings`` the recordings
with ground truth of the same names. For every frame with a pose, the model's joints are
recomputed from its ``q`` and the run's body (so results written with or without offsets fit
the same), and each joint's offset to the ground truth is taken into its segment's frame and
divided by the body's stature ratio. The offset of a joint is the median over all frames: a
frame whose tracking failed is far off in any direction and moves a median little.

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
from depthmocap.shared.joint_offsets import JointOffsets, offset_joints, save_joint_offsets
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions

__all__ = ["fit_offsets", "load_tracked", "main"]


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


def _poses_file(folder: Path) -> Path | None:
    for candidate in (folder / "poses.jsonl", folder / "result" / "poses.jsonl"):
        if candidate.is_file():
            return candidate
    return None


def load_tracked(results: Path, recordings: Path, reference: BodyShape) -> dict[str, np.ndarray]:
    """Every posed frame of every result in ``results`` with its recording's ground truth.

    Returns:
        ``model``, ``truth`` (N, J, 3), ``rotations`` (N, S, 3, 3), ``scale`` (N,) (body
        stature over ``reference``'s), ``recording`` (N,) index into ``names``, ``names``.
    """
    model, truth, rots, scale, which, names = [], [], [], [], [], []
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
        ratio = float(body.stature()) / float(reference.stature())
        scale.append(np.full(len(rows), ratio))
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
        "recording": np.concatenate(which),
        "names": np.asarray(names),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.joint_offsets_fit",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("--results", type=Path, required=True, help="runtime-track outputs")
    p.add_argument("--recordings", type=Path, required=True, help="their recordings")
    p.add_argument("--out", type=Path, required=True, help="the joint-offsets file to write")
    args = p.parse_args(argv)
    for flag, folder in (("--results", args.results), ("--recordings", args.recordings)):
        if not folder.is_dir():
            p.error(f"{flag} {folder}: no such folder")
    reference = BodyShape.default(torch.float64)
    try:
        data = load_tracked(args.results, args.recordings, reference)
    except (FileNotFoundError, ValueError, KeyError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    offsets = fit_offsets(data["model"], data["truth"], data["rotations"], data["scale"])
    moved = offset_joints(
        torch.from_numpy(data["model"]),
        torch.from_numpy(data["rotations"]),
        torch.from_numpy(offsets),
        torch.from_numpy(data["scale"]),
    ).numpy()
    before = np.linalg.norm(data["model"] - data["truth"], axis=-1)
    after = np.linalg.norm(moved - data["truth"], axis=-1)
    result = JointOffsets(
        offsets,
        float(reference.stature()),
        fitted_on=f"{args.results} against {args.recordings}",
        frames=len(before),
    )
    save_joint_offsets(args.out, result)
    print(f"{len(data['names'])} recordings, {len(before)} frames -> {args.out}")
    print(f"mean joint error on them: {1e3 * before.mean():.1f} -> {1e3 * after.mean():.1f} mm")
    for j, name in enumerate(sk.JOINT_NAMES):
        size = 1e3 * np.linalg.norm(offsets[j])
        print(
            f"  {name:<11s} offset {size:5.1f} mm   "
            f"{1e3 * before[:, j].mean():6.1f} -> {1e3 * after[:, j].mean():6.1f} mm"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
