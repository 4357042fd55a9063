"""``python -m depthmocap.bench.hybrid_ab``: hybrid settings timed against each other, the fair
way on a host whose speed drifts.

Two ``make bench-broad`` runs one after the other on these machines differ by 10-30% from the
host alone, more than most changes. Here every recording is run with each setting in turn
within one process, the order reversed on every other recording, so drift falls on all
settings alike; the figures are pooled over recordings as ``make bench-broad`` pools them
(:mod:`bench.hybrid`), with each setting's ratio to the first.

    python -m depthmocap.bench.hybrid_ab --recordings data/dev_broad --every 4 \\
        --setting shipped= --setting no_resets=off.yaml

A setting is ``NAME=FILE``: ``FILE`` a settings file laid over the shipped preset (as
``runtime-track --config``), empty for the shipped preset itself.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from .hybrid import benchmark_hybrid, selected_recordings, spread_rows, work_rows

__all__ = ["ab_rows", "benchmark_settings", "main", "parse_setting"]


def parse_setting(text: str) -> tuple[str, Path | None]:
    """``NAME=FILE`` -> (name, file or None for the shipped preset)."""
    name, sep, path = text.partition("=")
    if not sep or not name:
        raise ValueError(f"--setting {text!r}: expected NAME=FILE (FILE empty: the shipped preset)")
    return name, Path(path) if path else None


def benchmark_settings(
    recordings: list[Path],
    settings: Mapping[str, str | Path | Mapping | None],
    device: str = "cpu",
    frames: int | None = None,
) -> dict[str, dict[str, np.ndarray]]:
    """Each recording run with every setting, the order reversed on every other recording.

    Returns:
        per setting name: ``ms`` (F,) frame times, ``work`` (F,) what each frame ran and
        ``statuses`` (F,), concatenated over the recordings in their order, and ``order``
        (R,) the position the setting ran at on each recording (0 = first).
    """
    names = list(settings)
    runs: dict[str, list[dict]] = {n: [] for n in names}
    order: dict[str, list[int]] = {n: [] for n in names}
    for i, rec in enumerate(recordings):
        turn = names if i % 2 == 0 else names[::-1]
        for k, name in enumerate(turn):
            runs[name].append(benchmark_hybrid(str(rec), device, frames, config=settings[name]))
            order[name].append(k)
    return {
        n: {
            "ms": np.concatenate([r["ms"] for r in runs[n]]),
            "work": np.concatenate([r["work"] for r in runs[n]]),
            "statuses": np.concatenate([r["statuses"] for r in runs[n]]),
            "order": np.asarray(order[n]),
        }
        for n in names
    }


_STATISTICS = (
    ("median", lambda ms: float(np.median(ms))),
    ("95th percentile", lambda ms: float(np.percentile(ms, 95))),
    ("mean", lambda ms: float(np.mean(ms))),
)


def ab_rows(results: Mapping[str, Mapping[str, np.ndarray]]) -> list[tuple[str, float, str]]:
    """Rows per setting (its spread and kinds of frames, :mod:`bench.hybrid`), the median,
    95th percentile and mean of each setting after the first with their ratio to the first's."""
    names = list(results)
    base = results[names[0]]["ms"]
    rows = []
    for name in names:
        ms, work = results[name]["ms"], results[name]["work"]
        rows.append((f"[{name}]", float(np.median(ms)), f"median of {len(ms)} frames"))
        spread = spread_rows(ms, name, "")
        if name != names[0]:
            for stat, of in _STATISTICS:
                value, ref = of(ms), of(base)
                spread.append((f"{stat} against {names[0]}", value, f"{value / ref:.3f} of it"))
        rows += spread + work_rows(ms, work)
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.bench.hybrid_ab", description=__doc__.splitlines()[0]
    )
    p.add_argument("--recordings", type=Path, required=True, help="a folder of recordings")
    p.add_argument("--setting", action="append", default=[], help="NAME=FILE, two or more")
    p.add_argument("--every", type=int, default=1, help="every N-th recording")
    p.add_argument("--start", type=int, default=0, help="from the N-th recording")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    p.add_argument("--threads", type=int, default=1, help="torch threads (bench-broad: 1)")
    args = p.parse_args(argv)
    try:
        settings = dict(parse_setting(s) for s in args.setting)
    except ValueError as err:
        p.error(str(err))
    if len(settings) < 2:
        p.error("give two or more --setting NAME=FILE (FILE empty: the shipped preset)")
    missing = [str(f) for f in settings.values() if f is not None and not f.is_file()]
    if missing:
        p.error(f"no such settings file: {', '.join(missing)}")
    recs = selected_recordings(p, args.recordings, args.every, args.start)
    torch.set_num_threads(args.threads)
    results = benchmark_settings(recs, settings, args.device)
    print(f"== {len(recs)} recordings, each setting in turn, order alternated ==")
    for what, ms, note in ab_rows(results):
        print(f"  {what:<45s} {ms:9.3f} ms  {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
