"""The whole hybrid, frame by frame, on one device: what ``runtime-bench --device cuda`` is
for, and ``make bench``'s end-to-end figure (issue 38). Each frame goes through
``runtime-track``'s own loop (:func:`runtime.track_loop.track`: depth to metres, the person's
mask and the forest's labels on the reader thread, then tracker, arm search, detections),
exactly as ``runtime-track`` runs a file, without the file outputs. A frame's time is the
interval between two poses: the rate a recording is processed at.

Frame rate is reported as the median frame time over all frames (pooled over recordings),
with the 95th percentile, because recovery (the arm search, detections, the one-off size
search) makes a few frames far slower than the rest, and a live stream falls behind on those.
The latency figure replays the measured frame times against a camera delivering
:data:`CAMERA_FPS` frames/s where the newest frame wins (what ``runtime-track --realtime``
does): it is the mean time from a frame's arrival to its pose, and the share of frames the
estimator never saw. It is a replay of measured times, not a live run: on skipped frames the
real tracker would see larger motion.
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from depthmocap.runtime.api import Tracker
from depthmocap.runtime.estimator import make_estimator
from depthmocap.runtime.estimator_setup import load_body
from depthmocap.runtime.look_back import file_hold
from depthmocap.runtime.streams import FrameRange, open_stream
from depthmocap.runtime.track_loop import track

__all__ = [
    "CAMERA_FPS",
    "STARTUP_FRAMES",
    "after_startup_rows",
    "benchmark_hybrid",
    "frame_work",
    "hybrid_rows",
    "paced_latency",
    "recordings_in",
    "recordings_rows",
    "selected_recordings",
    "spread_rows",
    "work_rows",
]

# The camera rate the latency replay assumes (Kinect v1, v2, Xtion: 30 frames/s).
CAMERA_FPS = 30.0
# A stream's first second: without a body file the size search samples every 3rd of its first
# ~24 tracked frames, and the first frame is a detection. The broad protocol's clips are 3 s
# long, so this start-up is a third of their frames but a moment of a session of minutes.
STARTUP_FRAMES = 30


class _FrameLog:
    """The result writer of a timed run: each frame's status and what it ran, no files."""

    def __init__(self, estimator) -> None:
        self.estimator = estimator
        self.statuses: list[str] = []
        self.work: list[str] = []
        self._samples = self._size_samples()
        # Whether each estimate took a size sample, oldest first: a look-back writes a frame
        # after later ones were estimated, and every estimate is written once, in order.
        self._sized: deque[bool] = deque()

    def note_estimated(self) -> None:
        """Called by the track loop right after each estimate."""
        samples = self._size_samples()
        self._sized.append(samples > self._samples)
        self._samples = samples

    def _size_samples(self) -> int:
        search = getattr(self.estimator, "scale_search", None)
        return 0 if search is None else search.samples

    def write_frame(self, index, time, status, joints, q, errors, observed=None) -> None:
        self.statuses.append(status)
        sized = self._sized.popleft() if self._sized else False
        self.work.append(frame_work(status, errors or {}, sized))

    def update_body(self, body) -> None:
        pass


def benchmark_hybrid(
    source: str,
    device: str,
    frames: int | None,
    warmup: int = 3,
    pipelined: bool = True,
    config: str | Path | Mapping | None = None,
) -> dict:
    """Per-frame wall times of the shipped hybrid on the first ``frames`` frames of ``source``
    (any ``open_stream`` name; None: all of them), after ``warmup`` untimed frames of the
    same source, run by ``runtime-track``'s own loop (:func:`runtime.track_loop.track`),
    with its look-back for a file.
    ``config``: settings laid over the shipped preset (``runtime-track --config``).

    ``pipelined``: as ``runtime-track`` runs a file, each frame's mask and forest labels
    made on the reader thread beside the previous frame's estimate, a frame's time the
    interval between two poses; False: one frame after the other on one thread.

    Returns:
        ``ms`` (F,) per-frame milliseconds, ``statuses`` (F,) str, ``work`` (F,) str (what
        each frame ran, :func:`frame_work`), ``device``.
    """
    tracker = Tracker(device=device, config=config)  # default body, as runtime-track
    with open_stream(source) as stream:
        for frame in itertools.islice(stream, warmup):  # allocator growth, kernel caches
            tracker.track(frame)
        intrinsics = stream.intrinsics
    estimator = make_estimator(
        tracker.mode, tracker.model, load_body(None), intrinsics, tracker.device,
        tracker.settings,
    )  # fmt: skip
    log = _FrameLog(estimator)
    # A file as runtime-track tracks it: held for the hybrid's look-back (a frame's time
    # includes the refits it started).
    with open_stream(source, frame_range=FrameRange(0, frames)) as stream:
        stats = track(
            stream, estimator, log, tracker.segmentation, tracker.device, pipelined=pipelined,
            look_back=file_hold(estimator),
        )  # fmt: skip
    return {
        "ms": np.asarray(stats.frame_ms),
        "statuses": np.asarray(log.statuses),
        "work": np.asarray(log.work),
        "device": tracker.device,
    }


