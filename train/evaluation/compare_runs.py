"""Two dev_benchmark runs of the same recordings, compared the way a change is accepted.

A change is kept when it helps across motion classes, bodies and views, not because one
recording flipped: on the broad tuning set single recordings swing the pooled joint error by
up to a millimetre either way (``docs/experiments.md``). This prints, for a baseline and a
candidate run (each one or more ``dev_benchmark --out`` folders, e.g. the two halves):

- the pooled, frame-weighted figures of both;
- each recording's change in joint error weighted by its frames, so they sum to the pooled
  change: how many moved by over 1 mm either way, the three largest each way, and the sum
  without them (``trimmed``);
- the pooled change per group (motion class, view, cut, height class, from each
  recording's ``protocol.json``), and how many groups of each kind moved by over
  ``--margin`` mm either way.

    python -m depthmocap.train.evaluation.compare_runs --base OUT_A [OUT_B] \\
        --new OUT_A2 [OUT_B2]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

__all__ = [
    "GROUPS",
    "METRICS",
    "CompareError",
    "compare",
    "format_comparison",
    "load_runs",
    "pooled",
]

DEFAULT_CONFIG = "hybrid, default body"
# (report key, label) of the pooled figures.
METRICS = (
    ("mean_joint_error_mm", "joint error mm"),
    ("mean_joint_error_offset_normalized_mm", "offset-normalized mm"),
    ("precision_10cm", "precision 10 cm"),
    ("tracking_failure_pct", "tracking failure %"),
    ("system_failure_pct", "system failure %"),
    ("system_failure_observed_pct", "system failure, observed joints %"),
)
# protocol.json keys the recordings are grouped by.
GROUPS = ("motion_class", "view", "cut", "height_class")
ERROR = "mean_joint_error_mm"


class CompareError(ValueError):
    """Runs that cannot be compared (missing reports, different recordings)."""


def load_runs(outs: list[Path], config: str = DEFAULT_CONFIG) -> dict[str, dict]:
    """Every recording's entry of ``config`` in the ``report.json`` of each folder, by
    recording name, with its ``protocol.json`` (``{}`` when it has none) under
    ``"protocol"``."""
    runs: dict[str, dict] = {}
    for out in outs:
        path = Path(out) / "report.json"
        if not path.is_file():
            raise CompareError(f"{path}: no report.json (not a finished dev_benchmark --out?)")
        report = json.loads(path.read_text())
        if config not in report:
            raise CompareError(f"{path} has no configuration {config!r} ({', '.join(report)})")
        for entry in report[config]["per_recording"].values():
            name = Path(entry["recording"]).name
            if name in runs:
                raise CompareError(f"recording {name} is in more than one of {outs}")
            protocol = Path(entry["recording"]) / "protocol.json"
            spec = json.loads(protocol.read_text()) if protocol.is_file() else {}
            runs[name] = {**entry, "protocol": spec}
    if not runs:
        raise CompareError(f"no recordings in {outs}")
    return runs


def pooled(entries: list[dict], key: str) -> float:
    """The frame-weighted mean of ``key`` over ``entries`` with a value for it."""
    have = [e for e in entries if e.get(key) is not None]
    frames = sum(e["frames"] for e in have)
    return sum(e[key] * e["frames"] for e in have) / frames if frames else float("nan")


def compare(base: dict[str, dict], new: dict[str, dict], margin_mm: float = 0.5) -> dict:
    """The comparison of two :func:`load_runs` of the same recordings (module docstring)."""
    if set(base) != set(new):
        only = sorted(set(base) ^ set(new))
        raise CompareError(f"the runs hold different recordings: {', '.join(only[:5])} ...")
    names = sorted(base)
    total = sum(base[n]["frames"] for n in names)
    figures = {
        key: (pooled([base[n] for n in names], key), pooled([new[n] for n in names], key))
        for key, _ in METRICS
    }
    deltas = sorted(
        ((new[n][ERROR] - base[n][ERROR]) * base[n]["frames"] / total, n) for n in names
    )
    raw = {n: new[n][ERROR] - base[n][ERROR] for n in names}
    trimmed = sum(d for d, _ in deltas[3:-3]) if len(deltas) > 6 else float("nan")
    groups = {}
    for key in GROUPS:
        members = defaultdict(list)
        for n in names:
            value = base[n]["protocol"].get(key)
            if value is not None:
                members[str(value)].append(n)
        rows = {
            value: (
                pooled([base[n] for n in ns], ERROR),
                pooled([new[n] for n in ns], ERROR),
                len(ns),
            )
            for value, ns in sorted(members.items())
        }
        if rows:
            groups[key] = rows
    return {
        "recordings": len(names),
        "frames": total,
        "pooled": figures,
        "better": sum(d < -1.0 for d in raw.values()),
        "worse": sum(d > 1.0 for d in raw.values()),
        "largest_gains": deltas[:3],
        "largest_losses": deltas[::-1][:3],
        "change": sum(d for d, _ in deltas),
        "trimmed": trimmed,
        "groups": groups,
        "margin_mm": margin_mm,
    }


def format_comparison(c: dict) -> str:
    """The comparison as text (markdown tables)."""
    lines = [
        f"{c['recordings']} recordings, {c['frames']} frames",
        "",
        "| | base | new |",
        "|---|---|---|",
    ]
    for key, label in METRICS:
        a, b = c["pooled"][key]
        scale = 100.0 if key == "precision_10cm" else 1.0
        lines.append(f"| {label} | {a * scale:.2f} | {b * scale:.2f} |")
    lines += [
        "",
        f"joint error change {c['change']:+.2f} mm: {c['better']} recordings better by over "
        f"1 mm, {c['worse']} worse; without the three largest each way {c['trimmed']:+.2f} mm",
        "largest gains: " + ", ".join(f"{n} {d:+.2f}" for d, n in c["largest_gains"]),
        "largest losses: " + ", ".join(f"{n} {d:+.2f}" for d, n in c["largest_losses"]),
    ]
    m = c["margin_mm"]
    for key, rows in c["groups"].items():
        better = sum(b - a < -m for a, b, _ in rows.values())
        worse = sum(b - a > m for a, b, _ in rows.values())
        lines += [
            "",
            f"by {key.replace('_', ' ')}: {better} of {len(rows)} better by over {m:g} mm, "
            f"{worse} worse",
            "",
            "| group | recordings | base mm | new mm | change |",
            "|---|---|---|---|---|",
        ]
        for value, (a, b, n) in rows.items():
            lines.append(f"| {value} | {n} | {a:.2f} | {b:.2f} | {b - a:+.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.compare_runs",
        description="Compare two dev_benchmark runs of the same recordings: pooled figures, "
        "each recording's share of the change, and the change per motion class, view, cut "
        "and height class.",
    )
    parser.add_argument("--base", nargs="+", type=Path, required=True, help="--out folders")
    parser.add_argument("--new", nargs="+", type=Path, required=True, help="--out folders")
    parser.add_argument("--config", default=DEFAULT_CONFIG, help="configuration to compare")
    parser.add_argument(
        "--margin", type=float, default=0.5, help="a group's change that counts (mm)"
    )
    args = parser.parse_args(argv)
    try:
        result = compare(
            load_runs(args.base, args.config), load_runs(args.new, args.config), args.margin
        )
    except CompareError as err:
        print(f"compare_runs: {err}", file=sys.stderr)
        return 2
    print(format_comparison(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
