"""``python -m depthmocap.bench.frame_phases``: where each kind of frame's time goes, piece by
piece, in the whole hybrid as ``make bench-broad`` runs it (issue 38: the 95th percentile is
set by the frames that recover).

    python -m depthmocap.bench.frame_phases --recordings data/dev_broad --every 4

Each recording runs through :func:`bench.hybrid.benchmark_hybrid` (``runtime-track``'s own
pipelined loop) while the pieces of :meth:`HybridEstimator.estimate` listed in
:data:`PHASES` are timed on the thread that estimates (the size search's refits on its worker
thread, and half of a split refit on the helper thread, are not: what the frame waits for is).
Phases nest: the refits are inside the detector and the arm search, RANSAC and IK inside the
detector. Printed per kind of frame (:func:`bench.hybrid.frame_work`): the median frame time
and each phase's median, then the same means over that kind's frames over 50 ms. A diagnostic
for a person, never asserted; the timing wrappers cost a few microseconds a call.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from .hybrid import benchmark_hybrid, selected_recordings

__all__ = ["PHASES", "main", "phase_rows", "phase_timer", "run_phases"]

# (name, module, attribute path): the callables timed, in the table's order.
PHASES: tuple[tuple[str, str, str], ...] = (
    ("track", "depthmocap.runtime.hybrid.estimator", "HybridEstimator._fit"),
    ("arm search", "depthmocap.runtime.hybrid.arm_search", "ArmSearch.search"),
    ("detector", "depthmocap.runtime.hybrid.estimator", "HybridEstimator._run_detector"),
    ("refits", "depthmocap.runtime.hybrid.split_refits", "SplitRefits.fit_starts"),
    ("RANSAC", "depthmocap.runtime.detector.detect", "fit_bones"),
    ("IK", "depthmocap.runtime.detector.detect", "fit_pose"),
    ("size wait", "depthmocap.runtime.hybrid.body_scale", "BodyScaleSearch._read"),
    ("behind", "depthmocap.runtime.hybrid.estimator", "HybridEstimator._drop_behind"),
    ("observation", "depthmocap.runtime.frame", "Frame.observation"),
)
_ESTIMATE = ("depthmocap.runtime.hybrid.estimator", "HybridEstimator.estimate")


def _owner(module: str, path: str):
    """The object holding the attribute ``path`` names (a module or a class), and its name."""
    obj = importlib.import_module(module)
    *outer, name = path.split(".")
    for part in outer:
        obj = getattr(obj, part)
    return obj, name


@contextlib.contextmanager
def phase_timer() -> Iterator[list[dict[str, float]]]:
    """Time :data:`PHASES` within every hybrid estimate made inside the block.

    Yields:
        a list that gets one dict per estimate, in order: milliseconds per phase (summed over
        its calls on the estimating thread) and ``"estimate"``, the whole call's.
    """
    records: list[dict[str, float]] = []
    current: dict[str, float] = {}
    estimating = threading.local()
    saved = []

    def timed(name, fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            if not getattr(estimating, "on", False):
                return fn(*args, **kwargs)
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                current[name] = current.get(name, 0.0) + 1e3 * (time.perf_counter() - start)

        return wrapper

    def timed_estimate(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            current.clear()
            estimating.on = True
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                estimating.on = False
                records.append({**current, "estimate": 1e3 * (time.perf_counter() - start)})

        return wrapper

    try:
        for name, module, path in PHASES:
            owner, attr = _owner(module, path)
            saved.append((owner, attr, owner.__dict__[attr]))
            setattr(owner, attr, timed(name, getattr(owner, attr)))
        owner, attr = _owner(*_ESTIMATE)
        saved.append((owner, attr, owner.__dict__[attr]))
        setattr(owner, attr, timed_estimate(getattr(owner, attr)))
        yield records
    finally:
        for owner, attr, original in reversed(saved):
            setattr(owner, attr, original)


def run_phases(recordings: list[Path], device: str = "cpu") -> dict[str, np.ndarray]:
    """Each recording through ``benchmark_hybrid`` with :func:`phase_timer` on.

    Returns:
        ``ms`` (F,) frame times, ``work`` (F,) what each frame ran, ``phases`` (F, P + 1)
        milliseconds of each of :data:`PHASES` and of the whole estimate (last column).
    """
    ms, work, rows = [], [], []
    with phase_timer() as records:
        for rec in recordings:
            first = len(records)
            run = benchmark_hybrid(str(rec), device, None)
            # The untimed warm-up frames were estimated first, by another estimator.
            if len(records) - first < len(run["ms"]):
                raise RuntimeError(f"{rec}: fewer hybrid estimates than frames timed")
            timed = records[len(records) - len(run["ms"]) :]
            ms.append(run["ms"])
            work.append(run["work"])
            rows += timed
    names = [p[0] for p in PHASES] + ["estimate"]
    phases = np.array([[r.get(n, 0.0) for n in names] for r in rows]).reshape(-1, len(names))
    return {"ms": np.concatenate(ms), "work": np.concatenate(work), "phases": phases}


def phase_rows(ms: np.ndarray, work: np.ndarray, phases: np.ndarray) -> list[str]:
    """The table: one line per kind of frame (most frames first) with its count, median
    frame time and each phase's median, and under it the means over its frames over 50 ms."""
    names = [p[0] for p in PHASES] + ["estimate"]
    head = f"{'kind of frame':<36s} {'frames':>6s} {'frame':>8s} " + " ".join(
        f"{n[:11]:>11s}" for n in names
    )
    lines = [head]

    def line(label: str, count: int, frame: float, each: np.ndarray) -> str:
        return f"{label:<36s} {count:6d} {frame:8.1f} " + " ".join(f"{v:11.1f}" for v in each)

    kinds = sorted(set(work.tolist()), key=lambda k: -int((work == k).sum()))
    for kind in kinds:
        mine = work == kind
        lines.append(
            line(kind, int(mine.sum()), np.median(ms[mine]), np.median(phases[mine], axis=0))
        )
        slow = mine & (ms > 50.0)
        if slow.any():
            lines.append(
                line("  over 50 ms (means)", int(slow.sum()), ms[slow].mean(),
                     phases[slow].mean(axis=0))
            )  # fmt: skip
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.bench.frame_phases", description=__doc__.splitlines()[0]
    )
    p.add_argument("--recordings", type=Path, required=True, help="a folder of recordings")
    p.add_argument("--every", type=int, default=1, help="every N-th recording")
    p.add_argument("--start", type=int, default=0, help="from the N-th recording")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    p.add_argument("--threads", type=int, default=1, help="torch threads (bench-broad: 1)")
    args = p.parse_args(argv)
    recs = selected_recordings(p, args.recordings, args.every, args.start)
    torch.set_num_threads(args.threads)
    r = run_phases(recs, args.device)
    ms = r["ms"]
    print(
        f"== {len(recs)} recordings, {len(ms)} frames: median {np.median(ms):.1f} ms, 95th "
        f"percentile {np.percentile(ms, 95):.1f} ms, {int((ms > 50).sum())} frames over 50 ms =="
    )
    print("milliseconds on the estimating thread; refits, RANSAC and IK are inside detector / arm")
    for line in phase_rows(ms, r["work"], r["phases"]):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
