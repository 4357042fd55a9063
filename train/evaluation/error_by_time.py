"""When in a take the errors and the tracking failures are: the frames of ``dev_benchmark``
runs pooled by their index in the take.

A take starts with a detection and, without a body file, at the population's size until the
size search has read its first sample, so its first frames behave unlike the rest. How much a
start-up change moves a table depends on the takes' length: the broad tuning set's takes are
24 frames long, the size tuning set's 60 and the reported set's 57 on average, and a change
that helped the first set's start-ups did not help the others (``docs/experiments.md``,
thirty-ninth session). This table shows where in time a run's error and re-detections sit,
and with ``--base`` how a change moves each stretch. A second table splits the run's frames by
how the hybrid chose their pose (:data:`KINDS`): a track kept after failing Wei's tests
because the detection fitted worse is reported ``tracked`` and is no tracking failure by
:func:`.metrics.tracking_failure_pct`, yet it is where the largest errors are.
``real_benchmark`` outputs are read too (their recordings' reference in place of the truth:
raw distances to another tracker).

Per bin of ``--bin`` frames (the last bin holds every later frame): the frames pooled, their
mean joint error (mm; the mean over a frame's joints, frames without a pose left out) and the
share of them that are tracking failures (:func:`.metrics.tracking_failure_pct`'s frames:
every frame not ``tracked`` except a track's first, so lost frames count too).

    python -m depthmocap.train.evaluation.error_by_time OUT [OUT ...] [--base OUT ...]
        [--bin 4] [--bins 6] [--config "hybrid, default body @ 0.2 rad"]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from depthmocap.shared.recording import Recording

from .compare_runs import DEFAULT_CONFIG, load_runs
from .metrics import initializations, joint_errors, per_frame_error_mm
from .result_io import load_result
from .truth import recording_truth, shared_joints

__all__ = [
    "KINDS",
    "frame_rows",
    "pose_kinds",
    "pooled_by_bin",
    "pooled_by_kind",
    "run_entries",
    "format_table",
    "format_kinds",
    "main",
]


def frame_rows(recording: str | Path, result: str | Path) -> dict[str, np.ndarray]:
    """Per written frame of ``result``: its index in the take, its mean joint error against
    the recording's truth (m; NaN without a pose) and whether it is a tracking failure, each
    (N,). Joints are those the result and the truth share."""
    truth = recording_truth(Recording(recording))
    res = load_result(result)
    try:
        _, ours, true = shared_joints(truth, res)
    except ValueError as err:
        raise ValueError(f"{result} against {recording}: {err}") from None
    distance = joint_errors(ours, true)  # (N, J), NaN where no pose
    error = per_frame_error_mm(distance) / 1e3
    worst = np.fmax.reduce(distance, axis=1)  # NaN only where the frame has no pose
    failure = (res.status != "tracked") & ~initializations(res.status)
    return {
        "index": res.frame.astype(np.int64),
        "error": error,
        "worst": worst,
        "failure": failure,
        "kind": pose_kinds(res.status, res.errors),
    }


def pose_kinds(status: np.ndarray, errors: dict[str, np.ndarray]) -> np.ndarray:
    """(N,) how the hybrid chose each frame's pose (:data:`KINDS`), from its status and the
    flags the estimator writes among a frame's errors (``runtime.hybrid.estimator``)."""
    status = np.asarray(status)
    n = len(status)

    def flag(name: str) -> np.ndarray:
        return np.isfinite(errors[name]) if name in errors else np.zeros(n, bool)

    kind = np.full(n, KINDS[0], dtype=object)
    tracked = status == "tracked"
    kind[tracked & (flag("rechecked") | flag("confirmed_by_detector"))] = KINDS[1]
    kind[tracked & flag("detector_waited")] = KINDS[2]
    kind[tracked & flag("kept_over_detector")] = KINDS[3]
    start = initializations(status)
    kind[(status == "detected") & ~start] = KINDS[4]
    kind[start] = KINDS[5]
    kind[status == "lost"] = KINDS[6]
    return kind


#: How a frame's pose was chosen: passed Wei's tests; passed them, was rechecked by the
#: detector and kept; failed or suspect while the detector waited after a refusal; failed
#: them and kept because the detection fitted worse; the detection taken over a track; a
#: track's first frame; no pose.
KINDS = (
    "tracked",
    "tracked, rechecked",
    "tracked, detector waited",
    "tracked, tests failed",
    "detection taken",
    "track start",
    "lost",
)


def pooled_by_kind(runs: Iterable[dict[str, np.ndarray]], gross_m: float = 0.2) -> list[dict]:
    """Rows of :func:`frame_rows` pooled by :func:`pose_kinds` (the kinds that occur, in
    :data:`KINDS` order): ``kind``, ``frames``, ``frames_pct`` (of all), ``error_mm`` and
    ``gross_pct``, the kind's share of all frames with a joint more than ``gross_m`` off."""
    runs = list(runs)
    if not runs:
        return []
    kind = np.concatenate([r["kind"] for r in runs])
    error = np.concatenate([r["error"] for r in runs])
    with np.errstate(invalid="ignore"):
        gross = np.concatenate([r["worst"] for r in runs]) > gross_m
    rows = []
    for k in KINDS:
        sel = kind == k
        if not sel.any():
            continue
        posed = sel & np.isfinite(error)
        rows.append(
            {
                "kind": k,
                "frames": int(sel.sum()),
                "frames_pct": 100.0 * float(sel.mean()),
                "error_mm": 1e3 * float(error[posed].mean()) if posed.any() else float("nan"),
                "gross_pct": 100.0 * float((gross & sel).sum()) / max(int(gross.sum()), 1),
            }
        )
    return rows