def frame_work(status: str, errors: dict, sized: bool) -> str:
    """What a frame ran beyond its own track, from its estimate: "size search" (the frame was
    refitted at every candidate size), "detector" (the detector ran: the frame was detected,
    its track was kept over the detection after failing or being rechecked, or it was lost
    after it), "arm search" (arm refits were tried); joined by " + ", or "track only"; "no
    person" for a lost frame where nothing ran."""
    ran = []
    if sized:
        ran.append("size search")
    # Keys only the detector's path writes: its labelled pixels (a detection, found or not),
    # a track kept over it or confirmed by it, a fit too poor to report after it; and a
    # look-back's refit, which replaced the errors of a frame the detector was asked about.
    asked = (
        "labelled_pixels", "kept_over_detector", "rechecked", "confirmed_by_detector",
        "unsupported", "looked_back",
    )  # fmt: skip
    if (
        status == "detected"
        or any(k in errors for k in asked)
        or any(k.startswith("tracker_") for k in errors)
    ):
        ran.append("detector")
    if "arms_searched" in errors:
        ran.append("arm search")
    if not ran and status == "lost":
        return "no person"  # the frame held nobody: nothing ran
    return " + ".join(ran) or "track only"


def work_rows(ms: np.ndarray, work: np.ndarray) -> list[tuple[str, float, str]]:
    """One row per kind of frame (:func:`frame_work`), most time first: its median time, its
    share of the frames and of the time, and how many of its frames took over 50 ms."""
    total = float(ms.sum())
    rows = []
    for kind in sorted(set(work.tolist()), key=lambda k: -float(ms[work == k].sum())):
        mine = ms[work == kind]
        rows.append(
            (
                f"  {kind}",
                float(np.median(mine)),
                f"median; {100 * len(mine) / len(ms):.1f}% of frames, "
                f"{100 * float(mine.sum()) / total:.0f}% of the time, "
                f"{int((mine > 50).sum())} over 50 ms",
            )
        )
    return rows


def paced_latency(ms: np.ndarray, fps: float = CAMERA_FPS) -> tuple[float, float]:
    """Replay frame times ``ms`` (F,) against a camera at ``fps`` whose newest frame wins.

    Frame i arrives at i / fps. When the estimator is free it takes the newest frame that has
    arrived (waiting for the next one if none is new) and is busy for that frame's measured
    time; the frames in between are skipped.

    Returns:
        mean latency (ms, arrival to pose) of the frames taken, and the share of frames skipped.
    """
    period = 1e3 / fps
    n = len(ms)
    if n == 0:
        return float("nan"), 0.0
    now, i, taken, latency = 0.0, 0, 0, []
    while i < n:
        newest = max(i, min(n - 1, int(np.floor(now / period + 1e-9))))
        arrival = newest * period
        now = max(now, arrival) + float(ms[newest])
        latency.append(now - arrival)
        taken += 1
        i = newest + 1
    return float(np.mean(latency)), 1.0 - taken / n


def recordings_in(folder: Path) -> list[Path]:
    """The recordings (folders with a ``meta.json``) in ``folder``, sorted; ``folder``
    itself if it is one."""

    def is_recording(p: Path) -> bool:
        return (p / "meta.json").is_file()

    if is_recording(folder):
        return [folder]
    return sorted(p for p in folder.iterdir() if p.is_dir() and is_recording(p))


