"""``runtime-calibrate``: measure a person's body (bone lengths, radii) and write a body file.

The person stands facing the camera in the reference pose (T-pose: arms raised sideways to
the horizontal, legs a little apart; see :mod:`runtime.calibration.calibrate`). Per frame:
depth -> person mask (:func:`runtime.segmentation.segment_person`) -> part labels (the forest,
or with ``--labels recording`` the ground-truth labels of a synthetic recording) -> the
detector's pose with the template body. Once the reference pose has been held for ``--frames``
consecutive frames, those frames are calibrated (Wei section 6) and the body is written; it is
what ``runtime-track --body`` loads. ``--no-pose-check`` takes the first ``--frames`` frames
with a person without checking the pose (a recording known to show the reference pose).

Exit codes: 0 written; 2 bad input or the pose was never held (one ``error: ...`` line).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch
from depthmocap.runtime.frame import depth_mm_to_metres
from depthmocap.shared.body import BodyShape
from depthmocap.shared.recording import Recording, RecordingError
from depthmocap.shared.resources import CONFIGS_DIR

from .calibration import (
    CalibrationConfig,
    CalibrationError,
    ReferencePoseWatcher,
    calibrate_body,
    person_stature,
)
from .cli_common import add_frame_range_args, add_source_args, check_output_file, report_error
from .detector import (
    DetectorConfig,
    DetectorError,
    labels_from,
    load_forest_labeler,
)
from .detector.detect import detect_pose
from .forest.inference import DEFAULT_CALIBRATION_MODEL, DEFAULT_MODEL
from .segmentation import PersonSegmenter
from .streams import FrameRange, StreamError, open_stream

# The training population's average body (written by
# python -m depthmocap.train.bodies.template_body).
DEFAULT_TEMPLATE = CONFIGS_DIR / "body_template.json"

__all__ = ["main", "build_parser", "CalibrateError"]


class CalibrateError(ValueError):
    """Bad options or input for ``runtime-calibrate``."""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="runtime-calibrate",
        description="Calibrate the body model (bone lengths and radii) from depth frames of a "
        "person holding the reference pose (T-pose facing the camera); writes a body file.",
    )
    add_source_args(p, "body file to write (JSON)")
    p.add_argument(
        "--model",
        type=Path,
        default=DEFAULT_CALIBRATION_MODEL,
        help="forest labelling the reference pose for calibration (default: the shipped "
        "calibration-pose forest, trained on that pose only as in Wei section 6)",
    )
    p.add_argument(
        "--detect-model",
        type=Path,
        default=DEFAULT_MODEL,
        help="general forest for the automatic pose check (the calibration forest labels every "
        "pose as if it were the reference pose, so it cannot tell whether the pose is held)",
    )
    p.add_argument(
        "--labels",
        choices=("forest", "recording"),
        default="forest",
        help="part labels from the forest, or the recording's own ground-truth labels/",
    )
    p.add_argument("--frames", type=int, default=10, help="frames the pose must be held / used")
    p.add_argument(
        "--template",
        type=Path,
        default=DEFAULT_TEMPLATE,
        help="template body file whose proportions the measurements scale (default: the "
        "training population's average, python -m depthmocap.train.bodies.template_body; "
        "the built-in average "
        "adult when that file is missing)",
    )
    p.add_argument(
        "--no-pose-check", action="store_true", help="use the first frames without a pose check"
    )
    p.add_argument(
        "--length-scale",
        choices=("consensus", "per_bone"),
        default="consensus",
        help="one scale for all lengths (default) or Wei's per-bone lengths",
    )
    add_frame_range_args(p)
    p.add_argument("--quiet", "-q", action="store_true", help="no progress messages")
    return p


def _forest_labeler(model: Path, intr):
    if not model.is_file():
        raise CalibrateError(f"model file not found: {model}")
    return load_forest_labeler(model, "cpu", intr)


def _labeler(args, intr):
    if args.labels == "forest":
        return _forest_labeler(args.model, intr)
    try:
        rec = Recording(args.input)
    except RecordingError as err:
        raise CalibrateError(f"--labels recording needs a recording directory: {err}") from None
    if not rec.has_labels:
        raise CalibrateError(f"{args.input}: the recording has no labels/")
    return lambda index: torch.from_numpy(rec.read_labels(index).astype("int64"))


def _sized_template(template: BodyShape, depth, mask, intr, floor) -> BodyShape:
    """The template scaled to the person's stature in this frame (the pose check's detector
    fits a body of the person's size; runtime.calibration.pose_check)."""
    stature = person_stature(depth, mask, intr, floor)
    if stature is None:
        return template
    return template.scaled(stature / float(template.stature()))


