"""Where the gross errors are: each joint placed against the depth image, ours and the truth.

The mean joint error mixes two things a fix must tell apart: joints a few centimetres off and
joints that are wrong (over 20 cm, the system-failure threshold). For the wrong ones, where a
joint lies relative to what the camera sees says which mechanism could fix it:

- ``outside``: it projects outside the image (or is missing): nothing in the frame shows it;
- ``off_body``: no person pixel within ``SLACK_PX`` of its pixel;
- ``in_front``: in the empty space in front of the surface the camera sees there;
- ``on_surface``: within ``HIDDEN_M`` behind that surface (a joint inside a limb the camera
  sees lies a few centimetres behind its skin);
- ``hidden``: more than ``HIDDEN_M`` behind it: behind another part, where no data term
  reaches.

A true joint ``hidden`` whose estimate is ``on_surface`` is a limb the camera does not see laid
onto parts it does see; a true joint ``outside`` whose estimate is ``on_surface``, a limb out
of view folded back into it. :func:`gross_error_table` pools recordings by (estimate, truth)
place. The placing is :func:`~train.evaluation.depth_refutation.joint_places` (the tests that
refute a tracker's joint, plus the hidden one) on the person's pixels: the recording's part
labels when it has them (rendered recordings show the floor and clutter too), else its depth.

    python -m depthmocap.train.evaluation.error_sources OUT [OUT ...] [--threshold 0.2]

reads one configuration (``--config``, the fully automatic hybrid by default) of
``dev_benchmark`` outputs (``OUT/report.json``, read as :mod:`.compare_runs` reads them) and
prints the table.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from depthmocap.shared.recording import Recording

from .compare_runs import DEFAULT_CONFIG, load_runs
from .depth_refutation import (
    HIDDEN,
    HIDDEN_M,
    IN_FRONT,
    OFF_BODY,
    ON_SURFACE,
    OUTSIDE,
    PLACES,
    joint_places,
)
from .result_io import load_result
from .truth import recording_truth, shared_joints

__all__ = [
    "HIDDEN",
    "HIDDEN_M",
    "IN_FRONT",
    "OFF_BODY",
    "ON_SURFACE",
    "OUTSIDE",
    "PLACES",
    "gross_error_table",
    "joint_places",
    "person_depth",
    "recording_places",
]


def person_depth(rec: Recording, i: int) -> np.ndarray:
    """Frame ``i``'s depth (metres) on the person only: on the recording's part labels when
    it has them, else all of its depth (a recording with the background removed)."""
    depth = rec.read_depth(i).astype(np.float64)
    if rec.has_labels:
        depth = np.where(rec.read_labels(i) > 0, depth, 0.0)
    return depth


def recording_places(recording: str | Path, result: str | Path) -> dict[str, np.ndarray]:
    """Per frame of ``result`` and joint the recording's truth and the result share: the
    error (m), our place and the truth's (:data:`PLACES` indices), each (F, J), and the joint
    names (J,)."""
    rec = Recording(recording)
    truth = recording_truth(rec)
    res = load_result(result)
    names, ours, true = shared_joints(truth, res)
    error = np.linalg.norm(ours - true, axis=-1)
    our_places = np.empty(error.shape, np.int64)
    true_places = np.empty(error.shape, np.int64)
    for k, i in enumerate(res.frame):
        depth = person_depth(rec, int(i))
        our_places[k] = joint_places(depth, ours[k], rec.intrinsics)
        true_places[k] = joint_places(depth, true[k], rec.intrinsics)
    return {"error": error, "ours": our_places, "truth": true_places, "names": np.array(names)}


def gross_error_table(
    runs: Iterable[dict[str, np.ndarray]], threshold_m: float = 0.2
) -> list[dict[str, float | str]]:
    """Over all joint estimates of ``runs`` (:func:`recording_places`), the gross ones
    (error over ``threshold_m``) by (our place, the truth's): each pair's share of all joint
    estimates, its share of the total error, and its mean error (mm), largest share of the
    error first; a last row ``all gross`` sums them. Missing estimates (NaN) count nowhere."""
    runs = list(runs)
    error = np.concatenate([r["error"].ravel() for r in runs])
    ours = np.concatenate([r["ours"].ravel() for r in runs])
    true = np.concatenate([r["truth"].ravel() for r in runs])
    ok = np.isfinite(error)
    total, count = float(error[ok].sum()), int(ok.sum())
    gross = ok & (error > threshold_m)
    rows = []
    for a in range(len(PLACES)):
        for b in range(len(PLACES)):
            sel = gross & (ours == a) & (true == b)
            if sel.any():
                rows.append(
                    {
                        "ours": PLACES[a],
                        "truth": PLACES[b],
                        "joints_pct": 100.0 * sel.sum() / count,
                        "error_pct": 100.0 * error[sel].sum() / total,
                        "mean_mm": 1e3 * float(error[sel].mean()),
                    }
                )
    rows.sort(key=lambda r: -r["error_pct"])
    if gross.any():
        rows.append(
            {
                "ours": "all gross",
                "truth": "",
                "joints_pct": 100.0 * gross.sum() / count,
                "error_pct": 100.0 * error[gross].sum() / total,
                "mean_mm": 1e3 * float(error[gross].mean()),
            }
        )
    return rows


def format_table(rows: list[dict[str, float | str]]) -> str:
    """The table as markdown."""
    lines = [
        "| ours | truth | share of joints | share of the error | mean error mm |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['ours']} | {r['truth']} | {r['joints_pct']:.1f}% | {r['error_pct']:.1f}% "
            f"| {r['mean_mm']:.0f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.error_sources",
        description="Where the gross joint errors of dev_benchmark runs are: each joint "
        "placed against the depth image (outside, off the body, in front, on the surface, "
        "hidden), ours against the truth.",
    )
    parser.add_argument("outs", nargs="+", type=Path, help="dev_benchmark --out folders")
    parser.add_argument("--config", default=DEFAULT_CONFIG, help="configuration to read")
    parser.add_argument("--threshold", type=float, default=0.2, help="gross error (m)")
    args = parser.parse_args(argv)
    try:
        entries = load_runs(args.outs, args.config).values()
        runs = [recording_places(e["recording"], e["result"]) for e in entries]
    except ValueError as err:  # a missing or malformed report, recording or result
        print(f"error_sources: {err}", file=sys.stderr)
        return 2
    print(format_table(gross_error_table(runs, args.threshold)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