def selected_recordings(parser, folder: Path, every: int, start: int) -> list[Path]:
    """Every ``every``-th recording in ``folder`` from the ``start``-th, for a command line
    (``--recordings``, ``--every``, ``--start``): a wrong value is the parser's error."""
    if every < 1 or start < 0:
        parser.error(f"--every must be >= 1 and --start >= 0, got {every} and {start}")
    if not folder.is_dir():
        parser.error(f"--recordings {folder}: no such folder")
    recs = recordings_in(folder)[start::every]
    if not recs:
        parser.error(f"no recordings in {folder}")
    return recs


def spread_rows(ms: np.ndarray, label: str, note: str) -> list[tuple[str, float, str]]:
    """Median, 95th percentile, mean, replayed latency and slowest of frame times ``ms``."""
    median = float(np.median(ms))
    latency, skipped = paced_latency(ms)
    return [
        (f"median frame ({label})", median, f"= {1000.0 / median:.1f} frames/s; {note}"),
        ("95th-percentile frame", float(np.percentile(ms, 95)), "target <= 50 ms"),
        ("mean frame", float(np.mean(ms)), f"= {1000.0 / float(np.mean(ms)):.1f} frames/s"),
        (
            f"mean latency, camera at {CAMERA_FPS:.0f} frames/s (replay)",
            latency,
            f"newest frame wins: {100 * skipped:.0f}% of frames skipped",
        ),
        ("slowest frame", float(ms.max()), ""),
    ]


def _status_note(statuses: np.ndarray) -> str:
    counts = {s: int((statuses == s).sum()) for s in ("tracked", "detected", "lost")}
    return ", ".join(f"{k} {v}" for k, v in counts.items())


def hybrid_rows(source: str, device: str, frames: int) -> list[tuple[str, float, str]]:
    """Rows for ``runtime-bench``: median, 95th percentile and mean frame time, the replayed
    latency, and the statuses."""
    r = benchmark_hybrid(source, device, frames)
    return spread_rows(r["ms"], f"{len(r['ms'])} frames", _status_note(r["statuses"]))


def after_startup_rows(runs: list[np.ndarray], startup: int) -> list[tuple[str, float, str]]:
    """The median and 95th percentile of the frames after each run's first ``startup``
    (runs: per recording, (F,) frame times); none when no run is longer."""
    later = [ms[startup:] for ms in runs]
    ms = np.concatenate(later) if later else np.zeros(0)
    if ms.size == 0:
        return []
    note = (
        f"{ms.size} frames after each recording's first {startup}: the size search and the "
        "first detection over, what a long stream sees"
    )
    return [
        ("median frame after the first second", float(np.median(ms)), note),
        ("95th-percentile frame after the first second", float(np.percentile(ms, 95)), ""),
    ]


def recordings_rows(
    folder: Path, device: str, startup: int = STARTUP_FRAMES
) -> list[tuple[str, float, str]]:
    """The hybrid end to end on every recording in ``folder`` (a fresh tracker each, as a
    ``runtime-track`` run): pooled figures first (and those after each recording's first
    ``startup`` frames), then each recording's median."""
    recs = recordings_in(folder)
    if not recs:
        return []
    runs = [benchmark_hybrid(str(rec), device, None) for rec in recs]
    ms = np.concatenate([r["ms"] for r in runs])
    statuses = np.concatenate([r["statuses"] for r in runs])
    rows = spread_rows(ms, f"{len(recs)} recordings, {len(ms)} frames", _status_note(statuses))
    rows += after_startup_rows([r["ms"] for r in runs], startup)
    rows += work_rows(ms, np.concatenate([r["work"] for r in runs]))
    for rec, r in zip(recs, runs, strict=True):
        median = float(np.median(r["ms"]))
        rows.append(
            (
                f"  {rec.name[:41]}",
                median,
                f"median, {1000.0 / median:.1f} frames/s; p95 {np.percentile(r['ms'], 95):.0f} ms",
            )
        )
    return rows