def _refine(body: BodyShape, intr, depth, mask, iterations: int):
    """Wei's refinement of a detection: a few tracker iterations on this frame."""
    from .tracker.tracker import Tracker

    if iterations <= 0:
        return None
    tracker = Tracker(body, intr)
    obs = tracker.observe(depth, mask)
    return lambda starts: tracker.fit_starts(obs, starts, iterations)


def run(args: argparse.Namespace) -> BodyShape:
    if args.frames < 1:
        raise CalibrateError(f"--frames must be >= 1, got {args.frames}")
    template = BodyShape.default()  # when the shipped template is missing
    if args.template != DEFAULT_TEMPLATE or DEFAULT_TEMPLATE.is_file():
        try:
            template = BodyShape.load(args.template)
        except (FileNotFoundError, ValueError) as err:
            raise CalibrateError(str(err)) from None
    cfg = CalibrationConfig(hold_frames=args.frames, length_scale=args.length_scale)
    det_cfg = DetectorConfig(refine_iterations=cfg.check_refine_iterations)
    watcher = ReferencePoseWatcher(cfg)
    with open_stream(args.input, frame_range=FrameRange(args.start, args.stop)) as stream:
        intr = stream.intrinsics
        labeler = _labeler(args, intr)
        # Ground-truth labels serve both; forest labels: the general forest for the pose check.
        check_with_forest = args.labels == "forest" and not args.no_pose_check
        detect_labeler = _forest_labeler(args.detect_model, intr) if check_with_forest else None
        segment_person = PersonSegmenter()
        for frame in stream:
            depth = depth_mm_to_metres(frame.depth_mm)
            mask = segment_person(depth, intr)
            if not bool(mask.any()):
                watcher.update(None, depth, depth)
                continue
            if args.labels == "forest":
                labels = labels_from(labeler(depth, mask))
            else:
                labels = labeler(frame.index) * mask
            if args.no_pose_check:
                watcher.frames.append((depth, labels))
            else:
                det_labels = (
                    labels if detect_labeler is None else labels_from(detect_labeler(depth, mask))
                )
                floor = segment_person.floor
                body = _sized_template(template, depth, mask, intr, floor)
                det = detect_pose(
                    depth, det_labels, intr, body, det_cfg, mask=mask,
                    refine=_refine(body, intr, depth, mask, det_cfg.refine_iterations),
                )  # fmt: skip
                up = None if floor is None else floor[0]
                watcher.update(det.q if det.found else None, depth, labels, up, body)
            if not args.quiet:
                print(f"frame {frame.index}: held {len(watcher.frames)}/{args.frames}",
                      file=sys.stderr)  # fmt: skip
            if watcher.ready:
                break
    if not watcher.ready:
        raise CalibrateError(
            f"the reference pose (T-pose facing the camera) was not held for {args.frames} "
            f"frames in {args.input}"
        )
    frames = watcher.frames[: args.frames]
    return calibrate_body([f[0] for f in frames], [f[1] for f in frames], intr, template, cfg)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        check_output_file(args.output)  # before a camera is opened
        body = run(args)
        body.save(args.output)
    except (CalibrateError, CalibrationError, StreamError, RecordingError, DetectorError) as err:
        return report_error(err)
    except ValueError as err:  # the forest loader's ForestFormatError and similar bad input
        return report_error(err)
    except OSError as err:
        return report_error(f"cannot write {args.output}: {err}")
    if not args.quiet:
        lengths = ", ".join(f"{x * 100:.1f}" for x in body.lengths.tolist())
        print(f"wrote {args.output} (lengths cm: {lengths})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
