"""The tracking loop of ``runtime-track``: stream -> :class:`~runtime.frame.Frame` (metres,
person mask) -> estimate -> result writer, with real-time pacing, overlays, a live view and
progress. Each frame is prepared once here; the estimator only reads it.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import numpy as np

from .estimator import PoseEstimator, estimate_frame, prepare_frame
from .frame import Frame
from .look_back import LookBack
from .segmentation import PersonSegmenter, SegmentationConfig
from .streams import DepthStream
from .streams.latest_frame import LatestFrameReader, timed_frames

__all__ = ["Progress", "TrackStats", "track"]


@dataclass
class TrackStats:
    """What :func:`track` did.

    Attributes:
        frames: frames estimated (all written by the end of the run).
        status_counts: estimated frames per status.
        dropped: frames skipped because a newer one arrived while the estimator was busy
            (live cameras and ``--realtime``; a file read as fast as possible skips none).
        last_index: index of the last written frame (None if none).
        wall_s: seconds spent.
        latency_ms: per written frame, milliseconds from its arrival (read from the source)
            to its pose being written.
        frame_ms: per written frame, milliseconds the system spent on it. A file: from the
            previous frame's pose written to this one's (the frame rate it is processed at;
            its mask and labels were made on the reader thread beside the previous estimate,
            and a wait for them counts). Live: from taking the frame to its pose written,
            without the wait for the camera; its mask and labels, made on the reader thread,
            are not counted.
        looked_back: (frames refitted backwards, frames whose estimate was replaced) by the
            look-back (:mod:`runtime.look_back`).

    With a look-back, frames are written up to its hold behind their estimate; ``latency_ms``
    and ``frame_ms`` run to the estimate leaving the loop, not to the held frame's writing.
    """

    frames: int = 0
    status_counts: dict[str, int] = field(
        default_factory=lambda: {"tracked": 0, "detected": 0, "lost": 0}
    )
    dropped: int = 0
    last_index: int | None = None
    wall_s: float = 0.0
    latency_ms: list[float] = field(default_factory=list)
    frame_ms: list[float] = field(default_factory=list)
    looked_back: tuple[int, int] = (0, 0)

    @property
    def fps(self) -> float:
        return self.frames / self.wall_s if self.wall_s > 0 else 0.0

    def timing(self) -> dict[str, dict[str, float] | None]:
        """``latency_ms`` and ``frame_time_ms``: mean, median, 95th percentile and maximum
        over the written frames (None before the first), for ``summary.json``."""
        return {"latency_ms": _spread(self.latency_ms), "frame_time_ms": _spread(self.frame_ms)}


def _spread(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    v = np.asarray(values)
    return {
        "mean": round(float(v.mean()), 2),
        "p50": round(float(np.percentile(v, 50)), 2),
        "p95": round(float(np.percentile(v, 95)), 2),
        "max": round(float(v.max()), 2),
    }


class Progress:
    """One updating progress line on a terminal (a plain line every few seconds otherwise)."""

    def __init__(self, total: int | None, out: TextIO | None = None, quiet: bool = False):
        self.total, self.out, self.quiet = total, out or sys.stderr, quiet
        self.tty = bool(getattr(self.out, "isatty", lambda: False)())
        self._interval = 0.2 if self.tty else 5.0
        self._shown = -math.inf
        self._fps = 0.0
        self._t_last: float | None = None
        self._width = 0
        self._latest: tuple[TrackStats, int] | None = None

    def update(self, stats: TrackStats, index: int) -> None:
        now = time.perf_counter()
        if self._t_last is not None:
            inst = 1.0 / max(now - self._t_last, 1e-6)
            self._fps = inst if self._fps == 0 else 0.9 * self._fps + 0.1 * inst
        self._t_last = now
        self._latest = (stats, index)
        if self.quiet or now - self._shown < self._interval:
            return
        self._shown = now
        self._show(stats, index)

    def _show(self, stats: TrackStats, index: int) -> None:
        c = stats.status_counts
        of = f"/{self.total}" if self.total else ""
        line = (
            f"frame {index} ({stats.frames}{of})  {self._fps:5.1f} fps  "
            f"tracked {c['tracked']}  detected {c['detected']}  lost {c['lost']}"
        )
        if stats.dropped:
            line += f"  dropped {stats.dropped}"
        if self.tty:
            self.out.write("\r" + line.ljust(self._width))
            self._width = len(line)
        else:
            self.out.write(line + "\n")
        self.out.flush()

    def close(self) -> None:
        if self.tty and self._width and not self.quiet:
            self._show(*self._latest)  # the final counts, not the last periodic ones
            self.out.write("\n")
            self.out.flush()


def track(
    stream: DepthStream,
    estimator: PoseEstimator,
    writer,
    seg_cfg: SegmentationConfig | None = None,
    device: str = "cpu",
    *,
    realtime: bool = False,
    save_overlays: bool = False,
    progress: Progress | None = None,
    stop: threading.Event | None = None,
    stats: TrackStats | None = None,
    view=None,
    pipelined: bool = True,
    look_back: int = 0,
) -> TrackStats:
    """Run the pipeline over ``stream``, writing every frame to ``writer``.

    Args:
        writer: a ResultWriter (``write_frame(index, time, status, joints, q, errors,
            observed=...)``).
        save_overlays: write each frame's overlay PNG into ``overlays/`` of the writer's
            directory.
        realtime: pace a file source to its frame rate, as a camera delivers it. A live
            camera, and a paced file, are read on their own thread and the newest frame wins
            (:class:`~runtime.streams.latest_frame.LatestFrameReader`); frames it replaced
            are counted in ``stats.dropped``.
        stop: set it to end the loop after the frame in flight (Ctrl-C handler).
        stats: filled in place (so a caller sees the counts even if the loop raises).
        pipelined: prepare frames on a reader thread beside the estimate (a file keeps every
            frame); False: read and prepare each frame on this thread, then estimate it (a
            live source is always read on its own thread).
        look_back: hold each estimate this many frames and refit doubtful ones backwards
            from the clean frame after them (:mod:`runtime.look_back`; estimators with
            ``refit_from_later``, the hybrid's); 0: write each estimate at once.
    Raises:
        whatever the stream raises (StreamError, SensorDisconnected, KeyboardInterrupt); the
        frames written before are complete.
    """
    stats = stats if stats is not None else TrackStats()
    segment = PersonSegmenter(seg_cfg or SegmentationConfig())

    def prepare(frame) -> Frame:
        return prepare_frame(estimator, frame, segment, device)

    t_begin = time.perf_counter()
    live = realtime or stream.is_live
    # Each frame is prepared (mask, forest labels) on the reader thread while the estimator
    # works on the one before. Live, the newest frame wins; a file keeps every frame.
    reader = LatestFrameReader(
        stream, pace=realtime and not stream.is_live, prepare=prepare, skip=live
    ) if pipelined or live else None  # fmt: skip
    frames = iter(reader) if reader is not None else timed_frames(stream)
    body = getattr(estimator, "body", None)
    stage = LookBack.for_estimator(estimator, look_back)
    # The processing rate counts estimates, not the held frames' writes.
    note_estimated = getattr(writer, "note_estimated", None)

    def emit(prepared: Frame, est) -> None:
        """Write (and draw, and show) one frame's final estimate."""
        writer.write_frame(
            prepared.index, prepared.time, est.status, est.joints, est.q, est.errors,
            observed=est.observed,
        )  # fmt: skip
        if view is not None:
            view.log_frame(prepared, est)
        if save_overlays:
            import cv2

            from .export.overlay import draw_overlay

            # In the writer's directory as it is now: a result is staged beside its
            # output until its first frame is written (runtime.export.results), which a
            # fixed lag delays, and a new one holds no stale overlays.
            overlay_dir = Path(writer.directory) / "overlays"
            overlay_dir.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(overlay_dir / f"{prepared.index:06d}.png"), draw_overlay(prepared, est))

    t_frame = time.perf_counter()
    try:
        for item, arrival in frames:
            if live:  # the wait for the camera is not the system's time
                t_frame = time.perf_counter()
            prepared = item if reader is not None else prepare(item)
            est = estimate_frame(estimator, prepared)
            if getattr(estimator, "body", None) is not body:  # e.g. the person's size found
                body = estimator.body
                writer.update_body(body)
            if note_estimated is not None:
                note_estimated()
            for done in [(prepared, est)] if stage is None else stage.push(prepared, est):
                emit(*done)
            t_written = time.perf_counter()
            stats.latency_ms.append((t_written - arrival) * 1e3)
            stats.frame_ms.append((t_written - t_frame) * 1e3)
            t_frame = t_written
            stats.frames += 1
            stats.status_counts[est.status] = stats.status_counts.get(est.status, 0) + 1
            stats.last_index = prepared.index
            if progress is not None:
                progress.update(stats, prepared.index)
            if stop is not None and stop.is_set():
                break
            if reader is not None:
                stats.dropped = reader.skipped
        for done in [] if stage is None else stage.flush():
            emit(*done)
    except BaseException:
        # Nothing estimated is lost: what is held is written as it stands.
        for done in [] if stage is None else stage.release():
            emit(*done)
        raise
    finally:
        if reader is not None:
            reader.close()
            stats.dropped = reader.skipped
        stats.wall_s = time.perf_counter() - t_begin
        if stage is not None:
            stats.looked_back = (stage.refits, stage.revised)
    return stats
