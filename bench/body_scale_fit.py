"""Measure the size search's systematic error (``runtime.hybrid.body_scale``) and the
correction that removes it, and calibrate the stature read off the silhouette
(``runtime.hybrid.stature_extent``, the search's ``extent_check``).

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

The same tracking collects the silhouette's extent on the first upright frames (the search's
``extent_frames``; the check itself never acts here) and goes on until it has them. Their
median over the stature of the body the search found, medianed over the recordings, is
``body_scale.extent_ratio``; the report gives its spread and how far the sizes it gives fall
from the search's own (``extent_check`` is the 99th percentile of that on recordings the
search sizes right), and the same ratio over the true stature with the stature errors of the
sizes it gives (cross-validated like the correction).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared.body import BodyShape

__all__ = [
    "correction_of",
    "extent_figures",
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


def extent_figures(rows: Sequence[dict], stature_m: float, frames: int) -> dict | None:
    """The extent calibration from measured ``rows`` (``needed``, ``found``, ``extents``) on
    a population body of ``stature_m``, over the recordings with ``frames`` extents.

    ``ratio`` (``body_scale.extent_ratio``) is the median of each recording's median extent
    over the stature of the body the search found, with its 10th and 90th percentiles;
    ``disagreement`` gives the 95th and 99th percentiles and the maximum of
    ``|extent size / found - 1|`` with it (``body_scale.extent_check`` is the 99th), and
    ``size_gap_cross_validated`` its mean with each half of the recordings sized by the other
    half's ratio. ``stature_ratio`` is the same median over the true stature, and
    ``stature_errors_cross_validated`` the stature errors of the sizes it gives (halves
    crossed). None with fewer than two recordings."""
    used = [r for r in rows if len(r.get("extents") or ()) >= frames and r["found"] is not None]
    if len(used) < 2:
        return None
    needed = np.array([r["needed"] for r in used])
    found = np.array([r["found"] for r in used])
    extent = np.array([float(np.median(r["extents"][:frames])) for r in used])
    halves = [np.arange(len(used)) % 2 == part for part in (0, 1)]

    def crossed(share: np.ndarray) -> np.ndarray:  # each half sized with the other's median
        out = np.empty_like(extent)
        for mine in halves:
            out[mine] = extent[mine] / float(np.median(share[~mine])) / stature_m
        return out

    of_found = extent / (found * stature_m)  # each recording's extent over the search's body
    of_true = extent / (needed * stature_m)  # ... and over its true stature
    ratio = float(np.median(of_found))
    gap = np.abs(extent / ratio / stature_m / found - 1.0)
    return {
        "recordings": len(used),
        "ratio": ratio,
        "ratio_p10_p90": np.percentile(of_found, [10, 90]).tolist(),
        "disagreement": dict(zip(("p95", "p99", "max"), [*np.percentile(gap, [95, 99]).tolist(),
                                                         float(gap.max())])),
        "size_gap_cross_validated": float(np.mean(np.abs(crossed(of_found) / found - 1.0))),
        "stature_ratio": float(np.median(of_true)),
        "stature_errors_cross_validated": size_errors(needed, crossed(of_true), stature_m),
    }  # fmt: skip


def search_stream(frames: Iterable, model: Path | None = None) -> dict:
    """Track ``frames`` (DepthFrames) as ``runtime-track`` does without a body file, until
    the size search ends (or the frames do).

    Returns:
        ``found`` (the search's uncorrected factor, None if it did not end), ``frames``
        (frames read), ``curves`` ((samples, G * S) overlaps, girth-major; None where a
        girth was not refitted), ``factors`` (S,), ``girths`` (G,), ``girth`` (the one
        found, None if the search did not end), ``extents``
        (metres, the upright frames' extents the search collected: ``extent_frames`` of them
        unless the frames ran out first).
    """
    from depthmocap.runtime.api import Tracker

    # An infinite tolerance: the extents are collected and never replace the size.
    config = {"body_scale": {"correction": 1.0, "extent_check": math.inf, "extent_sizes": False}}
    tracker = Tracker(body=None, model=model, config=config, device="cpu")
    read = 0
    for frame in frames:
        tracker.track(frame)
        read += 1
        if tracker.size_search is not None and not tracker.size_search.searching:
            break
    search = tracker.size_search
    return {
        "found": None if search is None else search.peak,
        "frames": read,
        "curves": [] if search is None else [_json_curve(c) for c in search.curves],
        "factors": [] if search is None else search.factors.round(5).tolist(),
        "girths": [] if search is None else search.girths.round(5).tolist(),
        "girth": None if search is None or search.scale is None else search.girth,
        "extents": [] if search is None else [round(e, 5) for e in search.extents],
    }


def _json_curve(curve: np.ndarray) -> list[float | None]:
    """A sample's overlaps (G * S,) for JSON: rounded, None where not refitted (NaN)."""
    return [round(float(v), 5) if np.isfinite(v) else None for v in curve]


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
    from depthmocap.runtime.hybrid.body_scale import BodyScaleConfig

    chosen_rows = [r for r in rows if r["recording"] in chosen]
    report["extent"] = extent_figures(chosen_rows, stature, BodyScaleConfig().extent_frames)
    args.out.with_suffix(".report.json").write_text(json.dumps(report, indent=1) + "\n")
    print(f"{len(ended)} searches ({report['not_ended']} did not end): correction {corr:.4f}")
    for key in ("before", "after", "after_cross_validated"):
        _print_errors(key.replace("_", " "), report[key])
    ext = report["extent"]
    if ext is None:
        print("extent: fewer than two recordings with enough upright frames")
    else:
        lo, hi = ext["ratio_p10_p90"]
        gap = ext["disagreement"]
        print(f"extent on {ext['recordings']} recordings: {ext['ratio']:.4f} of the search's "
              f"body (10-90%: {lo:.3f}-{hi:.3f}); |extent size / search - 1| 95% "
              f"{gap['p95']:.3f}, 99% {gap['p99']:.3f}, max {gap['max']:.3f}, mean "
              f"{ext['size_gap_cross_validated']:.3f} cross-validated")  # fmt: skip
        print(f"extent over the true stature: {ext['stature_ratio']:.4f}")
        _print_errors("its statures, cross-validated", ext["stature_errors_cross_validated"])
    return 0


def _print_errors(label: str, e: dict) -> None:
    print(
        f"  {label}: stature bias {e['bias_cm']:+.1f} cm, std {e['std_cm']:.1f}, "
        f"mean |error| {e['mean_abs_cm']:.1f}, max {e['max_abs_cm']:.1f}"
    )


if __name__ == "__main__":
    sys.exit(main())
