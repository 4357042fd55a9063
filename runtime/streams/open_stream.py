"""``open_stream(spec)``: one string names any depth source (what ``runtime-track --input`` takes).

Accepted forms, tried in this order:

- ``demo``: the built-in synthetic sequence (:mod:`runtime.streams.demo`), no camera or data.
- ``device``: the first OpenNI2 camera found; ``device:URI``: a given OpenNI2 device URI
  (``device:Dummy`` is OpenNI2's synthetic test device). A bare URI such as
  ``1d27/0601@1/5`` or ``freenect://0`` also works when no file of that name exists.
- ``*.oni``: an OpenNI2 recording, played back.
- a directory with ``meta.json``: a recording (DESIGN.md).
- any other directory: a folder of 16-bit PNG or raw uint16 frames.
"""

from __future__ import annotations

import re
from pathlib import Path

from depthmocap.shared.camera import Intrinsics

from .base import ALL_FRAMES, DepthStream, FrameRange, StreamError

__all__ = ["open_stream", "describe_sources"]

# USB-style OpenNI2 URIs (vendor/product@bus/address) and scheme URIs (freenect://0).
_URI = re.compile(r"^([0-9a-fA-F]{4}/[0-9a-fA-F]{4}@\S+|[A-Za-z][\w+.-]*://\S*)$")


def describe_sources() -> str:
    """One line listing the accepted forms (for help texts and errors)."""
    return "'demo', 'device', 'device:URI', a .oni file, a recording directory or an image folder"


def open_stream(
    spec: str,
    intrinsics: Intrinsics | None = None,
    frame_range: FrameRange = ALL_FRAMES,
    fps: float | None = None,
    timeout_s: float = 2.0,
) -> DepthStream:
    """Open the depth source named by ``spec`` (see the module docstring).

    Args:
        spec: the source.
        intrinsics: overrides the source's own intrinsics (required size must match).
        frame_range: frames to deliver.
        fps: nominal frame rate for sources that carry none (image folders; default 30).
        timeout_s: seconds without a frame after which a camera counts as disconnected.
    Raises:
        StreamError (or RecordingError for a bad recording): a one-line reason.
    """
    if intrinsics is not None:
        try:
            intrinsics.validate()
        except ValueError as err:
            raise StreamError(f"invalid intrinsics: {err}") from None
    spec = spec.strip()
    if spec == "demo":
        try:
            from .demo import open_demo_stream
        except ImportError as err:
            raise StreamError(f"the demo sequence is not available in this build ({err})") from None
        return open_demo_stream(intrinsics=intrinsics, frame_range=frame_range, fps=fps)
    path = Path(spec).expanduser()
    if spec == "device" or spec.startswith("device:"):
        from .openni import OpenNIStream

        uri = spec.partition(":")[2] or None
        return OpenNIStream(uri, intrinsics, frame_range, timeout_s)
    if spec.lower().endswith(".oni"):
        from .openni import OpenNIStream

        if not path.is_file():
            raise StreamError(f"{spec}: no such .oni file")
        return OpenNIStream(str(path), intrinsics, frame_range, timeout_s)
    if path.is_dir():
        meta = path / "meta.json"
        if meta.exists() or meta.is_symlink():  # a broken link: the recording says why
            from .recording import RecordingStream

            return RecordingStream(path, intrinsics, frame_range)
        from .image_folder import ImageFolderStream

        return ImageFolderStream(path, intrinsics, fps or 30.0, frame_range)
    if not path.exists() and _URI.match(spec):
        from .openni import OpenNIStream

        return OpenNIStream(spec, intrinsics, frame_range, timeout_s)
    if path.exists():
        raise StreamError(f"{spec}: not a depth source (expected {describe_sources()})")
    raise StreamError(f"{spec}: no such file or directory (expected {describe_sources()})")
