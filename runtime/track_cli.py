"""``runtime-track``: track a person in a depth stream and write a tracking result directory.

Pipeline per frame: depth (uint16 mm) -> metres -> :func:`runtime.segmentation.segment_person`
-> the pose estimator of ``--mode`` -> :class:`runtime.export.results.ResultWriter`
(``poses.jsonl`` flushed every frame, ``motion.bvh``, ``summary.json``). A frame without a
person (empty mask, all-zero or NaN depth) is written as ``lost`` and the estimator is reset;
the run goes on.

Exit codes: 0 done, or stopped with Ctrl-C (the usual way to end a live capture; 130 if Ctrl-C
comes before the first frame, when nothing was written); 1 the camera
stopped delivering frames; 2 bad input (missing/corrupt model, unreadable source, wrong frame
size, no camera, bad options), reported as one ``error: ...`` line without a traceback. In
every case the files written so far are complete and valid up to the last finished frame.

Ctrl-C finishes the frame in flight and stops; a second Ctrl-C stops at once.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import numpy as np
import torch

from shared.body import BodyShape
from shared.camera import Intrinsics
from shared.config import (
    ConfigError,
    add_cli_args,
    config_from_args,
    config_to_dict,
    load_config,
    load_settings,
)
from shared.recording import RecordingError
from shared.skeleton import JOINT_NAMES

from .estimator import MODES, MODES_NEEDING_MODEL, PoseEstimate, PoseEstimator, make_estimator
from .forest.inference import DEFAULT_MODEL
from .segmentation import SegmentationConfig, segment_person
from .streams import (
    DepthStream,
    FrameRange,
    SensorDisconnected,
    StreamError,
    describe_sources,
    open_stream,
)

__all__ = [
    "main",
    "build_parser",
    "track",
    "TrackStats",
    "TrackError",
    "depth_to_metres",
    "DEFAULT_MODEL",
]


# Skeleton lines of the overlay images, between named joints.
_BONES = (
    ("head", "neck"),
    ("neck", "spine"),
    ("spine", "pelvis"),
    ("neck", "l_shoulder"),
    ("l_shoulder", "l_elbow"),
    ("l_elbow", "l_wrist"),
    ("neck", "r_shoulder"),
    ("r_shoulder", "r_elbow"),
    ("r_elbow", "r_wrist"),
    ("pelvis", "l_hip"),
    ("l_hip", "l_knee"),
    ("l_knee", "l_ankle"),
    ("pelvis", "r_hip"),
    ("r_hip", "r_knee"),
    ("r_knee", "r_ankle"),
)


class TrackError(ValueError):
    """Bad options or set-up for ``runtime-track`` (one line, shown as ``error: ...``)."""


def _forest_error_types() -> tuple[type[BaseException], ...]:
    try:
        from shared.forest_format import ForestFormatError
    except ImportError:  # a build without the forest format: nothing extra to catch
        return ()
    return (ForestFormatError,)


def _input_errors() -> tuple[type[BaseException], ...]:
    """Exception types that mean bad input (exit 2, one line)."""
    from .estimator import EstimatorUnavailable
    from .live_view import LiveViewError

    try:
        from .export.results import ResultDirError
    except ImportError:
        extra: tuple[type[BaseException], ...] = ()
    else:
        extra = (ResultDirError,)
    return (
        TrackError,
        StreamError,
        RecordingError,
        ConfigError,
        EstimatorUnavailable,
        LiveViewError,
        *_forest_error_types(),
        *extra,
    )


# --------------------------------------------------------------------------------------------
# Options


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="runtime-track",
        description="Track full-body motion in a depth stream; writes poses.jsonl, motion.bvh "
        "and summary.json to --output.",
    )
    p.add_argument("--input", "-i", required=True, help=f"depth source: {describe_sources()}")
    p.add_argument("--output", "-o", required=True, type=Path, help="result directory")
    p.add_argument(
        "--model",
        type=Path,
        default=DEFAULT_MODEL,
        help="forest artifact (default: models/forest.npz of the checkout)",
    )
    p.add_argument("--mode", choices=MODES, default="hybrid", help="pose estimator")
    p.add_argument("--body", type=Path, help="body file (shared.body JSON); default: average")
    p.add_argument(
        "--config",
        type=Path,
        help="YAML of the mode's settings (e.g. configs/hybrid.yaml, configs/tracker.yaml)",
    )
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto", help="torch device")
    g = p.add_argument_group("intrinsics (override the source's own)")
    g.add_argument("--width", type=int, help="image width, pixels")
    g.add_argument("--height", type=int, help="image height, pixels")
    g.add_argument("--fx", type=float, help="focal length x, pixels (default: Kinect v1)")
    g.add_argument("--fy", type=float, help="focal length y, pixels (default: fx)")
    g.add_argument("--cx", type=float, help="principal point column (default: centre)")
    g.add_argument("--cy", type=float, help="principal point row (default: centre)")
    g.add_argument("--fps", type=float, help="frame rate of an image folder (default 30)")
    r = p.add_argument_group("frames and pacing")
    r.add_argument("--start", type=int, default=0, help="first frame index")
    r.add_argument("--stop", type=int, help="stop before this frame index")
    r.add_argument(
        "--realtime",
        action="store_true",
        help="pace files to their frame rate and drop frames when behind, like a live "
        "camera (default: as fast as possible, every frame)",
    )
    o = p.add_argument_group("output")
    o.add_argument(
        "--save-overlays",
        action="store_true",
        help="write OUTPUT/overlays/NNNNNN.png: depth, part labels or mask, skeleton",
    )
    o.add_argument("--quiet", "-q", action="store_true", help="no progress line")
    o.add_argument(
        "--view",
        nargs="?",
        const="",
        metavar="FILE.rrd",
        help="live 3D view in rerun (needs rerun-sdk); with a file name, save the .rrd instead",
    )
    s = p.add_argument_group("person segmentation")
    s.add_argument("--segmentation-config", type=Path, help="YAML preset of the options below")
    add_cli_args(s, SegmentationConfig)
    return p


def intrinsics_from_args(args: argparse.Namespace) -> Intrinsics | None:
    """The intrinsics override, or None when no intrinsics option is given.

    Width and height are required; missing focal lengths are the Kinect v1's at that size,
    a missing principal point is the image centre.
    """
    given = [args.fx, args.fy, args.cx, args.cy, args.width, args.height]
    if all(v is None for v in given):
        return None
    if args.width is None or args.height is None:
        raise TrackError("intrinsics options need --width and --height")
    kinect = Intrinsics.kinect_v1(640).resized(args.width, args.height)
    fx = args.fx if args.fx is not None else kinect.fx
    intr = Intrinsics(
        args.width,
        args.height,
        fx,
        args.fy if args.fy is not None else (fx if args.fx is not None else kinect.fy),
        args.cx if args.cx is not None else (args.width - 1) / 2,
        args.cy if args.cy is not None else (args.height - 1) / 2,
    )
    try:
        intr.validate()
    except ValueError as err:
        raise TrackError(f"invalid intrinsics: {err}") from None
    return intr


def load_mode_config(path: Path | None) -> dict:
    """The mode's settings from ``--config`` (a YAML mapping, possibly extending another
    preset: :func:`shared.config.load_settings`; checked by the mode itself)."""
    if path is None:
        return {}
    try:
        return load_settings(path)
    except ConfigError as err:
        raise TrackError(str(err)) from None


def initial_pose(stream, start: int) -> np.ndarray | None:
    """Ground-truth pose of the first frame when the input has one (recordings, demo)."""
    gt = getattr(stream, "groundtruth", None)
    if gt is None and hasattr(stream, "recording") and stream.recording.has_groundtruth:
        gt = stream.recording.groundtruth()
    if not gt or "q" not in gt or len(gt["q"]) <= start:
        return None
    return np.asarray(gt["q"][start], dtype=np.float64)


def pick_device(name: str) -> str:
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise TrackError("--device cuda: no CUDA device available (use --device cpu)")
    return name


def load_body(path: Path | None) -> BodyShape:
    if path is None:
        return BodyShape.default()
    try:
        return BodyShape.load(path)
    except FileNotFoundError:
        raise TrackError(f"body file not found: {path}") from None
    except ValueError as err:
        raise TrackError(str(err)) from None


def check_model(path: Path, mode: str) -> None:
    """Fail early, before a camera is opened, on a missing or unreadable model."""
    if mode not in MODES_NEEDING_MODEL:
        return
    if not path.is_file():
        raise TrackError(
            f"model file not found: {path} (train one with `make train-forest` or pass --model)"
        )
    try:
        from shared.forest_format import load_forest
        from shared.labels import PART_NAMES
    except ImportError:  # the estimator's own loader will check it
        return
    load_forest(path, expected_classes=PART_NAMES)


# --------------------------------------------------------------------------------------------
# The tracking loop


def depth_to_metres(depth_mm: np.ndarray, device: str | torch.device = "cpu") -> torch.Tensor:
    """(H, W) depth in millimetres (uint16, or float with NaN) -> float32 metres, 0 = none."""
    depth = np.asarray(depth_mm)
    if depth.dtype.kind == "f":
        depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0)
    return torch.from_numpy(depth.astype(np.float32)).to(device) * 1e-3


@dataclass
class TrackStats:
    """What :func:`track` did.

    Attributes:
        frames: frames written.
        status_counts: written frames per status.
        dropped: frames skipped by real-time pacing.
        last_index: index of the last written frame (None if none).
        wall_s: seconds spent.
    """

    frames: int = 0
    status_counts: dict[str, int] = field(
        default_factory=lambda: {"tracked": 0, "detected": 0, "lost": 0}
    )
    dropped: int = 0
    last_index: int | None = None
    wall_s: float = 0.0

    @property
    def fps(self) -> float:
        return self.frames / self.wall_s if self.wall_s > 0 else 0.0


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


def _overlay(frame, mask: torch.Tensor, est: PoseEstimate) -> np.ndarray:
    """BGR image: depth in grey, the part labels (or the person mask) tinted, the skeleton."""
    import cv2

    from shared.labels import PART_COLORS

    depth = frame.depth_mm.astype(np.float32)
    valid = depth > 0
    lo, hi = np.percentile(depth[valid], [2, 98]) if valid.any() else (0.0, 1.0)
    grey = np.clip(255 * (1 - (depth - lo) / max(hi - lo, 1.0)), 40, 255).astype(np.uint8)
    img = cv2.cvtColor(np.where(valid, grey, 0).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    m = mask.detach().cpu().numpy().astype(bool)
    if est.labels is not None and est.labels.shape == m.shape:
        tint = PART_COLORS[est.labels][..., ::-1]
        show = est.labels > 0
    else:
        tint = np.broadcast_to(np.array([60, 60, 220], np.uint8), img.shape)
        show = m
    img[show] = (0.5 * img[show] + 0.5 * tint[show]).astype(np.uint8)
    if est.joints is not None and np.isfinite(est.joints).all():
        intr = frame.intrinsics
        z = np.maximum(est.joints[:, 2], 1e-3)
        uv = np.stack(
            [intr.fx * est.joints[:, 0] / z + intr.cx, intr.fy * est.joints[:, 1] / z + intr.cy], 1
        )
        pix = {n: tuple(int(round(c)) for c in uv[i]) for i, n in enumerate(JOINT_NAMES)}
        for a, b in _BONES:
            cv2.line(img, pix[a], pix[b], (0, 255, 0), 1, cv2.LINE_AA)
        for p, ok in zip(pix.values(), est.observed_or_all()):
            # Inferred joints (the camera does not confirm them) as open red rings.
            if ok:
                cv2.circle(img, p, 2, (0, 255, 255), -1, cv2.LINE_AA)
            else:
                cv2.circle(img, p, 3, (0, 0, 255), 1, cv2.LINE_AA)
    return img


def track(
    stream: DepthStream,
    estimator: PoseEstimator,
    writer,
    seg_cfg: SegmentationConfig | None = None,
    device: str = "cpu",
    *,
    realtime: bool = False,
    overlay_dir: Path | None = None,
    progress: Progress | None = None,
    stop: threading.Event | None = None,
    stats: TrackStats | None = None,
    view=None,
) -> TrackStats:
    """Run the pipeline over ``stream``, writing every frame to ``writer``.

    Args:
        writer: a ResultWriter (``write_frame(index, time, status, joints, q, errors,
            observed=...)``).
        realtime: pace a file source to its frame rate and drop frames when behind.
        stop: set it to end the loop after the frame in flight (Ctrl-C handler).
        stats: filled in place (so a caller sees the counts even if the loop raises).
    Raises:
        whatever the stream raises (StreamError, SensorDisconnected, KeyboardInterrupt); the
        frames written before are complete.
    """
    stats = stats if stats is not None else TrackStats()
    seg_cfg = seg_cfg or SegmentationConfig()
    t_begin = time.perf_counter()
    t_stream0: float | None = None
    t_wall0 = t_begin
    frame_dt = 1.0 / stream.fps
    if overlay_dir is not None:
        overlay_dir.mkdir(parents=True, exist_ok=True)
    try:
        for frame in stream:
            if realtime and not stream.is_live:
                if t_stream0 is None:  # the clocks start at the first frame: never dropped
                    t_stream0, t_wall0 = frame.time, time.perf_counter()
                lag = time.perf_counter() - t_wall0 - (frame.time - t_stream0)
                if lag < 0:
                    time.sleep(-lag)
                elif lag > 1.5 * frame_dt:  # a live camera would have dropped this frame
                    stats.dropped += 1
                    continue
            depth_m = depth_to_metres(frame.depth_mm, device)
            mask = segment_person(depth_m, frame.intrinsics, seg_cfg)
            if not bool(mask.any()):
                est = PoseEstimate(None, None, "lost", {})
                estimator.reset()
            else:
                est = estimator.estimate(frame, mask)
            writer.write_frame(
                frame.index, frame.time, est.status, est.joints, est.q, est.errors,
                observed=est.observed,
            )  # fmt: skip
            stats.frames += 1
            stats.status_counts[est.status] = stats.status_counts.get(est.status, 0) + 1
            stats.last_index = frame.index
            if view is not None:
                view.log_frame(frame, mask, est)
            if overlay_dir is not None:
                import cv2

                cv2.imwrite(str(overlay_dir / f"{frame.index:06d}.png"), _overlay(frame, mask, est))
            if progress is not None:
                progress.update(stats, frame.index)
            if stop is not None and stop.is_set():
                break
    finally:
        stats.wall_s = time.perf_counter() - t_begin
    return stats


@contextmanager
def _graceful_sigint(stop: threading.Event):
    """First Ctrl-C sets ``stop`` (finish the frame in flight); a second one interrupts."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


