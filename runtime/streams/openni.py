"""OpenNI2 depth cameras (Kinect v1 via its OpenNI2 driver, Asus Xtion, Orbbec) and ``.oni``
playback files, as depth streams.

Needs the PyPI package ``openni`` (``pip install 'depthmocap[runtime]'``) and the OpenNI2
library (Debian ``libopenni2-0``). The library directory is searched in this order:
``$DEPTHMOCAP_OPENNI2_DIR``, ``$OPENNI2_REDIST64``, ``$OPENNI2_REDIST``, the system's multiarch
library directory (``/usr/lib/x86_64-linux-gnu`` on Debian, where ``initialize`` is known to
work) and ``/usr/lib``, ``/usr/local/lib``.

Behaviour measured with Debian's libOpenNI2 2.2.0.33:

- With no camera, ``Device.open_any()`` fails cleanly ("no devices found"): a StreamError here.
- The ``Dummy`` URI (driver ``libDummyDevice``) opens a synthetic 320x240 30 fps 1-mm depth
  stream that the tests use in place of a camera.
- ``oniShutdown`` (what ``openni2.unload`` calls, registered by the package at exit) crashes
  the process with a segmentation fault once a Dummy stream has been started. We therefore
  unregister that exit hook; this module closes its own streams and devices, and the
  operating system releases the driver when the process ends. The process also crashed at
  exit when a closed stream's objects were left for the interpreter's final garbage
  collection (they sit in reference cycles); a ``gc.collect`` registered at exit, which runs
  while the library is intact, prevents that.
- ``.oni`` playback of a file recorded from the Dummy device delivered no frames at all (the
  frame count was right), so playback cannot be checked on this machine; reads use a timeout so
  a silent player gives a clear error instead of a hang.

Frames come unmirrored (mirroring is switched off where the driver supports it) so images
follow the OpenCV camera convention of DESIGN.md. Intrinsics come from the stream's field of
view when the driver reports it, else Kinect v1 values scaled to the stream's resolution;
``intrinsics`` overrides both.
"""

from __future__ import annotations

import atexit
import gc
import math
import os
import sysconfig
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from depthmocap.shared.camera import Intrinsics

from .base import ALL_FRAMES, DepthFrame, DepthStream, FrameRange, SensorDisconnected, StreamError

__all__ = ["OpenNIStream", "openni_library_dirs", "load_openni2"]

# Depth units of OpenNI2 pixel formats, in millimetres per count.
_FORMAT_MM = {"ONI_PIXEL_FORMAT_DEPTH_1_MM": 1.0, "ONI_PIXEL_FORMAT_DEPTH_100_UM": 0.1}


def openni_library_dirs() -> list[str]:
    """Directories to look for libOpenNI2 in, most specific first."""
    dirs = [
        os.environ.get(k) for k in ("DEPTHMOCAP_OPENNI2_DIR", "OPENNI2_REDIST64", "OPENNI2_REDIST")
    ]
    multiarch = sysconfig.get_config_var("MULTIARCH")
    if multiarch:
        dirs.append(f"/usr/lib/{multiarch}")
    dirs += ["/usr/lib", "/usr/local/lib"]
    return [d for d in dict.fromkeys(dirs) if d and Path(d).is_dir()]


def load_openni2():
    """The initialized ``openni.openni2`` module; StreamError if the package or library is
    missing."""
    try:
        from openni import openni2
    except ImportError:
        raise StreamError(
            "OpenNI2 input needs the 'openni' package: pip install 'depthmocap[runtime]'"
        ) from None
    if not openni2.is_initialized():
        dirs = openni_library_dirs()
        try:
            openni2.initialize(dirs)
        except Exception as err:  # InitializationError, OSError from ctypes
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise StreamError(
                f"OpenNI2 library not found in {dirs} (install libopenni2-0 or set "
                f"DEPTHMOCAP_OPENNI2_DIR): {first}"
            ) from None
        # Why: oniShutdown segfaults after a Dummy stream ran, and so does the interpreter's
        # own teardown if it is left to collect openni's reference cycles (module docstring):
        # collect them at exit while the library is still intact.
        atexit.unregister(openni2.unload)
        atexit.register(gc.collect)
    return openni2


def _message(err: Exception) -> str:
    """One line from an OpenNIError, whose args are (status, bytes message, ...)."""
    args = getattr(err, "args", ())
    if len(args) >= 2 and isinstance(args[1], bytes):
        return args[1].decode(errors="replace")
    return str(err).splitlines()[0] if str(err) else type(err).__name__


