"""The Python API: poses from depth frames in the caller's own loop.

::

    from depthmocap import Tracker, open_stream, read_poses

    tracker = Tracker()                      # shipped forest and preset; body optional
    with open_stream("demo") as stream:      # or "device", a recording, a .oni, a folder
        for frame, pose in tracker.track_stream(stream):  # status, joints (m), flags, q
            ...
    pose = tracker.track(depth_frame)        # or one frame at a time, in your own loop

:class:`Tracker` runs the same per-frame pipeline as ``runtime-track`` (depth to metres, the
person's mask, the estimator of the mode with the preset's settings) and checks its inputs with
the same messages (:mod:`runtime.estimator_setup`). It is built from names and paths, not
from the internals, so that what a script runs is what ``runtime-track`` runs.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics

from .estimator import PoseEstimate, PoseEstimator, estimate_frame, make_estimator, prepare_frame
from .estimator_setup import (
    TrackError,
    check_model,
    load_body,
    load_mode_config,
    pick_device,
    settings_for_body,
)
from .forest.inference import DEFAULT_MODEL
from .frame import Frame
from .segmentation import PersonSegmenter, SegmentationConfig
from .streams import DepthFrame, DepthStream

__all__ = ["Tracker", "TrackError", "PoseEstimate"]


class Tracker:
    """Full-body poses from depth frames, one frame at a time, keeping the track in between.

    Args:
        body: the person's body: a :class:`BodyShape`, a ``body.json`` (``runtime-calibrate``
            or ``runtime-personalize`` make one), or None for the population's average adult
            (``configs/body_template.json``), scaled to the person once their size is found.
        model: the body-part forest (default: the shipped ``models/forest.npz``).
        preset: named hybrid settings (``runtime.presets.PRESETS``; default ``"shipped"``,
            the measured-best system; ``"wei2012"`` for the paper's thresholds).
        config: settings laid over the preset key by key: a YAML path or a mapping of the
            same shape.
        mode: "hybrid" (tracker with detector fall-back), "detector" or "shotton".
        device: "auto" (the device the hybrid is measured fastest on: today the CPU, see
            ``estimator_setup.AUTO_DEVICE``), "cpu" or "cuda".
        segmentation: how the person is cut from the background (defaults when None).
    Raises:
        TrackError (a ValueError): bad body, model, preset, config or device; the message is
        one line, as ``runtime-track`` prints it.
    """

    def __init__(
        self,
        body: BodyShape | str | Path | None = None,
        model: str | Path | None = None,
        preset: str | None = None,
        config: str | Path | Mapping | None = None,
        mode: str = "hybrid",
        device: str = "auto",
        segmentation: SegmentationConfig | None = None,
    ):
        self.device = pick_device(device)
        self._body = body if isinstance(body, BodyShape) else load_body(_path(body))
        self.model = Path(model) if model is not None else DEFAULT_MODEL
        self.mode = mode
        check_model(self.model, mode)
        self.settings = settings_for_body(
            load_mode_config(_path(config), preset, mode), mode, body is not None
        )
        self.segmentation = segmentation or SegmentationConfig()
        self._segmenter = PersonSegmenter(self.segmentation)
        self._estimator: PoseEstimator | None = None
        self._intrinsics: Intrinsics | None = None
        self._next_index = 0
        self.skipped = 0  # frames track_stream skipped on a live camera (newest wins)
        # Seconds of the warm-up before the first live stream (NaN: it failed, and was skipped).
        self.warm_up_s: float | None = None

    def track(
        self,
        frame: DepthFrame | np.ndarray,
        intrinsics: Intrinsics | None = None,
        time: float | None = None,
    ) -> PoseEstimate:
        """The pose in one depth frame, tracked from the previous one.

        Args:
            frame: a frame of :func:`open_stream`, or an (H, W) uint16 array of millimetres
                (0 = no reading; float arrays may hold NaN for no reading).
            intrinsics: the camera of a raw array (default: a Kinect v1 at the array's
                width); ignored for a stream's frame, which carries its own.
            time: seconds since the start, for a raw array (default: index / 30).
        Returns:
            :class:`PoseEstimate`: ``status`` ("tracked", "detected" or "lost"), ``joints``
            (16, 3) camera metres and ``q`` (34,) (None when lost), ``observed`` (16,) bool,
            ``errors`` (fit figures). A frame with nobody in it is "lost" and resets the track.
        """
        if not isinstance(frame, DepthFrame):
            frame = self._wrap_array(frame, intrinsics, time)
        self._next_index = frame.index + 1
        estimator = self._estimator_for(frame.intrinsics)
        prepared = Frame.from_depth(frame, device=self.device, segment=self._segmenter)
        return estimate_frame(estimator, prepared)

    def track_stream(
        self, stream: DepthStream, fixed_lag: int | None = None, look_back: int | None = None
    ) -> Iterator[tuple[Frame, PoseEstimate]]:
        """Every frame of ``stream`` tracked, as ``runtime-track`` runs it: each frame is read,
        its person cut out and its forest labels made on a reader thread while the previous
        frame is estimated, so the two cores share the work, and a file's poses smoothed
        over a centred window (``fixed_lag``; :meth:`track` on a file's frames gives the
        poses of ``fixed_lag=0``, more slowly).

        Args:
            fixed_lag: each pose yielded this many frames late, its joints and q the binomial
                mean of the frames as many either side (:mod:`runtime.export.fixed_lag`); 0:
                each pose as fitted, at once. None: as ``runtime-track``, 2 for a file and 0
                for a live camera.
            look_back: hold each pose this many frames and refit the frames the hybrid
                doubted backwards from the clean frame after them, then every held frame
                once (the sweep, ``look_back.sweep_margin``; :mod:`runtime.look_back`); 0:
                off. None: as ``runtime-track``, the hybrid's ``look_back.frames`` for a file
                and 0 for a live camera.

        A file keeps every frame, in order. A live camera's newest frame wins: frames that
        arrived while the estimator was busy are skipped and counted in :attr:`skipped`; so
        before a live stream's first frame the process is warmed up once
        (:mod:`runtime.warm_up`, about a second; :attr:`warm_up_s`).
        Closing the iteration early (``break``) stops the reader; the stream stays open for
        its ``with`` block. Do not call :meth:`reset` or :meth:`track` meanwhile.

        Yields:
            (frame, pose): the prepared :class:`~runtime.frame.Frame` (``index``, ``time``,
            ``depth_m``, ``mask``) and its :class:`PoseEstimate`.
        Raises:
            whatever the stream raises (a disconnected camera, a corrupt file), after the
            poses of the frames read before it.
        """
        from .export.fixed_lag import FILE_FIXED_LAG, MAX_FIXED_LAG, smoothed_estimates

        if fixed_lag is None:
            fixed_lag = 0 if stream.is_live else FILE_FIXED_LAG
        if not 0 <= fixed_lag <= MAX_FIXED_LAG:
            raise TrackError(f"fixed_lag must be 0-{MAX_FIXED_LAG} frames, got {fixed_lag}")
        from .look_back import MAX_LOOK_BACK, LookBack, file_hold, looked_back

        estimator = self._estimator_for(stream.intrinsics)
        if look_back is None:
            look_back = 0 if stream.is_live else file_hold(estimator)
        if not 0 <= look_back <= MAX_LOOK_BACK:
            raise TrackError(f"look_back must be 0-{MAX_LOOK_BACK} frames, got {look_back}")
        pairs = self._track_stream(stream)
        stage = LookBack.for_estimator(estimator, look_back)
        if stage is not None:
            pairs = looked_back(pairs, stage)
        return pairs if fixed_lag == 0 else smoothed_estimates(pairs, fixed_lag)

    def _track_stream(self, stream: DepthStream) -> Iterator[tuple[Frame, PoseEstimate]]:
        """:meth:`track_stream` with ``fixed_lag=0`` and ``look_back=0``."""
        from .streams.latest_frame import LatestFrameReader

        estimator = self._estimator_for(stream.intrinsics)
        if stream.is_live and self.warm_up_s is None:
            from .warm_up import try_warm_up

            seconds, error = try_warm_up(
                lambda: make_estimator(self.mode, self.model, self._body, stream.intrinsics,
                                       self.device, self.settings),
                stream.intrinsics, PersonSegmenter(self.segmentation), self.device,
            )  # fmt: skip
            if error is not None:  # an optimization only: the stream is tracked all the same
                warnings.warn(
                    f"warm-up failed ({error}); the first frames may be dropped", stacklevel=2
                )
            self.warm_up_s = math.nan if seconds is None else seconds

        def prepare(frame: DepthFrame) -> Frame:
            return prepare_frame(estimator, frame, self._segmenter, self.device)

        self.skipped = 0
        reader = LatestFrameReader(stream, prepare=prepare, skip=stream.is_live)
        try:
            for prepared, _ in reader:
                self._next_index = prepared.index + 1
                pose = estimate_frame(estimator, prepared)
                self.skipped = reader.skipped
                yield prepared, pose
        finally:
            reader.close()
            self.skipped = reader.skipped

    @property
    def body(self) -> BodyShape:
        """The body in use: the given one, or the estimator's once it has found the person's
        size (the hybrid's ``body_scale``)."""
        found = getattr(self._estimator, "body", None)
        return self._body if found is None else found

    @property
    def size_search(self):
        """The hybrid's size search (``runtime.hybrid.body_scale.BodyScaleSearch``): its
        factor, peak and overlap curves; None before the first frame, with a body file and
        in the other modes."""
        return getattr(self._estimator, "scale_search", None)

    def reset(self) -> None:
        """Forget the track: the next frame is found from scratch (a new person, a cut)."""
        self._segmenter.reset()
        if self._estimator is not None:
            self._estimator.reset()

    def _estimator_for(self, intrinsics: Intrinsics) -> PoseEstimator:
        # Built on the first frame, whose camera it needs; a new camera gets a new one.
        if self._estimator is None or intrinsics != self._intrinsics:
            try:
                self._estimator = make_estimator(
                    self.mode, self.model, self._body, intrinsics, self.device, self.settings
                )
            except TrackError:
                raise
            except ValueError as err:  # a mode's own bad-input error (its contract)
                raise TrackError(str(err)) from None
            self._intrinsics = intrinsics
        return self._estimator

    def _wrap_array(
        self, depth: np.ndarray, intrinsics: Intrinsics | None, time: float | None
    ) -> DepthFrame:
        depth = np.asarray(depth)
        if depth.ndim != 2 or depth.dtype.kind not in "uif":
            raise TrackError(
                f"a depth frame is an (H, W) array of millimetres, got {depth.shape} {depth.dtype}"
            )
        height, width = depth.shape
        if intrinsics is None:
            intrinsics = Intrinsics.kinect_v1(width)
        if (intrinsics.height, intrinsics.width) != (height, width):
            raise TrackError(
                f"the frame is {width}x{height} but the intrinsics are "
                f"{intrinsics.width}x{intrinsics.height}"
            )
        index = self._next_index
        return DepthFrame(index, index / 30.0 if time is None else float(time), depth, intrinsics)


def _path(value: str | Path | Mapping | None):
    return Path(value) if isinstance(value, str) else value
