"""Depth streams: the one interface through which the runtime reads depth frames.

Every source (a recording directory, a folder of images, an OpenNI2 camera or ``.oni`` file,
the built-in synthetic demo) is a :class:`DepthStream`: an iterable of :class:`DepthFrame` with
the camera's intrinsics, a nominal frame rate and, for finite sources, a frame count.

Two error types keep bad input apart from a camera that goes away:

- :class:`StreamError` (a ``ValueError``): the source cannot be opened or read at all (missing
  path, wrong frame size, no camera attached). Raised when opening or on the frame that is bad.
- :class:`SensorDisconnected`: a live source stopped delivering frames after it had started.
  It is not a ``ValueError`` on purpose: the frames read so far are good and the caller should
  finish its outputs with them, not treat the input as invalid.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from depthmocap.shared.camera import Intrinsics

__all__ = [
    "DepthFrame",
    "DepthStream",
    "FrameRange",
    "StreamError",
    "SensorDisconnected",
    "check_frame_shape",
    "ALL_FRAMES",
]


class StreamError(ValueError):
    """A depth source that cannot be opened or read; the message says which and why."""


class SensorDisconnected(RuntimeError):
    """A live source stopped delivering frames mid-stream (cable pulled, driver gone)."""


@dataclass(frozen=True)
class DepthFrame:
    """One depth image as it comes from a source.

    Attributes:
        index: frame number in the source (a recording's own index, so ground truth matches).
        time: seconds since the start of the source.
        depth_mm: (H, W) uint16 millimetres, 0 = no reading.
        intrinsics: camera of this image (H x W).
    """

    index: int
    time: float
    depth_mm: np.ndarray
    intrinsics: Intrinsics


@dataclass(frozen=True)
class FrameRange:
    """Frames ``start <= index < stop`` of a source (``stop=None``: to the end)."""

    start: int = 0
    stop: int | None = None

    def __post_init__(self) -> None:
        if self.start < 0:
            raise StreamError(f"frame range start must be >= 0, got {self.start}")
        if self.stop is not None and self.stop <= self.start:
            raise StreamError(
                f"frame range is empty: stop ({self.stop}) must be > start ({self.start})"
            )

    def clip(self, frame_count: int) -> range:
        """Indices of a finite source of ``frame_count`` frames that fall in the range."""
        if self.start >= frame_count > 0:
            raise StreamError(
                f"frame range starts at {self.start} but the source has {frame_count} frames"
            )
        stop = frame_count if self.stop is None else min(self.stop, frame_count)
        return range(self.start, stop)

    def contains(self, index: int) -> bool:
        return index >= self.start and (self.stop is None or index < self.stop)

    def finished(self, index: int) -> bool:
        """True once ``index`` is past the end of the range (live sources stop reading)."""
        return self.stop is not None and index >= self.stop


ALL_FRAMES = FrameRange()


def check_frame_shape(depth_mm: np.ndarray, intrinsics: Intrinsics, where: str) -> np.ndarray:
    """``depth_mm`` unchanged if it is a uint16 image of the intrinsics' size; else StreamError."""
    h, w = intrinsics.height, intrinsics.width
    if depth_mm.ndim != 2 or depth_mm.dtype != np.uint16:
        raise StreamError(
            f"{where}: expected a single-channel uint16 depth image, got "
            f"{depth_mm.dtype} with shape {depth_mm.shape}"
        )
    if depth_mm.shape != (h, w):
        raise StreamError(
            f"{where}: frame is {depth_mm.shape[1]}x{depth_mm.shape[0]} but the intrinsics are "
            f"for {w}x{h} (give matching --width/--height or intrinsics)"
        )
    return depth_mm


class DepthStream(ABC):
    """A source of depth frames; iterate it once, then :meth:`close` it (or use ``with``).

    Attributes:
        source: short description of where frames come from (written into results).
    """

    source: str = "unknown"
    # Set by every subclass's constructor.
    _intrinsics: Intrinsics
    _fps: float

    @property
    def intrinsics(self) -> Intrinsics:
        """Camera of every frame of this stream."""
        return self._intrinsics

    @property
    def fps(self) -> float:
        """Nominal frames per second (pacing in real time, BVH frame time)."""
        return self._fps

    @property
    def frame_count(self) -> int | None:
        """Frames this stream will deliver (after the frame range); ``None`` for live sources."""
        return None

    @property
    def is_live(self) -> bool:
        """True for cameras: frames arrive in real time and cannot be paced or counted."""
        return False

    @abstractmethod
    def __iter__(self) -> Iterator[DepthFrame]:
        """Frames in order. Raises StreamError on an unreadable frame, SensorDisconnected when
        a live source stops."""

    def close(self) -> None:  # noqa: B027 (optional hook: file sources hold nothing open)
        """Release the source; safe to call twice."""

    def __enter__(self) -> DepthStream:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
