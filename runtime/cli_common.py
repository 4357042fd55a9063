"""What the runtime's command-line tools share: the depth-source and frame-range options, and
the report of bad input (one ``error: ...`` line on stderr, exit status 2, no traceback)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .streams import describe_sources

__all__ = ["BAD_INPUT", "add_frame_range_args", "add_source_args", "report_error"]

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
