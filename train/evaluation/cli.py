"""``train-eval``: score a tracking result against a recording's ground truth.

    train-eval --recording REC --result DIR [--json OUT] [--plot PNG]

Prints a table (mean and per-joint joint error, raw and offset-normalized, precision at
10 cm raw and after normalization, the share of frames with a joint beyond 20 cm after
normalization, 97%-quantile surface error, tracking/system failure rates, frames/s), writes the
figure to ``--plot`` (default ``DIR/evaluation.png``; ``--plot ''`` for none) and the full
report to ``--json``. Metric definitions: :mod:`train.evaluation.metrics`; frame and joint
matching: :mod:`train.evaluation.evaluate`. Exit status 2 with a one-line ``error:`` on
missing or mismatched inputs.

A recording without ground truth but with a reference skeleton (``reference.npz``: another
tracker's joints, e.g. the Kinect SDK's on imported real data) is scored against that
reference, on the joints its map gives a counterpart; the output then says, at the top and in
the notes, that the figures are agreement with another tracker, not accuracy.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from depthmocap.shared.config import ConfigError, add_cli_args, config_from_args
from depthmocap.shared.recording import RecordingError
from depthmocap.train.evaluation.evaluate import (
    EvalConfig,
    Evaluation,
    EvaluationError,
    evaluate,
    format_failed_frames,
)
from depthmocap.train.evaluation.plot import render_plot, save_plot
from depthmocap.train.evaluation.result_io import ResultFileError
from depthmocap.train.evaluation.truth import REFERENCE

__all__ = ["main", "format_table"]


def _fmt(v, unit: str = "", digits: int = 1) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}{unit}"


def format_table(ev: Evaluation) -> str:
    """The human-readable report."""
    r = ev.report
    reference = r.get("truth") == REFERENCE
    lines = [f"recording  {r['recording']}", f"result     {r['result']}"]
    if reference:
        lines += [
            f"reference  {r['truth_source']}, NOT ground truth:",
            "           the figures are agreement with another tracker, not accuracy",
        ]
        if r["reference_joints_without_counterpart"]:
            lines.append(
                "           not evaluated (no counterpart among our joints): "
                + ", ".join(r["reference_joints_without_counterpart"])
            )
    lines += [
        f"frames     {r['frames']} evaluated, {r['frames_with_pose']} with a pose, "
        f"{r['frames_missing']} missing, {r['frames_unprocessed']} not processed",
        "",
        f"{'joint':<14}{'distance mm' if reference else 'error mm':>12}{'offset-norm mm':>16}"
        f"{'prec@10cm':>11}{'norm@10cm':>11}{'norm>20cm %':>13}",
    ]
    for name in r["joints"]:
        lines.append(
            f"{name:<14}{_fmt(r['per_joint_error_mm'][name]):>12}"
            f"{_fmt(r['per_joint_error_offset_normalized_mm'][name]):>16}"
            f"{_fmt(r['per_joint_precision_10cm'][name], digits=3):>11}"
            f"{_fmt(r['per_joint_precision_10cm_offset_normalized'][name], digits=3):>11}"
            f"{_fmt(r['per_joint_failure_offset_normalized_pct'][name]):>13}"
        )
    failed = r.get("system_failure_frames") or []
    failed_norm = r.get("system_failure_offset_normalized_frames") or []
    lines += [
        f"{'mean':<14}{_fmt(r['mean_joint_error_mm']):>12}"
        f"{_fmt(r['mean_joint_error_offset_normalized_mm']):>16}"
        f"{_fmt(r['precision_10cm'], digits=3):>11}"
        f"{_fmt(r['precision_10cm_offset_normalized'], digits=3):>11}",
        "",
        f"surface error q97     {_fmt(r['surface_error_q97_mm'], ' mm')}"
        f" ({r['surface_error_frames']} frames)",
        f"tracking failure      {_fmt(r['tracking_failure_pct'], ' %', 2)}"
        f" (detector frames, the first included: {_fmt(r['detector_frames_pct'], ' %', 2)})",
        f"system failure        {_fmt(r['system_failure_pct'], ' %', 2)}"
        + (f" (frames {format_failed_frames(failed, 12)})" if failed else ""),
        f"  offset-normalized   {_fmt(r['system_failure_offset_normalized_pct'], ' %', 2)}"
        + (f" (frames {format_failed_frames(failed_norm, 12)})" if failed_norm else ""),
        f"  seen joints only    {_fmt(r.get('system_failure_visible_pct'), ' %', 2)}"
        + ("" if r.get("system_failure_visible_pct") is not None else " (no part labels)"),
        f"  observed joints only {_fmt(r.get('system_failure_observed_pct'), ' %', 2)}"
        + (
            f" (the result calls {_fmt(r.get('observed_joints_pct'), ' %', 1)} of its joints "
            f"observed; they cover {_fmt(r.get('observed_flag_recall_pct'), ' %', 1)} of the "
            f"seen joints)"
            if r.get("system_failure_observed_pct") is not None
            else " (the result has no observed flags)"
        ),
        f"processing rate       {_fmt(r['fps'], ' frames/s')}",
        f"offset-norm frames    {r['offset_frame']}",
    ]
    lines += [f"note: {n}" for n in r["notes"]]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train-eval", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--recording",
        required=True,
        help="recording directory with groundtruth.npz (or, failing that, reference.npz)",
    )
    p.add_argument("--result", required=True, help="runtime-track result directory")
    p.add_argument("--json", default=None, help="write the full report as JSON here")
    p.add_argument(
        "--plot", default=None, help="figure PNG (default RESULT/evaluation.png; '' for none)"
    )
    add_cli_args(p, EvalConfig)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = config_from_args(EvalConfig, args)
        ev = evaluate(args.recording, args.result, cfg)
        print(format_table(ev))
        plot = Path(args.result) / "evaluation.png" if args.plot is None else args.plot
        if plot:
            title = f"{Path(args.result).name} vs {Path(args.recording).name}" + (
                " (reference: another tracker)" if ev.truth.kind == REFERENCE else ""
            )
            image = render_plot(
                ev.frame_errors_mm,
                ev.frame_status,
                ev.joint_names,
                ev.per_joint_mm,
                ev.per_joint_norm_mm,
                title=title,
                threshold_mm=cfg.precision_threshold_m * 1e3,
            )
            save_plot(plot, image)
            print(f"plot: {plot}")
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps(ev.report, indent=2, allow_nan=False) + "\n")
            print(f"json: {args.json}")
    except (RecordingError, ResultFileError, EvaluationError, ConfigError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
