"""Depth sources for the runtime: recordings, image folders, OpenNI2 cameras and ``.oni``
files, the synthetic demo. :func:`open_stream` picks one from a string."""

from .base import (
    ALL_FRAMES,
    DepthFrame,
    DepthStream,
    FrameRange,
    SensorDisconnected,
    StreamError,
    check_frame_shape,
)
from .open_stream import describe_sources, open_stream

__all__ = [
    "ALL_FRAMES",
    "DepthFrame",
    "DepthStream",
    "FrameRange",
    "SensorDisconnected",
    "StreamError",
    "check_frame_shape",
    "describe_sources",
    "open_stream",
]