def format_kinds(rows: list[dict]) -> str:
    """:func:`pooled_by_kind`'s rows as markdown."""
    lines = [
        "| pose | frames | share | joint error mm | share of frames with a joint > 20 cm |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['kind']} | {r['frames']} | {r['frames_pct']:.1f}% | {r['error_mm']:.1f} "
            f"| {r['gross_pct']:.1f}% |"
        )
    return "\n".join(lines)


def pooled_by_bin(runs: Iterable[dict[str, np.ndarray]], bin_frames: int, bins: int) -> list[dict]:
    """``bins`` rows of :func:`frame_rows` pooled over ``runs``: frames ``k * bin_frames``
    to ``(k + 1) * bin_frames - 1``, the last row from its first frame on. Each row: ``first``,
    ``last`` (None for the open last row), ``frames``, ``error_mm`` (NaN for no pose) and
    ``failure_pct``."""
    if bin_frames < 1 or bins < 1:
        raise ValueError(f"bin_frames and bins must be >= 1, got {bin_frames}, {bins}")
    runs = list(runs)
    index = np.concatenate([r["index"] for r in runs]) if runs else np.zeros(0, np.int64)
    error = np.concatenate([r["error"] for r in runs]) if runs else np.zeros(0)
    failure = np.concatenate([r["failure"] for r in runs]) if runs else np.zeros(0, bool)
    which = np.minimum(index // bin_frames, bins - 1)
    rows = []
    for k in range(bins):
        sel = which == k
        posed = sel & np.isfinite(error)
        rows.append(
            {
                "first": k * bin_frames,
                "last": None if k == bins - 1 else (k + 1) * bin_frames - 1,
                "frames": int(sel.sum()),
                "error_mm": 1e3 * float(error[posed].mean()) if posed.any() else float("nan"),
                "failure_pct": 100.0 * float(failure[sel].mean()) if sel.any() else float("nan"),
            }
        )
    return rows


def format_table(rows: list[dict], base: list[dict] | None = None) -> str:
    """The rows as markdown; with ``base`` (the same bins), each figure as ``base -> new``."""

    def span(r: dict) -> str:
        return f"{r['first']}-{r['last']}" if r["last"] is not None else f"{r['first']}-"

    def pair(key: str, b: dict | None, r: dict, unit: str) -> str:
        new = f"{r[key]:.1f}{unit}"
        return new if b is None else f"{b[key]:.1f}{unit} -> {new}"

    lines = ["| frames | count | joint error mm | tracking failure |", "|---|---|---|---|"]
    for b, r in zip(base or [None] * len(rows), rows, strict=True):
        lines.append(
            f"| {span(r)} | {r['frames']} | {pair('error_mm', b, r, '')} "
            f"| {pair('failure_pct', b, r, '%')} |"
        )
    return "\n".join(lines)


def run_entries(outs: list[Path], config: str) -> list[dict]:
    """The per-recording entries (each with ``recording`` and ``result``) of ``dev_benchmark``
    outputs (``config``'s) or of ``real_benchmark`` outputs (their own, scored against the
    reference: raw distances, as the reference has no offsets of ours to normalize)."""
    real, bench = [], []
    for out in outs:
        path = Path(out) / "report.json"
        report = json.loads(path.read_text()) if path.is_file() else {}
        if isinstance(report.get("per_recording"), dict):  # real_benchmark's report
            real.extend(report["per_recording"].values())
        else:
            bench.append(out)
    return real + (list(load_runs(bench, config).values()) if bench else [])


def _frames(outs: list[Path], config: str) -> list[dict[str, np.ndarray]]:
    return [frame_rows(e["recording"], e["result"]) for e in run_entries(outs, config)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.error_by_time",
        description="Joint error and tracking failures of dev_benchmark runs by the frames' "
        "index in their take (start-up against the rest).",
    )
    parser.add_argument(
        "outs", nargs="+", type=Path, help="dev_benchmark or real_benchmark --out folders"
    )
    parser.add_argument(
        "--base", nargs="+", type=Path, default=None, help="folders of a run to compare with"
    )
    parser.add_argument("--config", default=DEFAULT_CONFIG, help="configuration to read")
    parser.add_argument("--bin", type=int, default=4, help="frames per bin")
    parser.add_argument("--bins", type=int, default=6, help="bins (the last one open)")
    args = parser.parse_args(argv)
    try:
        frames = _frames(args.outs, args.config)
        rows = pooled_by_bin(frames, args.bin, args.bins)
        base = None
        if args.base is not None:
            base = pooled_by_bin(_frames(args.base, args.config), args.bin, args.bins)
    except ValueError as err:  # a missing or malformed report, recording or result; bad bins
        print(f"error_by_time: {err}", file=sys.stderr)
        return 2
    print(format_table(rows, base))
    print()
    print(format_kinds(pooled_by_kind(frames)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
