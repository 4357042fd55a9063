"""The tracking result directory (DESIGN.md): one writer for everything ``runtime-track`` outputs.

::

    OUT/body.json      the body in use (shared.body format), written first: evaluation and
                       re-export rebuild the skeleton from it
    OUT/poses.jsonl    one line per frame, flushed per frame (shared.poses_format)
    OUT/motion.bvh     the motion, valid between any two frames (runtime.export.bvh)
    OUT/summary.json   run summary, refreshed about once a second while running and final
                       (``"complete": true``) after close (runtime.export.summary)

Every file is complete and readable up to the last finished frame at any moment, so Ctrl-C
or a dropped camera loses nothing but the frame in flight; call :meth:`ResultWriter.close`
(or use the writer as a context manager) to mark the summary complete.

Output directory policy: the result is written into a fresh directory beside ``out_dir``
(``.NAME.partial-*``) and moved into place once its first frame is written, so a run that
fails before it has a frame leaves an existing result untouched, and a new result never mixes
with an old one's files (overlays, evaluation). ``out_dir`` may be missing, empty or hold a
previous result (any of the four files above), which is then replaced as a whole; a directory
holding a recording (``meta.json`` or ``depth/``), or any other non-empty directory, is
refused with :class:`ResultDirError`, so a typo cannot overwrite data. A file-system error
(permission, read-only, disk full) is a :class:`ResultDirError` naming the path.

BVH frames follow the stream: frame ``f`` of ``motion.bvh`` is stream frame ``first_index + f``
at ``1 / fps`` seconds spacing. A frame without a pose (``q`` None, e.g. status ``lost``), and
any stream frames skipped between two written indices, repeat the last written pose; before
the first pose the rest pose facing the camera at 2.5 m is used. ``poses.jsonl`` keeps the
truth (null pose, status) for every written frame.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time as _time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.poses_format import STATUSES, PosesJsonlWriter, pose_record
from depthmocap.shared.skeleton import JOINT_NAMES, NUM_DOFS

from .bvh import BvhWriter
from .summary import RESULT_FORMAT, RESULT_VERSION, write_summary

__all__ = ["ResultWriter", "ResultDirError", "RESULT_FILES", "check_result_dir"]

RESULT_FILES = {
    "poses": "poses.jsonl",
    "bvh": "motion.bvh",
    "summary": "summary.json",
    "body": "body.json",
}
_MAX_GAP = 100_000  # frames; a larger jump in stream indices is a caller bug, not a drop


class ResultDirError(ValueError):
    """An output directory that must not be written into."""


def _now_iso() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def check_result_dir(out_dir: Path) -> None:
    """Refuse an output that must not be replaced by a result (module docstring)."""
    try:
        if out_dir.exists() and not out_dir.is_dir():
            raise ResultDirError(f"{out_dir}: exists and is not a directory")
        if not out_dir.is_dir():
            return
        if (out_dir / "meta.json").exists() or (out_dir / "depth").is_dir():
            raise ResultDirError(
                f"{out_dir}: holds a recording (meta.json or depth/); a result would overwrite "
                "it: choose another output directory"
            )
        entries = {p.name for p in out_dir.iterdir()}
    except OSError as err:
        raise ResultDirError(f"{out_dir}: cannot be read ({err.strerror or err})") from None
    if entries and not entries & set(RESULT_FILES.values()):
        raise ResultDirError(
            f"{out_dir}: directory is not empty and holds no tracking result; "
            "choose a new or empty output directory"
        )


def _holds_result(out_dir: Path) -> bool:
    return out_dir.is_dir() and any(out_dir.iterdir())


def _make_staging(out_dir: Path) -> Path:
    """A fresh directory beside ``out_dir`` (the same file system, so moving it is a rename)."""
    parent = out_dir.absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.partial-", dir=parent))
    except OSError as err:
        raise ResultDirError(
            f"{out_dir}: cannot create the result there ({err.strerror or err})"
        ) from None


def _replace_dir(staging: Path, out_dir: Path) -> None:
    """Move ``staging`` to ``out_dir``, replacing a previous result there; the old one is
    removed only once the new one is in place."""
    old = None
    if out_dir.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.old-", dir=out_dir.absolute().parent))
        os.replace(out_dir, old / out_dir.name)
    os.replace(staging, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


class ResultWriter:
    """Writes a tracking result directory frame by frame.

    Args:
        out_dir: result directory (see the module docstring for the overwrite policy).
        body: the body the tracker uses (unbatched).
        fps: nominal stream frame rate (BVH frame time, summary ``stream_fps``).
        intrinsics: depth camera of the stream (recorded in the summary).
        mode: what produced the poses (e.g. ``"hybrid"``, ``"tracker"``, ``"detector"``).
        source: where the frames came from (e.g. ``"recording:/data/rec1"``, ``"openni"``).
        bvh_units: ``"cm"`` (default) or ``"m"``/``"mm"`` for ``motion.bvh``.
        fsync: ``os.fsync`` the per-frame files after every frame (power-loss safety).
        summary_interval_s: how often ``summary.json`` is refreshed while running.
        body_may_change: the estimator may find a better body during the run
            (:meth:`update_body`); the BVH writer then keeps the poses to rewrite.

    Attributes:
        extra: dict the caller may fill; it is stored under ``"extra"`` in the summary.
    """

    def __init__(
        self,
        out_dir: Path,
        body: BodyShape,
        fps: float,
        intrinsics: Intrinsics,
        mode: str,
        source: str,
        *,
        bvh_units: str = "cm",
        fsync: bool = False,
        summary_interval_s: float = 1.0,
        body_may_change: bool = False,
    ) -> None:
        if not (math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be positive, got {fps}")
        intrinsics.validate()
        self.out_dir = Path(out_dir)
        check_result_dir(self.out_dir)
        self.fps = float(fps)
        self.intrinsics = intrinsics
        self.mode = mode
        self.source = source
        self.extra: dict = {}
        self._summary_interval = summary_interval_s
        self._status_counts = dict.fromkeys(STATUSES, 0)
        self._first_index: int | None = None
        self._last_index: int | None = None
        self._t_open = _clock()
        self._t_first: float | None = None
        self._t_last: float | None = None
        # When the caller says when each frame was estimated (note_estimated), the processing
        # rate is read from those times: a stage that holds frames (a fixed lag, the
        # look-back) writes them late and the last ones in a burst at the end.
        self._estimated = 0
        self._t_first_estimate: float | None = None
        self._t_last_estimate: float | None = None
        self._t_summary = -math.inf
        self._started = _now_iso()
        self._closed_summary: dict | None = None
        self._bvh_units = bvh_units
        self._dir = _make_staging(self.out_dir)
        self._poses = self._bvh = None
        try:
            body.save(self._dir / RESULT_FILES["body"])
            self._poses = PosesJsonlWriter(self._dir / RESULT_FILES["poses"], fsync=fsync)
            self._bvh = BvhWriter(
                self._dir / RESULT_FILES["bvh"], body, self.fps, bvh_units, fsync=fsync,
                keep_poses=body_may_change,
            )  # fmt: skip
            self._write_summary(complete=False)
        except BaseException as err:
            self._discard()
            if isinstance(err, OSError):
                raise ResultDirError(f"{self.out_dir}: cannot write ({err})") from None
            raise

    @property
    def directory(self) -> Path:
        """Where the files are now: a staging directory until the first frame is written,
        ``out_dir`` from then on."""
        return self._dir

    def _discard(self) -> None:
        for f in (self._poses, self._bvh):
            if f is not None:
                f.close()
        shutil.rmtree(self._dir, ignore_errors=True)

    def _publish(self) -> None:
        """Move the result into ``out_dir`` (once)."""
        if self._dir == self.out_dir:
            return
        _replace_dir(self._dir, self.out_dir)
        self._dir = self.out_dir

    @property
    def frames(self) -> int:
        """Frames written so far."""
        return self._poses.frames

    def note_estimated(self) -> None:
        """A frame was estimated now (it may be written later): ``fps`` is then the rate of
        the estimates, not of the writes."""
        now = _clock()
        if self._t_first_estimate is None:
            self._t_first_estimate = now
        self._t_last_estimate = now
        self._estimated += 1

    def update_body(self, body: BodyShape) -> None:
        """The estimator found a better body (e.g. the person's size, estimated while
        tracking): ``body.json`` and ``motion.bvh``, its frames so far included, use it."""
        try:
            self._bvh.set_body(body, self._dir / RESULT_FILES["bvh"])
            body.save(self._dir / RESULT_FILES["body"])
        except OSError as err:
            raise ResultDirError(f"{self.out_dir}: cannot write ({err})") from None

    def write_frame(
        self,
        index: int,
        time: float,
        status: str,
        joints: np.ndarray | None,
        q: np.ndarray | None,
        errors: dict[str, float],
        observed: np.ndarray | None = None,
        bvh_q=...,
    ) -> None:
        """Append one frame to ``poses.jsonl`` and ``motion.bvh``.

        Args:
            index: stream frame index; must increase from call to call (gaps allowed).
            time: stream timestamp, seconds.
            status: ``"tracked"``, ``"detected"`` or ``"lost"``.
            joints: (16, 3) named joints (``skeleton.JOINT_NAMES``) in camera metres, or None.
            q: (34,) pose in the camera frame, or None (BVH repeats the last pose).
            errors: per-frame fit errors by name (e.g. ``surface_error_q97_mm``).
            observed: (16,) bool, the joints the depth image confirms (the others are
                inferred), or None if unknown.
            bvh_q: the pose for ``motion.bvh`` when it is not ``q`` (a smoothed pose:
                :mod:`runtime.export.live`); ``poses.jsonl`` always gets ``q``.
        """
        if self._closed_summary is not None:
            raise ValueError(f"{self.out_dir}: result writer is closed")
        index = int(index)
        if self._last_index is not None and index <= self._last_index:
            raise ValueError(f"frame index {index} does not follow {self._last_index}")
        gap = 0 if self._last_index is None else index - self._last_index - 1
        if gap > _MAX_GAP:
            raise ValueError(f"frame index jumps from {self._last_index} to {index}")
        if joints is not None:
            joints = np.asarray(joints, dtype=np.float64)
        if q is not None:
            q = np.asarray(q, dtype=np.float64)
            if q.shape != (NUM_DOFS,):
                raise ValueError(f"q must have shape ({NUM_DOFS},), got {q.shape}")
        record = pose_record(index, time, status, joints, q, errors, JOINT_NAMES, observed)
        if bvh_q is ...:
            bvh_q = q
        elif bvh_q is not None:
            bvh_q = np.asarray(bvh_q, dtype=np.float64)
            if bvh_q.shape != (NUM_DOFS,):
                raise ValueError(f"bvh_q must have shape ({NUM_DOFS},), got {bvh_q.shape}")
        if bvh_q is not None and not np.isfinite(bvh_q).all():
            bvh_q = None

        try:
            self._poses.write(record)
            self._bvh.write_pose(None, repeat=gap)
            self._bvh.write_pose(bvh_q)
            self._publish()
        except OSError as err:
            raise ResultDirError(f"{self.out_dir}: cannot write ({err})") from None

        now = _clock()
        if self._first_index is None:
            self._first_index, self._t_first = index, now
        self._last_index, self._t_last = index, now
        self._status_counts[status] += 1
        if now - self._t_summary >= self._summary_interval:
            try:
                self._write_summary(complete=False)
            except OSError as err:
                raise ResultDirError(f"{self.out_dir}: cannot write ({err})") from None

    def _summary(self, complete: bool) -> dict:
        n = self.frames
        if self._estimated:
            k = self._estimated
            span = (self._t_last_estimate - self._t_first_estimate) if k >= 2 else None
            fps = (k - 1) / span if span else None
        else:
            span = (self._t_last - self._t_first) if n >= 2 else None
            fps = (n - 1) / span if span else None
        wall = (self._t_last if self._t_last is not None else _clock()) - self._t_open
        return {
            "format": RESULT_FORMAT,
            "version": RESULT_VERSION,
            "complete": complete,
            "frames": n,
            "first_frame": self._first_index,
            "last_frame": self._last_index,
            "fps": fps,
            "stream_fps": self.fps,
            "status_counts": dict(self._status_counts),
            "mode": self.mode,
            "source": self.source,
            "intrinsics": self.intrinsics.as_dict(),
            "timing": {
                "started": self._started,
                "finished": _now_iso() if complete else None,
                "wall_s": wall,
                "mean_frame_interval_ms": 1e3 / fps if fps else None,
            },
            "files": dict(RESULT_FILES),
            "bvh": {
                "frames": self._bvh.frames,
                "units": self._bvh_units,
                "world_frame": "y up, x = camera right, z = towards the camera; origin at camera",
            },
            "extra": self.extra,
        }

    def _write_summary(self, complete: bool) -> dict:
        summary = self._summary(complete)
        write_summary(self._dir / RESULT_FILES["summary"], summary)
        self._t_summary = _clock()
        return summary

    def close(self) -> dict:
        """Finish the files, write the final ``summary.json`` and return it. Idempotent.

        A run that wrote no frame leaves a previous result in ``out_dir`` as it was (and
        creates ``out_dir`` with an empty result only where there was none)."""
        if self._closed_summary is None:
            try:
                self._poses.close()
                self._bvh.close()
                self._closed_summary = self._write_summary(complete=True)
                if self.frames == 0 and _holds_result(self.out_dir):
                    self._discard()
                else:
                    self._publish()
            except OSError as err:
                self._closed_summary = self._summary(complete=False)
                raise ResultDirError(f"{self.out_dir}: cannot write ({err})") from None
        return self._closed_summary

    def __enter__(self) -> ResultWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _clock() -> float:
    return _time.perf_counter()
