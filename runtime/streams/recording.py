"""A recording directory (DESIGN.md, :mod:`shared.recording`) as a depth stream."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.recording import Recording

from .base import ALL_FRAMES, DepthFrame, DepthStream, FrameRange, StreamError

__all__ = ["RecordingStream"]


class RecordingStream(DepthStream):
    """Frames of a recording; ``RecordingError`` (a ``ValueError``) on anything unreadable.

    Args:
        path: recording directory with ``meta.json`` and ``depth/``.
        intrinsics: overrides the intrinsics in ``meta.json`` (must have the same size).
        frame_range: which frames to deliver; frame indices stay the recording's own.
    """

    def __init__(
        self,
        path: str | Path,
        intrinsics: Intrinsics | None = None,
        frame_range: FrameRange = ALL_FRAMES,
    ) -> None:
        self.recording = Recording(path)
        own = self.recording.intrinsics
        if intrinsics is not None:
            if (intrinsics.width, intrinsics.height) != (own.width, own.height):
                raise StreamError(
                    f"{path}: frames are {own.width}x{own.height} but the given intrinsics "
                    f"are for {intrinsics.width}x{intrinsics.height}"
                )
            own = intrinsics
        self._intrinsics = own
        self._fps = self.recording.fps
        self._indices = frame_range.clip(len(self.recording))
        self.source = f"recording:{Path(path).resolve()}"

    @property
    def frame_count(self) -> int:
        return len(self._indices)

    def __iter__(self) -> Iterator[DepthFrame]:
        unit_mm = self.recording.meta["depth_unit"] * 1e3
        for i in self._indices:
            depth = self.recording.read_depth_mm(i)
            if unit_mm != 1.0:
                # Recordings in another unit are converted so every stream delivers millimetres.
                depth = (depth.astype("float64") * unit_mm).clip(0, 65535).astype("uint16")
            yield DepthFrame(i, i / self.fps, depth, self._intrinsics)