# --------------------------------------------------------------------------------------------
# Entry point


def _error(msg: str) -> int:
    print(f"error: {msg}", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return _run(args)
    except KeyboardInterrupt:  # during set-up, before any output was written
        print("interrupted", file=sys.stderr)
        return 130


def _run(args: argparse.Namespace) -> int:
    bad_input = _input_errors()
    stream = None
    try:
        seg_cfg = config_from_args(
            SegmentationConfig, args, load_config(SegmentationConfig, args.segmentation_config)
        )
        device = pick_device(args.device)
        body = load_body(args.body)
        check_model(args.model, args.mode)
        stream = open_stream(
            args.input,
            intrinsics=intrinsics_from_args(args),
            frame_range=FrameRange(args.start, args.stop),
            fps=args.fps,
        )
        try:
            mode_cfg = load_mode_config(args.config)
            if args.mode == "tracker":
                mode_cfg["initial_q"] = initial_pose(stream, args.start)
            estimator = make_estimator(
                args.mode, args.model, body, stream.intrinsics, device=device, config=mode_cfg
            )
        except bad_input:
            raise
        except ValueError as err:  # a mode's own bad-input error (its contract)
            raise TrackError(str(err)) from None
        from .export.results import ResultWriter

        view = None
        if args.view is not None:
            from .live_view import LiveView

            view = LiveView(args.view or None)
        writer = ResultWriter(
            args.output, body, stream.fps, stream.intrinsics, args.mode, stream.source
        )
    except BaseException as err:
        if stream is not None:
            stream.close()  # a camera must be released whatever went wrong
        if isinstance(err, bad_input):
            return _error(str(err))
        raise

    stats = TrackStats()
    stop = threading.Event()
    progress = Progress(stream.frame_count, quiet=args.quiet)
    code, note = 0, None
    with stream, writer:
        writer.extra.update(
            {
                "device": device,
                "model": str(args.model) if args.mode in MODES_NEEDING_MODEL else None,
                "segmentation": config_to_dict(seg_cfg),
                "realtime": args.realtime,
            }
        )
        try:
            with _graceful_sigint(stop):
                track(
                    stream,
                    estimator,
                    writer,
                    seg_cfg,
                    device,
                    realtime=args.realtime,
                    overlay_dir=args.output / "overlays" if args.save_overlays else None,
                    progress=progress,
                    stop=stop,
                    stats=stats,
                    view=view,
                )
            if stop.is_set():
                note = "interrupted"
        except KeyboardInterrupt:
            note = "interrupted"
        except SensorDisconnected as err:
            code, note = 1, f"camera disconnected: {err}"
        except bad_input as err:
            code, note = 2, f"error: {err}"
        finally:
            progress.close()
            writer.extra.update({"dropped_frames": stats.dropped, "stopped": note})
    last = "no frames" if stats.last_index is None else f"up to frame {stats.last_index}"
    if note is not None:
        print(f"{note}; results {last} are in {args.output}", file=sys.stderr)
    if not args.quiet or code:
        c = stats.status_counts
        print(
            f"{stats.frames} frames at {stats.fps:.1f} fps (tracked {c['tracked']}, detected "
            f"{c['detected']}, lost {c['lost']}"
            + (f", dropped {stats.dropped}" if stats.dropped else "")
            + f") -> {args.output}",
            file=sys.stderr,
        )
    return code


if __name__ == "__main__":
    sys.exit(main())
