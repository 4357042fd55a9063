"""A folder of depth images: 16-bit PNGs, or raw little-endian uint16 files (.raw, .bin, .u16).

Files are read in natural order of their names (``f2`` before ``f10``). Raw files carry no
size, so it comes from the intrinsics; without intrinsics, a raw file whose byte count fits a
4:3 image (Kinect 640x480, 320x240, ...) is taken as that size with the Kinect v1 intrinsics,
and PNGs use the Kinect v1 intrinsics scaled to their size. Every frame is checked against the
intrinsics: a size mismatch is a :class:`StreamError` naming the file.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from depthmocap.shared.camera import Intrinsics

from .base import ALL_FRAMES, DepthFrame, DepthStream, FrameRange, StreamError, check_frame_shape

__all__ = ["ImageFolderStream", "RAW_SUFFIXES", "list_depth_files"]

RAW_SUFFIXES = (".raw", ".bin", ".u16")
PNG_SUFFIXES = (".png",)


def _natural_key(path: Path) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


def list_depth_files(folder: Path) -> list[Path]:
    """Depth image files of ``folder`` in natural order; StreamError if none or mixed kinds."""
    files = [p for p in folder.iterdir() if p.is_file()]
    pngs = [p for p in files if p.suffix.lower() in PNG_SUFFIXES]
    raws = [p for p in files if p.suffix.lower() in RAW_SUFFIXES]
    if pngs and raws:
        raise StreamError(f"{folder}: holds both PNG and raw depth files; keep one kind")
    if not pngs and not raws:
        kinds = ", ".join(PNG_SUFFIXES + RAW_SUFFIXES)
        raise StreamError(
            f"{folder}: no depth frames found (expected a recording with meta.json, or {kinds} "
            "files)"
        )
    return sorted(pngs or raws, key=_natural_key)


def _raw_size_guess(n_bytes: int) -> tuple[int, int] | None:
    """(width, height) of a 4:3 uint16 image of ``n_bytes``, if one fits exactly."""
    pixels = n_bytes // 2
    height = math.isqrt(pixels * 3 // 4)
    if n_bytes % 2 == 0 and height > 0 and height % 3 == 0 and height * (height * 4 // 3) == pixels:
        return height * 4 // 3, height
    return None


def _read_png(path: Path) -> np.ndarray:
    from depthmocap.shared.recording import RecordingError, read_png

    try:
        return read_png(path, np.uint16)
    except RecordingError as err:
        raise StreamError(f"{err} (a single-channel 16-bit PNG in millimetres)") from None


def _read_raw(path: Path, intrinsics: Intrinsics) -> np.ndarray:
    h, w = intrinsics.height, intrinsics.width
    n_bytes = path.stat().st_size
    if n_bytes != 2 * w * h:
        raise StreamError(
            f"{path}: {n_bytes} bytes do not make a {w}x{h} uint16 frame "
            f"({2 * w * h} bytes); check --width/--height"
        )
    return np.fromfile(path, dtype="<u2").reshape(h, w).astype(np.uint16)


class ImageFolderStream(DepthStream):
    """Depth frames from a folder of PNG or raw files.

    Args:
        folder: the directory.
        intrinsics: camera of the frames; ``None`` guesses Kinect v1 (see the module docstring).
        fps: nominal frame rate (folders carry none).
        frame_range: which files (by position in natural order) to deliver.
    """

    def __init__(
        self,
        folder: str | Path,
        intrinsics: Intrinsics | None = None,
        fps: float = 30.0,
        frame_range: FrameRange = ALL_FRAMES,
    ) -> None:
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise StreamError(f"{self.folder}: no such directory")
        if not fps > 0:
            raise StreamError(f"fps must be positive, got {fps}")
        self.files = list_depth_files(self.folder)
        self.is_raw = self.files[0].suffix.lower() in RAW_SUFFIXES
        self._intrinsics = intrinsics or self._guess_intrinsics()
        try:
            self._intrinsics.validate()
        except ValueError as err:
            raise StreamError(f"invalid intrinsics: {err}") from None
        self._fps = float(fps)
        self._indices = frame_range.clip(len(self.files))
        # Fail before any work if the first frame does not fit the intrinsics.
        self._read(self._indices.start)
        self.source = f"folder:{self.folder.resolve()}"

    def _guess_intrinsics(self) -> Intrinsics:
        first = self.files[0]
        if self.is_raw:
            size = _raw_size_guess(first.stat().st_size)
            if size is None:
                raise StreamError(
                    f"{first}: raw frames carry no size and {first.stat().st_size} bytes fit no "
                    "4:3 image; give --width and --height"
                )
            return Intrinsics.kinect_v1(640).resized(*size)
        h, w = _read_png(first).shape
        return Intrinsics.kinect_v1(640).resized(w, h)

    def _read(self, i: int) -> np.ndarray:
        path = self.files[i]
        image = _read_raw(path, self._intrinsics) if self.is_raw else _read_png(path)
        return check_frame_shape(image, self._intrinsics, str(path))

    @property
    def frame_count(self) -> int:
        return len(self._indices)

    def __iter__(self) -> Iterator[DepthFrame]:
        for i in self._indices:
            yield DepthFrame(i, i / self._fps, self._read(i), self._intrinsics)
