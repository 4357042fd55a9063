"""Move the joints of finished runs to another joint-offsets file, without tracking again.

    python -m depthmocap.train.evaluation.reapply_offsets \\
        --results out/broad/hybrid_default_body --old-offsets old.json \\
        --offsets models/joint_offsets.json --out out/broad_new/hybrid_default_body

The offsets are output-only (``shared.joint_offsets``): the poses ``q`` a run tracks do not
depend on them, so a run's joints under other offsets follow from its ``poses.jsonl``. Each
frame's joints are the model's joints of its ``q`` on the body tracked at that frame, moved by
the offsets at that pose. A run without a body file tracks the population body until the size
search ends and the scaled body (the result's ``body.json``) from then on, and in between the
population body at the search's interim sizes (``body_scale.interim_after``): for each frame
the body whose joints under ``--old-offsets`` come closest to the recorded ones is taken:
``body.json``, the population body, or the population body at the factor fitted to that
frame (the joints are affine in a uniform scale: every bone and offset scales with it; an
interim size can lie within a millimetre of the population body, so the fitted factor is
tried on every frame). A frame that none reproduces to 1 mm is an error (the run was made
with other offsets or bodies).
Every other field of ``poses.jsonl`` is kept; ``summary.json``, ``body.json`` and the BVH are
copied, so the evaluation (``dev_benchmark --reuse-results``, ``train-eval``) reads the new
folder as a run of its own.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared.body import BodyShape
from depthmocap.shared.joint_offsets import (
    JointOffsets,
    JointOffsetsError,
    apply_offsets,
    load_joint_offsets,
)
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
from depthmocap.shared.resources import CONFIGS_DIR

__all__ = ["ReapplyError", "fitted_scales", "joints_with_offsets", "reapply_result", "main"]

MATCH_M = 1e-3  # recorded joints are rounded to 1 um; float32 tracking differs by ~1e-6 m


class ReapplyError(ValueError):
    """A result that cannot be moved to other offsets (not made as this tool assumes)."""


def joints_with_offsets(q: np.ndarray, body: BodyShape, offsets: JointOffsets | None) -> np.ndarray:
    """(F, J, 3) output joints of poses ``q`` (F, 34) on ``body`` under ``offsets`` (None:
    the model's own joints), as the hybrid writes them."""
    body = body.to(torch.float64)
    pose = torch.as_tensor(q, dtype=torch.float64)
    kin = forward_kinematics(pose, body)
    joints = named_joint_positions(kin)
    if offsets is None:
        return joints.numpy()
    return apply_offsets(joints, kin.rotations, pose, offsets, body.stature()).numpy()


def fitted_scales(
    q: np.ndarray, recorded: np.ndarray, body: BodyShape, offsets: JointOffsets | None
) -> np.ndarray:
    """(F,) per frame the uniform scale of ``body`` whose joints under ``offsets`` come closest
    to the ``recorded`` (F, J, 3) joints of poses ``q`` (F, 34): the joints are affine in the
    scale (``A + s B``), so two evaluations give it in closed form."""
    at_one = joints_with_offsets(q, body.scaled(1.0), offsets)
    slope = joints_with_offsets(q, body.scaled(2.0), offsets) - at_one
    rest = np.nan_to_num(recorded - at_one + slope)  # recorded - A, with A = J(1) - B
    slope = np.where(np.isfinite(recorded), slope, 0.0)
    denom = (slope * slope).sum(axis=(1, 2))
    return (slope * rest).sum(axis=(1, 2)) / np.where(denom > 0, denom, 1.0)


def _scaled_candidates(
    q: np.ndarray, recorded: np.ndarray, body: BodyShape, old: JointOffsets | None
) -> tuple[list[BodyShape], np.ndarray, np.ndarray]:
    """``body`` at each distinct fitted scale of these frames (S bodies), each frame's index
    into them (F,), and its max joint error (F,) under ``old`` at its own scale (inf where a
    joint is unwritten)."""
    scales = np.round(fitted_scales(q, recorded, body, old), 6)
    distinct, index = np.unique(scales, return_inverse=True)
    bodies, err = [], np.full(len(q), np.inf)
    for k, s in enumerate(distinct):
        mine = index == k
        scaled = body.scaled(float(s))
        bodies.append(scaled)
        e = np.abs(joints_with_offsets(q[mine], scaled, old) - recorded[mine]).max(axis=(1, 2))
        err[mine] = np.where(np.isfinite(e), e, np.inf)
    return bodies, index, err


def reapply_result(
    result: Path,
    out: Path,
    bodies: list[BodyShape],
    old: JointOffsets | None,
    new: JointOffsets | None,
    scalable: BodyShape | None = None,
) -> int:
    """Write ``result`` (a run's folder) to ``out`` with its joints under ``new``.

    Args:
        bodies: the bodies the run may have tracked at a frame (its ``body.json`` first).
        scalable: a body the run may have tracked at any uniform scale (the population
            body at the size search's interim sizes): at its fitted scale, it is a frame's
            body wherever it reproduces that frame better than ``bodies`` do; None: none.
    Returns:
        the number of frames moved.
    Raises:
        ReapplyError: a frame whose recorded joints no candidate body reproduces, or a
            malformed line before the last (an unfinished last line, from an interrupted run,
            is dropped as the evaluation drops it).
    """
    from depthmocap.shared.poses_format import JOINT_NAMES

    if _fixed_lag(result) > 0:
        raise ReapplyError(
            f"{result}: its joints were smoothed over a fixed lag (runtime-track --fixed-lag), "
            "so they are not its poses' joints; track again with --fixed-lag 0"
        )
    lines = _read_lines(result / "poses.jsonl")
    posed = [i for i, r in enumerate(lines) if r.get("q") is not None and r.get("joints")]
    if posed:
        q = np.array([lines[i]["q"] for i in posed], dtype=np.float64)
        names = list(lines[posed[0]]["joints"])
        if names != list(JOINT_NAMES):
            raise ReapplyError(f"{result}: joints {names} are not this build's")
        recorded = np.array([[lines[i]["joints"][n] or [np.nan] * 3 for n in names] for i in posed])
        err = np.stack(
            [np.abs(joints_with_offsets(q, b, old) - recorded).max(axis=(1, 2)) for b in bodies]
        )  # (candidates, F); NaN rows (unwritten joints) never match
        which = np.argmin(np.where(np.isfinite(err), err, np.inf), axis=0)
        best = err[which, np.arange(len(posed))]
        if scalable is not None:
            # Where the fitted scale reproduces a frame better (an interim size can lie
            # within MATCH_M of a listed body), it is that frame's body.
            extra, index, extra_err = _scaled_candidates(q, recorded, scalable, old)
            closer = extra_err < best
            which = np.where(closer, len(bodies) + index, which)
            best = np.where(closer, extra_err, best)
            bodies = list(bodies) + extra
        bad = ~(best < MATCH_M)
        if bad.any():
            k = posed[int(np.argmax(bad))]
            raise ReapplyError(
                f"{result}: frame {lines[k]['frame']}'s joints are {best[bad].max() * 1e3:.1f} "
                "mm from every candidate body under the old offsets (other offsets or body?)"
            )
        moved = np.empty_like(recorded)
        for b, body in enumerate(bodies):
            mine = which == b
            if mine.any():
                moved[mine] = joints_with_offsets(q[mine], body, new)
        for row, i in zip(moved, posed):
            lines[i]["joints"] = {
                n: [round(float(v), 6) for v in xyz] for n, xyz in zip(names, row)
            }
    out.mkdir(parents=True, exist_ok=True)
    (out / "poses.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    for name in ("summary.json", "body.json", "motion.bvh"):
        if (result / name).is_file():
            shutil.copyfile(result / name, out / name)
    return len(posed)


def _fixed_lag(result: Path) -> int:
    """The run's ``extra.fixed_lag_frames`` (0 for runs made before it existed)."""
    try:
        summary = json.loads((result / "summary.json").read_text())
    except (OSError, ValueError):
        return 0
    return int((summary.get("extra") or {}).get("fixed_lag_frames") or 0)


def _read_lines(path: Path) -> list[dict]:
    raw = [x for x in path.read_text().splitlines() if x.strip()]
    lines = []
    for k, text in enumerate(raw):
        try:
            lines.append(json.loads(text))
        except json.JSONDecodeError as err:
            if k == len(raw) - 1:
                break  # the unfinished last line of an interrupted run
            raise ReapplyError(f"{path}: line {k + 1} is not JSON ({err})") from None
    return lines


def _offsets(path: str) -> JointOffsets | None:
    return None if path == "none" else load_joint_offsets(path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.reapply_offsets",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("--results", type=Path, required=True, help="one run folder per recording")
    p.add_argument("--old-offsets", required=True, help="the runs' offsets file, or 'none'")
    p.add_argument("--offsets", required=True, help="the offsets file to move to, or 'none'")
    p.add_argument("--out", type=Path, required=True, help="folder of the moved runs")
    args = p.parse_args(argv)
    if not args.results.is_dir():
        p.error(f"--results {args.results}: no such folder")
    try:
        old, new = _offsets(args.old_offsets), _offsets(args.offsets)
    except JointOffsetsError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    # The body runtime-track tracks without a body file (runtime.estimator_setup's).
    population = BodyShape.load(CONFIGS_DIR / "body_template.json")
    runs = sorted(d for d in args.results.iterdir() if d.is_dir())
    moved = 0
    for run in runs:
        # dev_benchmark keeps each run in NAME/result; runtime-track writes NAME itself.
        inner = run / "result" if (run / "result" / "poses.jsonl").is_file() else run
        if not (inner / "poses.jsonl").is_file():
            continue
        target = args.out / run.name / inner.relative_to(run)
        try:
            bodies = [population]
            if (inner / "body.json").is_file():
                bodies.insert(0, BodyShape.load(inner / "body.json"))
            moved += reapply_result(inner, target, bodies, old, new, scalable=population)
        except (ReapplyError, ValueError, OSError) as err:  # body loader: ValueError
            print(f"error: {run.name}: {err}", file=sys.stderr)
            return 2
    print(f"{len(runs)} runs, {moved} posed frames moved to {args.offsets} -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