class OpenNIStream(DepthStream):
    """Depth frames from an OpenNI2 device or ``.oni`` file.

    Args:
        uri: device URI (``None``: the first camera found), or a path ending in ``.oni``.
        intrinsics: overrides the camera's intrinsics (must match the stream's resolution).
        frame_range: frames to deliver, counted from the first frame read.
        timeout_s: a live camera that delivers nothing for this long is reported as
            disconnected; a file as ended.
    """

    def __init__(
        self,
        uri: str | None = None,
        intrinsics: Intrinsics | None = None,
        frame_range: FrameRange = ALL_FRAMES,
        timeout_s: float = 2.0,
    ) -> None:
        self._openni2 = openni2 = load_openni2()
        self._device = self._stream = None
        self._frame_range = frame_range
        self._timeout_s = timeout_s
        self.is_file = uri is not None and uri.lower().endswith(".oni")
        if self.is_file and not Path(uri).is_file():
            raise StreamError(f"{uri}: no such .oni file")
        try:
            if uri is None:
                self._device = openni2.Device.open_any()
            else:
                self._device = openni2.Device(uri.encode())
        except Exception as err:
            what = "no depth camera found via OpenNI2" if uri is None else f"cannot open '{uri}'"
            raise StreamError(f"{what} ({_message(err)})") from None
        try:
            self._open_depth_stream(intrinsics)
        except Exception:
            self.close()
            raise
        info = self._device.get_device_info()
        name = info.uri.decode(errors="replace") if info.uri else (uri or "device")
        self.source = f"{'oni' if self.is_file else 'openni'}:{name}"

    def _open_depth_stream(self, intrinsics: Intrinsics | None) -> None:
        openni2 = self._openni2
        if not self._device.has_sensor(openni2.SENSOR_DEPTH):
            raise StreamError("the OpenNI2 device has no depth sensor")
        try:
            self._stream = self._device.create_depth_stream()
            mode = self._stream.get_video_mode()
        except Exception as err:
            raise StreamError(f"cannot create the depth stream ({_message(err)})") from None
        fmt = str(getattr(mode.pixelFormat, "name", mode.pixelFormat)).rsplit(".", 1)[-1]
        if fmt not in _FORMAT_MM:
            raise StreamError(f"unsupported OpenNI2 depth pixel format {fmt}")
        self._mm_per_count = _FORMAT_MM[fmt]
        self._fps = float(mode.fps) if mode.fps > 0 else 30.0
        w, h = int(mode.resolutionX), int(mode.resolutionY)
        try:
            self._stream.set_mirroring_enabled(False)
        except Exception:  # drivers without the property deliver unmirrored frames
            pass
        if intrinsics is not None:
            if (intrinsics.width, intrinsics.height) != (w, h):
                raise StreamError(
                    f"the camera streams {w}x{h} but the given intrinsics are for "
                    f"{intrinsics.width}x{intrinsics.height}"
                )
            self._intrinsics = intrinsics
        else:
            self._intrinsics = self._camera_intrinsics(w, h)
        self._count = None
        if self.is_file:
            self._count = int(self._stream.get_number_of_frames())
            try:
                self._device.playback.repeat = False
                self._device.playback.speed = 0.0  # no waiting between frames
            except Exception:
                pass

    def _camera_intrinsics(self, w: int, h: int) -> Intrinsics:
        try:
            hfov, vfov = self._stream.get_horizontal_fov(), self._stream.get_vertical_fov()
        except Exception:  # e.g. the Dummy driver: property not implemented
            hfov = vfov = 0.0
        if hfov > 0 and vfov > 0:
            fx, fy = w / (2 * math.tan(hfov / 2)), h / (2 * math.tan(vfov / 2))
            return Intrinsics(w, h, fx, fy, (w - 1) / 2, (h - 1) / 2)
        return Intrinsics.kinect_v1(640).resized(w, h)

    @property
    def frame_count(self) -> int | None:
        if self._count is None:
            return None
        return len(self._frame_range.clip(self._count)) if self._count else 0

    @property
    def is_live(self) -> bool:
        return not self.is_file

    def _read(self) -> tuple[np.ndarray, int] | None:
        """Next (depth_mm, timestamp_us), or None when no frame came within the timeout."""
        openni2 = self._openni2
        try:
            if openni2.wait_for_any_stream([self._stream], self._timeout_s) is None:
                return None
            frame = self._stream.read_frame()
        except Exception as err:
            raise SensorDisconnected(
                f"{self.source}: frame read failed ({_message(err)})"
            ) from None
        try:
            w, h = frame.width, frame.height
            rows = np.frombuffer(frame.get_buffer_as_uint16(), dtype=np.uint16)
            depth = rows.reshape(h, -1)[:, :w].copy()  # stride may pad rows
            stamp = int(frame.timestamp)
        finally:
            frame.close()
        if self._mm_per_count != 1.0:
            depth = np.round(depth * self._mm_per_count).astype(np.uint16)
        return depth, stamp

    def __iter__(self) -> Iterator[DepthFrame]:
        try:
            self._stream.start()
        except Exception as err:
            raise StreamError(
                f"{self.source}: cannot start the depth stream ({_message(err)})"
            ) from None
        index, t0 = 0, None
        while not self._frame_range.finished(index):
            if self._count is not None and index >= self._count:
                return
            got = self._read()
            if got is None:
                if not self.is_file:
                    raise SensorDisconnected(
                        f"{self.source}: no frame for {self._timeout_s:g} s (camera disconnected?)"
                    )
                if index == 0:
                    raise StreamError(f"{self.source}: OpenNI2 delivered no frames from the file")
                return
            depth, stamp = got
            t0 = stamp if t0 is None else t0
            if depth.shape != (self._intrinsics.height, self._intrinsics.width):
                raise SensorDisconnected(f"{self.source}: frame size changed to {depth.shape}")
            if self._frame_range.contains(index):
                yield DepthFrame(index, (stamp - t0) * 1e-6, depth, self._intrinsics)
            index += 1

    def close(self) -> None:
        stream, device = self._stream, self._device
        self._stream = self._device = None
        for step in (
            lambda: stream and stream.stop(),
            lambda: stream and stream.close(),
            lambda: device and device.close(),
        ):
            try:
                step()
            except Exception:  # closing a dropped device may fail; nothing left to release
                pass
