"""``runtime-track``: track a person in a depth stream and write a tracking result directory.

Pipeline per frame: depth (uint16 mm) -> metres -> :func:`runtime.segmentation.segment_person`
-> the pose estimator of ``--mode`` -> :class:`runtime.export.results.ResultWriter`
(``poses.jsonl`` flushed every frame, ``motion.bvh``, ``summary.json``), a file's frames
smoothed over a centred window and so written two frames late (``--fixed-lag``,
:mod:`runtime.export.fixed_lag`). A frame without a
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
import dataclasses
import sys
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import (
    ConfigError,
    add_cli_args,
    config_from_args,
    config_to_dict,
    load_config,
)
from depthmocap.shared.recording import RecordingError

from .cli_common import (
    add_frame_range_args,
    add_source_args,
    check_plausible_intrinsics,
    report_error,
)
from .estimator import MODES, MODES_NEEDING_MODEL, make_estimator
from .estimator_setup import (
    TrackError,
    check_model,
    load_body,
    load_mode_config,
    pick_device,
    settings_for_body,
)
from .export.fixed_lag import FILE_FIXED_LAG, MAX_FIXED_LAG, FixedLagSmoother
from .export.live import add_live_args, live_output_from_args
from .forest.inference import DEFAULT_MODEL
from .look_back import MAX_LOOK_BACK, file_hold
from .presets import DEFAULT_PRESET, PRESETS
from .segmentation import SegmentationConfig
from .stop_signals import StopRequest, graceful_stop, interrupt_on_signals
from .streams import (
    FrameRange,
    SensorDisconnected,
    StreamError,
    open_stream,
)
from .track_loop import Progress, TrackStats, track

__all__ = [
    "main",
    "build_parser",
    "track",
    "TrackStats",
    "TrackError",
    "DEFAULT_MODEL",
]


def _forest_error_types() -> tuple[type[BaseException], ...]:
    try:
        from depthmocap.shared.forest_format import ForestFormatError
    except ImportError:  # a build without the forest format: nothing extra to catch
        return ()
    return (ForestFormatError,)


def _input_errors() -> tuple[type[BaseException], ...]:
    """Exception types that mean bad input (exit 2, one line)."""
    from .estimator import EstimatorUnavailable
    from .export.live import LiveOutputError
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
        LiveOutputError,
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
    add_source_args(p, "result directory")
    p.add_argument(
        "--model",
        type=Path,
        default=DEFAULT_MODEL,
        help="forest artifact (default: models/forest.npz of the checkout)",
    )
    p.add_argument("--mode", choices=MODES, default="hybrid", help="pose estimator")
    p.add_argument(
        "--body",
        type=Path,
        help="body file (shared.body JSON); default: the population's average adult, "
        "scaled to the person",
    )
    p.add_argument(
        "--config",
        type=Path,
        help="YAML of the mode's settings; for the hybrid, on top of --preset, key by key",
    )
    p.add_argument(
        "--preset",
        choices=sorted(PRESETS),
        help="named hybrid settings: "
        + "; ".join(f"{p.name}: {p.description}" for p in PRESETS.values())
        + f" (default: {DEFAULT_PRESET})",
    )
    p.add_argument(
        "--device",
        choices=("auto", "cpu", "cuda"),
        default="auto",
        help="torch device (auto: the one measured fastest, today the CPU: the GPU path is "
        "slower, docs/results.md)",
    )
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch CPU threads. The poses depend on it (summation order), not on the "
        "machine or OMP_NUM_THREADS; 1 was as fast as 2 or faster on a 2-core machine",
    )
    g = p.add_argument_group("intrinsics (override the source's own)")
    g.add_argument("--width", type=int, help="image width, pixels")
    g.add_argument("--height", type=int, help="image height, pixels")
    g.add_argument("--fx", type=float, help="focal length x, pixels (default: Kinect v1)")
    g.add_argument("--fy", type=float, help="focal length y, pixels (default: fx)")
    g.add_argument("--cx", type=float, help="principal point column (default: centre)")
    g.add_argument("--cy", type=float, help="principal point row (default: centre)")
    g.add_argument("--fps", type=float, help="frame rate of an image folder (default 30)")
    r = p.add_argument_group("frames and pacing")
    add_frame_range_args(r)
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
        "--fixed-lag",
        type=int,
        metavar="N",
        help="write each frame N frames late as the binomial mean of the frames N either side "
        "(runtime/export/fixed_lag.py; 0: each pose as fitted, at once). Default: "
        f"{FILE_FIXED_LAG} for a file read as fast as possible, 0 live and with --realtime",
    )
    o.add_argument(
        "--look-back",
        type=int,
        metavar="N",
        help="hold each estimate N frames and refit the frames the hybrid doubted (detections, "
        "tracks the detector was asked about) backwards from the clean frame after them, "
        "keeping a refit that fits better, and sweep every held frame backwards once as "
        "the hybrid's look_back.sweep_margin says (runtime/look_back.py; 0: off). Default: the "
        "hybrid's look_back.frames (12) for a file read as fast as possible, 0 live and with "
        "--realtime",
    )
    o.add_argument(
        "--view",
        nargs="?",
        const="",
        metavar="FILE.rrd",
        help="live 3D view in rerun (needs rerun-sdk); with a file name, save the .rrd instead",
    )
    add_live_args(p)
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


def initial_pose(stream, start: int) -> np.ndarray | None:
    """Ground-truth pose of the first frame when the input has one (recordings, demo)."""
    gt = getattr(stream, "groundtruth", None)
    if gt is None and hasattr(stream, "recording") and stream.recording.has_groundtruth:
        gt = stream.recording.groundtruth()
    if not gt or "q" not in gt or len(gt["q"]) <= start:
        return None
    return np.asarray(gt["q"][start], dtype=np.float64)


# --------------------------------------------------------------------------------------------
# Entry point


def fixed_lag_frames(args: argparse.Namespace, stream) -> int:
    """``--fixed-lag``, or its default for this source: a file tracked as fast as possible
    is smoothed over a centred window; a live stream (or ``--realtime``) is not delayed."""
    if args.fixed_lag is not None:
        return args.fixed_lag
    return 0 if args.realtime or stream.is_live else FILE_FIXED_LAG


def look_back_frames(args: argparse.Namespace, stream, estimator) -> int:
    """``--look-back``, or its default for this source: a file tracked as fast as possible
    is held as the hybrid's settings say (``look_back.frames``); a live stream (or
    ``--realtime``) is not held."""
    if args.look_back is not None:
        return args.look_back
    return 0 if args.realtime or stream.is_live else file_hold(estimator)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.threads < 1:
        return report_error(f"--threads must be >= 1, got {args.threads}")
    if args.fixed_lag is not None and not 0 <= args.fixed_lag <= MAX_FIXED_LAG:
        return report_error(f"--fixed-lag must be 0-{MAX_FIXED_LAG} frames, got {args.fixed_lag}")
    if args.look_back is not None and not 0 <= args.look_back <= MAX_LOOK_BACK:
        return report_error(f"--look-back must be 0-{MAX_LOOK_BACK} frames, got {args.look_back}")
    torch.set_num_threads(args.threads)
    stop = StopRequest()
    try:
        with interrupt_on_signals(stop):
            ready = _set_up(args)
    except KeyboardInterrupt:  # during set-up, before any output was written
        print(stop.reason or "interrupted", file=sys.stderr)
        return 143 if stop.reason == "terminated" else 130
    if isinstance(ready, int):
        return ready
    return _run(args, *ready)


def _set_up(args: argparse.Namespace):
    """Everything before the first frame: (stream, estimator, writer, view, settings), or
    the exit status of bad input (reported)."""
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
            check_plausible_intrinsics(stream.intrinsics)
        except ValueError as err:
            raise TrackError(str(err)) from None
        try:
            mode_cfg = load_mode_config(args.config, args.preset, args.mode)
            mode_cfg = settings_for_body(mode_cfg, args.mode, args.body is not None)
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
        live = live_output_from_args(args, body, stream.fps)  # --vmc, --osc, --smooth
        # The hybrid estimating the person's size rewrites body.json and motion.bvh with it.
        body_may_change = args.mode == "hybrid" and mode_cfg.get("body_scale") is not None
        writer = ResultWriter(
            args.output, body, stream.fps, stream.intrinsics, args.mode, stream.source,
            body_may_change=body_may_change,
        )  # fmt: skip
        if live is not None:
            writer = live.wrap(writer)
        writer = FixedLagSmoother(writer, fixed_lag_frames(args, stream))
        if args.realtime or stream.is_live:
            writer.extra.update(_warm_up(args, body, stream, mode_cfg, seg_cfg, device))
    except BaseException as err:
        if stream is not None:
            stream.close()  # a camera must be released whatever went wrong
        if isinstance(err, bad_input):
            return report_error(err)
        raise
    return stream, estimator, writer, view, seg_cfg, device


def _warm_up(args, body, stream, mode_cfg, seg_cfg, device) -> dict:
    """A live stream keeps only the newest frame: warm the process up first
    (:mod:`runtime.warm_up`), so that its first frames are not dropped while numba's kernels
    and torch load. Returns what ``summary.json`` records of it; a warm-up that fails is
    reported and the run goes on."""
    from .segmentation import PersonSegmenter
    from .warm_up import try_warm_up

    def throwaway():
        return make_estimator(
            args.mode, args.model, body, stream.intrinsics, device=device, config=mode_cfg
        )

    seconds, error = try_warm_up(throwaway, stream.intrinsics, PersonSegmenter(seg_cfg), device)
    if error is not None:
        print(
            f"warning: warm-up failed ({error}); the first frames may be dropped", file=sys.stderr
        )
        return {"warm_up_error": error}
    if not args.quiet:
        print(f"warmed up in {seconds:.1f} s", file=sys.stderr)
    return {"warm_up_s": round(seconds, 3)}


def _run(args, stream, estimator, writer, view, seg_cfg, device) -> int:
    bad_input = _input_errors()
    stats = TrackStats()
    stop = StopRequest()
    progress = Progress(stream.frame_count, quiet=args.quiet)
    held = look_back_frames(args, stream, estimator)
    code, note = 0, None
    try:
        with stream, writer:
            cfg = getattr(estimator, "cfg", None)
            writer.extra.update(
                {
                    "settings": config_to_dict(cfg) if dataclasses.is_dataclass(cfg) else None,
                    "preset": (args.preset or DEFAULT_PRESET) if args.mode == "hybrid" else None,
                    "config": str(args.config) if args.config is not None else None,
                    "device": device,
                    "model": str(args.model) if args.mode in MODES_NEEDING_MODEL else None,
                    "segmentation": config_to_dict(seg_cfg),
                    "realtime": args.realtime,
                }
            )
            try:
                with graceful_stop(stop):
                    track(
                        stream,
                        estimator,
                        writer,
                        seg_cfg,
                        device,
                        realtime=args.realtime,
                        save_overlays=args.save_overlays,
                        progress=progress,
                        stop=stop,
                        stats=stats,
                        view=view,
                        look_back=held,
                    )
                if stop.is_set():
                    note = stop.reason
            except KeyboardInterrupt:
                note = stop.reason or "interrupted"
            except SensorDisconnected as err:
                code, note = 1, f"camera disconnected: {err}"
            except bad_input as err:
                code, note = 2, f"error: {err}"
            finally:
                progress.close()
                writer.extra.update(
                    {
                        "dropped_frames": stats.dropped,
                        "stopped": note,
                        "body_scale": getattr(estimator, "body_scale", None),
                        "body_girth": getattr(estimator, "body_girth", None),
                        "looked_back": {
                            "frames": held,
                            "refits": stats.looked_back[0],
                            "revised": stats.looked_back[1],
                        },
                        **stats.timing(),
                    }
                )
    except bad_input as err:  # finishing the files failed (disk full, ...)
        code, note = 2, f"error: {err}"
    if code == 2:  # bad input: that one line, and where the frames before it are
        print(note, file=sys.stderr)
        if stats.last_index is not None:
            print(f"results up to frame {stats.last_index} are in {args.output}", file=sys.stderr)
        return code
    if note is not None:
        where = (
            "no frame was written"
            if stats.last_index is None
            else f"results up to frame {stats.last_index} are in {args.output}"
        )
        print(f"{note}; {where}", file=sys.stderr)
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
