"""Evaluation of personalization like Helten et al. 2013, Figure 3.

    python -m depthmocap.train.evaluation.personalization --subjects 6 --out DIR \
        [--threads 2] [--seed 0]

Renders the two calibration views of subjects of different gender and size
(:mod:`train.synth.calibration_views`; alternately male and female, heights spread over anny's adult
range), runs ``runtime-personalize`` on each (as a subprocess: ``train`` does not import
``runtime``), and compares the fitted rest mesh with the ground-truth rest mesh vertex by
vertex (same topology), head excluded as in Helten's table. Two figures per subject:

* ``raw``: both meshes in the body frame (origin at the hip centre, anny's A-pose rest);
* ``aligned``: after removing the mean offset, which stands in for Helten's pose
  compensation (an error of the fitted hip centre shifts every vertex).

Prints a table (mean, standard deviation, max in mm, fit seconds) and writes
``DIR/personalize_eval.json``. Exit status 2 with ``error:`` when a subject fails.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["subject_phenotypes", "vertex_errors", "main"]

HEAD_SEGMENT = 4  # shared.skeleton.SEGMENT_NAMES.index("head")


def subject_phenotypes(count: int, seed: int = 0) -> list[dict[str, float]]:
    """``count`` adult phenotypes: alternately male/female, heights spread evenly over
    [0.25, 0.6] (about 1.55-1.90 m), the other parameters random (seeded)."""
    rng = np.random.default_rng([seed, 606])
    heights = np.linspace(0.25, 0.6, max(count, 1))
    order = rng.permutation(count)
    out = []
    for i in range(count):
        out.append(
            {
                "gender": float(
                    abs(rng.normal(0.0, 0.1)) if i % 2 == 0 else 1 - abs(rng.normal(0.0, 0.1))
                ),
                "age": float(rng.uniform(0.7, 0.9)),
                "muscle": float(rng.uniform(0.2, 0.8)),
                "weight": float(rng.uniform(0.2, 0.8)),
                "height": float(heights[order[i]]),
                "proportions": float(rng.uniform(0.2, 0.8)),
            }
        )
    return out


def vertex_errors(fit_vertices: np.ndarray, gt_vertices: np.ndarray, keep: np.ndarray) -> dict:
    """Vertex-to-vertex distances (mm) over ``keep``: raw and with the mean offset removed."""
    diff = (fit_vertices - gt_vertices)[keep]
    out = {}
    for name, d in (("raw", diff), ("aligned", diff - diff.mean(0))):
        e = np.linalg.norm(d, axis=1) * 1000.0
        out[name] = {"mean_mm": float(e.mean()), "std_mm": float(e.std()), "max_mm": float(e.max())}
    return out


def _run_subject(
    root: Path, index: int, phenotype: dict, seed: int, threads: int, clean: bool, fit_args: list
) -> dict:
    from depthmocap.train.synth.calibration_views import (
        CalibrationViewConfig,
        render_calibration_views,
    )

    subject = root / f"subject{index}"
    cfg = CalibrationViewConfig(noise=not clean)
    render_calibration_views(subject, seed=seed + index, phenotype=phenotype, cfg=cfg,
                             overwrite=True)  # fmt: skip
    cmd = [
        sys.executable, "-m", "depthmocap.runtime.personalize_cli", "--input", str(subject),
        "--output", str(subject / "body.json"), "--mesh-out", str(subject / "fit.npz"),
        "--threads", str(threads), *fit_args,
    ]  # fmt: skip
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"subject {index}: {proc.stderr.strip() or proc.stdout.strip()}")
    with np.load(subject / "groundtruth_body.npz") as gt, np.load(subject / "fit.npz") as fit:
        keep = gt["vertex_segment"] != HEAD_SEGMENT
        errors = vertex_errors(fit["rest_vertices"], gt["rest_vertices"], keep)
        timings = json.loads(str(fit["timings"]))
        return {
            "subject": subject.name,
            "gender": "M" if phenotype["gender"] < 0.5 else "F",
            "phenotype": phenotype,
            "fitted_phenotype": fit["phenotype"].tolist(),
            "errors": errors,
            "fit_s": timings["fit_s"],
            "timings": timings,
            "process_wall_s": wall,
            "residual_rms_mm": (fit["rms_m"] * 1000).tolist(),
        }


def format_table(rows: list[dict]) -> str:
    names = [f"{r['gender']}{i}" for i, r in enumerate(rows)]
    lines = ["metric (mm)      " + "".join(f"{n:>8}" for n in names) + f"{'avg':>8}"]
    for kind in ("raw", "aligned"):
        for stat in ("mean_mm", "std_mm", "max_mm"):
            vals = [r["errors"][kind][stat] for r in rows]
            label = f"{kind} {stat[:-3]}"
            lines.append(
                f"{label:<17}" + "".join(f"{v:8.1f}" for v in vals) + f"{np.mean(vals):8.1f}"
            )
    fit = [r["fit_s"] for r in rows]
    lines.append(
        f"{'fit seconds':<17}" + "".join(f"{v:8.1f}" for v in fit) + f"{np.mean(fit):8.1f}"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.personalization",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("--subjects", type=int, default=6, help="number of synthetic subjects")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--seed", type=int, default=0, help="seed of phenotypes, poses and noise")
    p.add_argument("--threads", type=int, default=1, help="CPU threads of each fit")
    p.add_argument("--clean", action="store_true", help="render without Kinect noise")
    p.add_argument(
        "--fit-args", default="", help="extra runtime-personalize options, e.g. '--seed 1'"
    )
    args = p.parse_args(argv)
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    if args.subjects < 1:
        print("error: --subjects must be >= 1", file=sys.stderr)
        return 2
    root = Path(args.out)
    root.mkdir(parents=True, exist_ok=True)
    rows = []
    try:
        for i, ph in enumerate(subject_phenotypes(args.subjects, args.seed)):
            rows.append(
                _run_subject(
                    root, i, ph, args.seed, args.threads, args.clean, args.fit_args.split()
                )
            )
    except RuntimeError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    table = format_table(rows)
    print(table)
    summary = {
        "threads": args.threads,
        "subjects": rows,
        "mean": {
            kind: {
                s: float(np.mean([r["errors"][kind][s] for r in rows]))
                for s in ("mean_mm", "std_mm", "max_mm")
            }
            for kind in ("raw", "aligned")
        },  # fmt: skip
        "mean_fit_s": float(np.mean([r["fit_s"] for r in rows])),
    }
    (root / "personalize_eval.json").write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
