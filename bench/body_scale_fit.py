"""Measure the size search's systematic error (``runtime.hybrid.body_scale``) and the
correction that removes it.

    python -m depthmocap.bench.body_scale_fit \\
        --recordings data/size_tune --out out/size_fit/searches.jsonl

Each recording is tracked as ``runtime-track`` does without a body file (the population
body, the shipped hybrid settings, one thread) until the size search has found its factor,
with no correction applied. The factor the recording's own body would need is its stature
over the population body's (the recording's ``body.json``: read here for fitting only, never
at run time). One line per recording is appended to ``--out`` as it is measured, so an
interrupted run resumes where it stopped.

The correction is the median of needed over found factors: a factor, because the search's
error scales with the person (an overlap peak moved by a fixed share of the body). The
report gives the error before and after it, and the after figure also cross-validated (each
half corrected with the other half's median), so that what is printed is not the fit's own
residual. Fit on recordings you do not report: the shipped value comes from the size tuning
set (the broad protocol's spec with seed 1002 and 60 frames a take; ``docs/protocol.md``).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared.body import BodyShape

__all__ = [
    "correction_of",
    "cross_validated",
    "search_recording",
    "search_stream",
    "size_errors",
    "main",
]


def correction_of(needed: np.ndarray, found: np.ndarray) -> float:
    """Median of ``needed / found`` (N,) factors: the correction for the search's bias."""
    needed, found = np.asarray(needed, dtype=np.float64), np.asarray(found, dtype=np.float64)
    if needed.shape != found.shape or needed.size == 0:
        raise ValueError(f"need equal, non-empty arrays, got {needed.shape} and {found.shape}")
    return float(np.median(needed / found))


def size_errors(needed: np.ndarray, found: np.ndarray, stature_m: float) -> dict[str, float]:
    """Stature errors (cm) of ``found`` factors against ``needed`` ones, on a body of
    ``stature_m``: ``bias`` (mean), ``std``, ``mean_abs``, ``max_abs``."""
    e = 100.0 * stature_m * (np.asarray(found) - np.asarray(needed))
    return {
        "bias_cm": float(e.mean()),
        "std_cm": float(e.std()),
        "mean_abs_cm": float(np.abs(e).mean()),
        "max_abs_cm": float(np.abs(e).max()),
    }


def cross_validated(needed: np.ndarray, found: np.ndarray) -> np.ndarray:
    """(N,) found factors corrected with the other half's correction (even/odd entries)."""
    needed, found = np.asarray(needed), np.asarray(found)
    out = np.empty_like(found, dtype=np.float64)
    for part in (0, 1):
        mine = np.arange(len(found)) % 2 == part
        out[mine] = found[mine] * correction_of(needed[~mine], found[~mine])
    return out


def search_stream(frames: Iterable, model: Path | None = None) -> dict:
    """Track ``frames`` (DepthFrames) as ``runtime-track`` does without a body file, until
    the size search ends (or the frames do).

    Returns:
        ``found`` (the search's uncorrected factor, None if it did not end), ``frames``
        (frames read), ``curves`` ((samples, S) overlaps), ``factors`` (S,).
    """
    from depthmocap.runtime.api import Tracker

    tracker = Tracker(body=None, model=model, config={"body_scale": {"correction": 1.0}},
                      device="cpu")  # fmt: skip
    read = 0
    for frame in frames:
        tracker.track(frame)
        read += 1
        if tracker.size_search.scale is not None:
            break
    search = tracker.size_search
    return {
        "found": None if search is None else search.peak,
        "frames": read,
        "curves": [] if search is None else [c.round(5).tolist() for c in search.curves],
        "factors": [] if search is None else search.factors.round(5).tolist(),
    }


def search_recording(recording: Path, population: BodyShape, model: Path | None = None) -> dict:
    """:func:`search_stream` on a recording, with ``recording`` (its name) and ``needed``
    (its body's stature over ``population``'s) added."""
    from depthmocap.runtime.streams import open_stream

    truth = BodyShape.load(recording / "body.json")
    row = search_stream(open_stream(str(recording)), model)
    needed = float(truth.stature()) / float(population.stature())
    return {"recording": recording.name, "needed": needed, **row}


def _read_done(out: Path) -> list[dict]:
    if not out.is_file():
        return []
    rows = []
    for line in out.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:  # an interrupted last line: measured again
            break
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    from depthmocap.runtime.estimator_setup import POPULATION_BODY

    p = argparse.ArgumentParser(
        prog="python -m depthmocap.bench.body_scale_fit",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("--recordings", type=Path, required=True, help="recordings with body.json")
    p.add_argument("--out", type=Path, required=True, help="JSON lines, one per recording")
    p.add_argument("--model", type=Path, default=None, help="forest (default: shipped)")
    p.add_argument("--limit", type=int, default=None, help="only the first N recordings")
    args = p.parse_args(argv)
    if not args.recordings.is_dir():
        p.error(f"--recordings {args.recordings}: no such folder")
    recordings = sorted(r for r in args.recordings.iterdir() if (r / "body.json").is_file())
    if not recordings:
        p.error(f"--recordings {args.recordings}: no recording with a body.json")
    recordings = recordings[: args.limit]
    torch.set_num_threads(1)
    population = BodyShape.load(POPULATION_BODY)
    rows = _read_done(args.out)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("".join(json.dumps(r) + "\n" for r in rows))
    done = {r["recording"] for r in rows}
    with args.out.open("a") as f:
        for rec in recordings:
            if rec.name in done:
                continue
            try:
                row = search_recording(rec, population, args.model)
            except (ValueError, OSError) as err:  # a bad recording or model; rows so far kept
                print(f"error: {rec.name}: {err}", file=sys.stderr)
                return 2
            f.write(json.dumps(row) + "\n")
            f.flush()
            rows.append(row)
            print(f"{rec.name}: needed {row['needed']:.3f}, found {row['found']}", flush=True)
    chosen = {rec.name for rec in recordings}
    ended = [r for r in rows if r["found"] is not None and r["recording"] in chosen]
    if len(ended) < 2:
        print("error: fewer than two recordings where the search ended", file=sys.stderr)
        return 2
    needed = np.array([r["needed"] for r in ended])
    found = np.array([r["found"] for r in ended])
    stature = float(population.stature())
    corr = correction_of(needed, found)
    report = {
        "recordings": len(ended),
        "not_ended": len(recordings) - len(ended),
        "correction": corr,
        "before": size_errors(needed, found, stature),
        "after": size_errors(needed, found * corr, stature),
        "after_cross_validated": size_errors(needed, cross_validated(needed, found), stature),
    }
    args.out.with_suffix(".report.json").write_text(json.dumps(report, indent=1) + "\n")
    print(f"{len(ended)} searches ({report['not_ended']} did not end): correction {corr:.4f}")
    for key in ("before", "after", "after_cross_validated"):
        e = report[key]
        print(
            f"  {key.replace('_', ' ')}: stature bias {e['bias_cm']:+.1f} cm, std "
            f"{e['std_cm']:.1f}, mean |error| {e['mean_abs_cm']:.1f}, max {e['max_abs_cm']:.1f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
