"""The figures of dev_benchmark runs per group of recordings, averaged over runs.

The headline of the broad protocol is the mean of three runs (trust regions 0.18, 0.2 and
0.22 rad), and issue 37 asks for it per motion class too. ``dev_benchmark`` prints each run's
per-class table separately and without the failure over observed joints; this pools each
group's recordings frame-weighted within a run (all ``--out`` folders together, e.g. the two
halves), then averages the runs:

    python -m depthmocap.train.evaluation.group_table OUT_A OUT_B \\
        --configs "hybrid, default body @ 0.18 rad" "hybrid, default body @ 0.2 rad" \\
        "hybrid, default body @ 0.22 rad" --group motion_class
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import defaultdict
from pathlib import Path

from .compare_runs import GROUPS, METRICS, CompareError, load_runs, pooled

__all__ = ["format_group_table", "group_figures"]


def group_figures(runs: list[dict[str, dict]], group: str) -> dict[str, dict]:
    """Per value of the recordings' ``protocol.json`` key ``group``: ``recordings``,
    ``frames`` (of one run) and each :data:`~.compare_runs.METRICS` key, pooled over the
    group's recordings within each of ``runs`` (:func:`~.compare_runs.load_runs` results of
    the same recordings), then averaged over the runs (NaN where no run has it). An
    ``"all"`` row pools every recording."""
    names = sorted(runs[0])
    if any(sorted(r) != names for r in runs):
        raise CompareError("the runs hold different recordings")
    members: dict[str, list[str]] = defaultdict(list)
    for n in names:
        value = runs[0][n]["protocol"].get(group)
        if value is not None:
            members[str(value)].append(n)
    members = dict(sorted(members.items()))
    members["all"] = names
    table = {}
    for value, ns in members.items():
        row = {"recordings": len(ns), "frames": sum(runs[0][n]["frames"] for n in ns)}
        for key, _ in METRICS:
            per_run = [pooled([r[n] for n in ns], key) for r in runs]
            have = [v for v in per_run if not math.isnan(v)]
            row[key] = sum(have) / len(have) if have else math.nan
        table[value] = row
    return table


def format_group_table(table: dict[str, dict], group: str) -> str:
    """A :func:`group_figures` table as markdown."""
    head = " | ".join(label for _, label in METRICS)
    lines = [f"| {group.replace('_', ' ')} (recordings, frames) | {head} |",
             "|---|" + "---|" * len(METRICS)]  # fmt: skip
    for value, row in table.items():
        cells = [
            f"{100 * row[key]:.1f}" if key == "precision_10cm" else f"{row[key]:.1f}"
            for key, _ in METRICS
        ]
        name = f"**{value}**" if value == "all" else value
        lines.append(
            f"| {name} ({row['recordings']}, {row['frames']}) | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.group_table",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("outs", nargs="+", type=Path, help="dev_benchmark --out folders")
    p.add_argument(
        "--configs", nargs="+", required=True, help="runs to average (configuration names)"
    )
    p.add_argument("--group", default="motion_class", choices=GROUPS, help="protocol.json key")
    args = p.parse_args(argv)
    try:
        runs = [load_runs(args.outs, config) for config in args.configs]
        table = group_figures(runs, args.group)
    except CompareError as err:
        print(f"group_table: {err}", file=sys.stderr)
        return 2
    print(format_group_table(table, args.group))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
