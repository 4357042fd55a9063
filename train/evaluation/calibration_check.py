"""Does ``runtime-calibrate``'s automatic pose check accept any body's T-pose?

    python -m depthmocap.train.evaluation.calibration_check --bodies 20 --out DIR [--seed 0]

Renders ``--bodies`` random adult anny bodies holding the calibration T-pose, facing the
camera as a user told to would (within ``--max-yaw`` degrees), from random camera heights
and distances, with the sensor's noise, a floor and a random background: alternately female
and male, the height classes (short, medium, tall of the broad protocol's ranges, statures
about 1.48-1.95 m) and the weight classes (slim, average, heavy) in turn, the rest random.
Runs ``runtime-calibrate`` on each (a subprocess: ``train`` does not import ``runtime``) with
its automatic pose check, and reports which bodies it accepted and, for those, the stature
and the mean bone length error of the calibrated body against the rendered body's own.

Prints a table and writes ``DIR/calibration_check.json``; exit status 0 when every body was
accepted, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

__all__ = ["check_phenotypes", "main"]


def check_phenotypes(count: int, seed: int = 0) -> list[dict[str, float]]:
    """``count`` adult phenotypes spread over sex, height class and weight class (module
    docstring), the broad protocol's ranges."""
    from depthmocap.train.evaluation.protocol import (
        HEIGHT_CLASSES,
        WEIGHT_CLASSES,
        BroadProtocolConfig,
        variant_phenotype,
    )

    cfg = BroadProtocolConfig()
    rng = np.random.default_rng([seed, 3737])
    out = []
    for i in range(count):
        sex = "female" if i % 2 == 0 else "male"
        height, weight = HEIGHT_CLASSES[(i // 2) % 3], WEIGHT_CLASSES[(i // 6 + i) % 3]
        out.append(variant_phenotype(cfg, sex, height, weight, rng.random(6)))
    return out


def render_t_pose(phenotype: dict, out: Path, seed: int, frames: int, max_yaw: float) -> None:
    """The body ``phenotype`` holding the T-pose for ``frames`` frames, facing the camera
    within ``max_yaw`` degrees (a recording in ``out``)."""
    from depthmocap.train.synth.frame import SceneConfig
    from depthmocap.train.synth.sequence import render_sequence

    scene = SceneConfig()
    views = replace(
        scene.viewpoints,
        front_weight=1.0,
        side_weight=0.0,
        back_weight=0.0,
        front_half_angle_deg=max_yaw,
    )
    render_sequence(
        "t_pose", out, frames=frames, seed=seed, overwrite=True, phenotype=phenotype,
        cfg=replace(scene, viewpoints=views),
    )  # fmt: skip


def _body_errors(calibrated: Path, truth: Path) -> dict:
    from depthmocap.shared.body import BodyShape

    fit, true = BodyShape.load(calibrated), BodyShape.load(truth)
    return {
        "stature_m": round(float(fit.stature()), 4),
        "true_stature_m": round(float(true.stature()), 4),
        "length_error_cm": round(100 * float((fit.lengths - true.lengths).abs().mean()), 2),
    }


def check_body(recording: Path, out: Path, threads: int, hold: int = 10) -> dict:
    """``runtime-calibrate`` with its pose check on one recording (the pose held ``hold``
    frames): accepted, and how well."""
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    body = out / f"{recording.name}.json"
    cmd = [sys.executable, "-m", "depthmocap.runtime.calibrate_cli", "-i", str(recording),
           "-o", str(body), "--frames", str(hold), "-q"]  # fmt: skip
    run = subprocess.run(cmd, capture_output=True, text=True, env=env)
    row = {"recording": recording.name, "accepted": run.returncode == 0}
    if run.returncode == 0:
        row.update(_body_errors(body, recording / "body.json"))
    else:
        row["error"] = (run.stderr.strip().splitlines() or ["(no message)"])[-1]
    return row


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.calibration_check",
        description="runtime-calibrate's automatic pose check on random bodies' T-poses",
    )
    p.add_argument("--bodies", type=int, default=20, help="random bodies rendered")
    p.add_argument("--out", type=Path, default=Path("out/calibration_check"))
    p.add_argument("--seed", type=int, default=0, help="bodies and cameras are drawn from it")
    p.add_argument("--frames", type=int, default=15, help="frames of T-pose per body")
    p.add_argument("--max-yaw", type=float, default=20.0, help="facing the camera within, deg")
    p.add_argument("--threads", type=int, default=1, help="torch threads of each calibration")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.bodies < 1 or args.frames < 1 or not 0 <= args.max_yaw <= 90:
        parser.error("--bodies and --frames must be >= 1 and --max-yaw within 0-90 degrees")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, phenotype in enumerate(check_phenotypes(args.bodies, args.seed)):
        rec = args.out / f"body_{i:02d}"
        if not (rec / "groundtruth.npz").is_file():
            render_t_pose(phenotype, rec, 50_000 + 100 * args.seed + i, args.frames, args.max_yaw)
        hold = min(10, args.frames)  # runtime-calibrate's default, or all frames
        row = {**check_body(rec, args.out, args.threads, hold), "phenotype": phenotype}
        rows.append(row)
        detail = (
            f"stature {row['stature_m']:.3f} m (true {row['true_stature_m']:.3f}), "
            f"bone lengths {row['length_error_cm']:.1f} cm off"
            if row["accepted"]
            else row["error"]
        )
        print(f"{rec.name}  {'accepted' if row['accepted'] else 'REFUSED '}  {detail}", flush=True)
    accepted = [r for r in rows if r["accepted"]]
    print(f"accepted {len(accepted)} of {len(rows)} bodies")
    if accepted:
        errors = [r["length_error_cm"] for r in accepted]
        stature = [abs(r["stature_m"] - r["true_stature_m"]) * 100 for r in accepted]
        print(f"calibrated: bone lengths {np.mean(errors):.1f} cm off on average (max "
              f"{np.max(errors):.1f}), stature {np.mean(stature):.1f} cm off")  # fmt: skip
    (args.out / "calibration_check.json").write_text(json.dumps(rows, indent=1))
    return 0 if len(accepted) == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
