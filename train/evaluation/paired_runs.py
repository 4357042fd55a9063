"""Two or more hybrid settings on the same recordings, alternated recording by recording.

Live accuracy (``dev_benchmark --realtime``) depends on how fast the host runs: a frame that
takes longer makes the stream skip more, which makes tracking harder. This host's speed
drifts by 10-30% over minutes, and the same code gave 55.0 and 60.0 mm in two whole live runs
of the broad protocol half an hour apart (``docs/experiments.md``, thirtieth session). Two
whole runs one after the other therefore compare the hours as much as the settings. Here each
recording is tracked with every setting in turn before the next recording (the order
alternating from one recording to the next), so the drift falls on all settings alike.

Each setting's results and ``report.json`` go to ``OUT/NAME`` in ``dev_benchmark``'s layout,
so ``compare_runs --base OUT/A --new OUT/B`` compares them and ``dev_benchmark
--reuse-results --out OUT/NAME`` prints a setting's tables::

    python -m depthmocap.train.evaluation.paired_runs --realtime \\
        --setting shipped=configs/hybrid.yaml --setting other=OTHER.yaml --out out/paired
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .dev_benchmark import (
    HEADLINE,
    _protocol_recordings,
    aggregate,
    row_label,
    run_config,
    run_folder,
    run_row,
)

__all__ = ["parse_setting", "run_paired", "setting_order"]


def parse_setting(text: str) -> tuple[str, Path]:
    """``NAME=FILE.yaml`` -> (name, path)."""
    name, sep, path = text.partition("=")
    if not sep or not name or not path or "/" in name:
        raise argparse.ArgumentTypeError(f"expected NAME=FILE.yaml, got {text!r}")
    return name, Path(path)


def setting_order(names: list[str], index: int) -> list[str]:
    """The settings' order for the ``index``-th recording: as given, then reversed, in turn."""
    return list(names) if index % 2 == 0 else list(reversed(names))


def run_paired(
    settings: list[tuple[str, Path]],
    recs: list[Path],
    out: Path,
    model: str,
    device: str = "cpu",
    trust_region: float | None = 0.2,
    realtime: bool = False,
    reuse: bool = False,
) -> dict[str, dict]:
    """Track every recording with every setting, alternated; write and return each
    setting's report (``{row: {"mean", "per_recording", "config"}}``, as ``dev_benchmark``
    writes it) by setting name."""
    row = run_row(row_label(HEADLINE), realtime, trust_region)
    slug = run_folder(row)
    tracker = {"max_step_rad": trust_region} if trust_region else None
    paths = dict(settings)
    per_rec: dict[str, dict[str, dict]] = {name: {} for name in paths}
    for i, rec in enumerate(recs):
        for name in setting_order(list(paths), i):
            per_rec[name][rec.name] = run_config(
                HEADLINE, rec, out / name / slug / rec.name, model, device, paths[name],
                tracker, reuse, realtime,
            )  # fmt: skip
        print(f"{i + 1}/{len(recs)} {rec.name}", flush=True)
    reports = {}
    for name, reports_of in per_rec.items():
        report = {row: {"mean": aggregate(list(reports_of.values())),
                         "per_recording": reports_of, "config": HEADLINE}}  # fmt: skip
        (out / name).mkdir(parents=True, exist_ok=True)
        (out / name / "report.json").write_text(json.dumps(report, indent=1))
        reports[name] = report
    return reports


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.paired_runs",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("--setting", action="append", type=parse_setting, required=True,
                   metavar="NAME=FILE.yaml", help="a hybrid settings file and its name; "
                   "two or more")  # fmt: skip
    p.add_argument("--recordings", type=Path, default=Path("data/dev_broad"),
                   help="the broad protocol's recordings")  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("out/paired"))
    p.add_argument("--model", default="models/forest.npz")
    p.add_argument("--device", default="cpu")
    p.add_argument("--trust-region", type=float, default=0.2,
                   help="the tracker's max_step_rad, as dev_benchmark --trust-regions")  # fmt: skip
    p.add_argument("--every", type=int, default=1, help="every Nth recording only")
    p.add_argument("--realtime", action="store_true",
                   help="track as a live camera delivers each recording (dev_benchmark "
                   "--realtime); what the alternation is for")  # fmt: skip
    p.add_argument("--reuse-results", action="store_true",
                   help="evaluate complete results already under --out (resume)")  # fmt: skip
    args = p.parse_args(argv)
    names = [n for n, _ in args.setting]
    if len(names) < 2 or len(set(names)) != len(names):
        p.error(f"give two or more --setting with different names, got {names}")
    for name, path in args.setting:
        if not path.is_file():
            p.error(f"--setting {name}: no such file {path}")
    if args.every < 1:
        p.error(f"--every must be >= 1, got {args.every}")
    recs, _, problem = _protocol_recordings(args.recordings, None)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    recs = recs[:: args.every]
    reports = run_paired(args.setting, recs, args.out, args.model, args.device,
                         args.trust_region, args.realtime, args.reuse_results)  # fmt: skip
    for name, report in reports.items():
        ((row, entry),) = report.items()
        mean = entry["mean"]
        print(f"{name}: {mean.get('mean_joint_error_mm', float('nan')):.2f} mm, tracking "
              f"failure {mean.get('tracking_failure_pct', float('nan')):.2f}% ({row})")  # fmt: skip
    print(
        f"compare: python -m depthmocap.train.evaluation.compare_runs --config '{row}' "
        f"--base {args.out / names[0]} --new {args.out / names[1]}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
