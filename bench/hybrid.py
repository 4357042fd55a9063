"""The whole hybrid, frame by frame, on one device: what ``runtime-bench --device cuda`` is
for (issue 38). Each frame goes through :class:`runtime.api.Tracker` (depth to metres, the
person's mask, forest, tracker, arm search, detections), exactly as ``runtime-track`` runs it,
without the file outputs. A GPU session runs it once and records the device and figures.
"""

from __future__ import annotations

import itertools

import numpy as np
from depthmocap.runtime.api import Tracker
from depthmocap.runtime.streams import open_stream

from .timing import wall_ms

__all__ = ["benchmark_hybrid", "hybrid_rows"]


def benchmark_hybrid(source: str, device: str, frames: int, warmup: int = 3) -> dict:
    """Per-frame wall times of the shipped hybrid on the first ``frames`` frames of ``source``
    (any ``open_stream`` name), after ``warmup`` untimed frames of the same source.

    Returns:
        ``ms`` (F,) per-frame milliseconds, ``statuses`` (F,) str, ``device``.
    """
    tracker = Tracker(device=device)
    with open_stream(source) as stream:
        for frame in itertools.islice(stream, warmup):  # allocator growth, kernel caches
            tracker.track(frame)
    tracker.reset()
    times, statuses = [], []
    with open_stream(source) as stream:
        for frame in itertools.islice(stream, frames):
            times.append(wall_ms(lambda f=frame: statuses.append(tracker.track(f).status), device))
    return {"ms": np.asarray(times), "statuses": np.asarray(statuses), "device": tracker.device}


def hybrid_rows(source: str, device: str, frames: int) -> list[tuple[str, float, str]]:
    """Rows for ``runtime-bench``: median and 95th-percentile frame time, and the statuses."""
    r = benchmark_hybrid(source, device, frames)
    ms = r["ms"]
    counts = {s: int((r["statuses"] == s).sum()) for s in ("tracked", "detected", "lost")}
    note = ", ".join(f"{k} {v}" for k, v in counts.items())
    return [
        (f"median frame ({len(ms)} frames)", float(np.median(ms)),
         f"= {1000.0 / float(np.median(ms)):.1f} frames/s; {note}"),
        ("95th-percentile frame", float(np.percentile(ms, 95)), "target <= 50 ms"),
        ("slowest frame", float(ms.max()), ""),
    ]  # fmt: skip
