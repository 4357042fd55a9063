"""What the runtime's command-line tools share: the depth-source and frame-range options, and
the report of bad input (one ``error: ...`` line on stderr, exit status 2, no traceback)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from depthmocap.shared.camera import Intrinsics

from .streams import describe_sources

__all__ = [
    "BAD_INPUT",
    "FIELD_OF_VIEW_DEG",
    "add_frame_range_args",
    "add_source_args",
    "check_output_file",
    "check_plausible_intrinsics",
    "report_error",
]

# Horizontal fields of view depth cameras have: Kinect v1 57, Kinect v2 70, Azure Kinect 75
# (narrow) to 120 (wide), RealSense D435 87 degrees. Outside this range the intrinsics are
# wrong (a focal length for another resolution, a typo), and every frame would be "lost".
FIELD_OF_VIEW_DEG = (20.0, 150.0)

BAD_INPUT = 2  # exit status of a run stopped by bad input or options


def add_source_args(parser: argparse.ArgumentParser, output_help: str) -> None:
    """``--input/-i`` (a depth source, :func:`runtime.streams.open_stream`) and ``--output/-o``."""
    parser.add_argument("--input", "-i", required=True, help=f"depth source: {describe_sources()}")
    parser.add_argument("--output", "-o", required=True, type=Path, help=output_help)


def add_frame_range_args(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--start`` and ``--stop``, the frames read (:class:`runtime.streams.FrameRange`)."""
    parser.add_argument("--start", type=int, default=0, help="first frame index")
    parser.add_argument("--stop", type=int, help="stop before this frame index")


def report_error(message: object) -> int:
    """Print ``error: message`` on stderr; returns :data:`BAD_INPUT` for the tool's exit."""
    print(f"error: {message}", file=sys.stderr)
    return BAD_INPUT


def check_plausible_intrinsics(intr: Intrinsics) -> None:
    """Refuse intrinsics no depth camera has: the principal point outside the image, a
    field of view outside :data:`FIELD_OF_VIEW_DEG`, or pixels more than twice as tall as
    wide. Raises ValueError naming the values."""
    fov = math.degrees(2 * math.atan2(intr.width / 2, intr.fx)) if intr.fx > 0 else math.nan
    problems = []
    if not (0 <= intr.cx <= intr.width and 0 <= intr.cy <= intr.height):
        problems.append(f"the principal point ({intr.cx:g}, {intr.cy:g}) lies outside the "
                        f"{intr.width}x{intr.height} image")  # fmt: skip
    if not FIELD_OF_VIEW_DEG[0] <= fov <= FIELD_OF_VIEW_DEG[1]:
        problems.append(f"fx {intr.fx:g} gives a {fov:.0f} degree field of view (depth cameras: "
                        f"{FIELD_OF_VIEW_DEG[0]:.0f}-{FIELD_OF_VIEW_DEG[1]:.0f})")  # fmt: skip
    if not (intr.fy > 0 and 0.5 <= intr.fx / intr.fy <= 2.0):
        problems.append(f"fx {intr.fx:g} and fy {intr.fy:g} are too far apart")
    if problems:
        raise ValueError("implausible camera intrinsics: " + "; ".join(problems))


def check_output_file(path: str | Path) -> Path:
    """Make sure ``path`` can be written as a file before any work is done: not a directory,
    its folder creatable and writable. Returns it as a Path; raises ValueError saying why."""
    out = Path(path)
    if out.is_dir():
        raise ValueError(f"{out}: is a directory; name the file to write")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"{out.parent}: cannot create it ({err.strerror or err})") from None
    probe = out.parent / f".{out.name}.probe"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise ValueError(f"{out}: cannot write there ({err.strerror or err})") from None
    return out
