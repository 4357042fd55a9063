"""Fixed-lag smoothing of the output (``runtime-track --fixed-lag N``): each written frame is
the weighted mean of itself and its neighbours up to N frames either side, written N frames
late.

Why: the per-frame fits jitter. On the synthetic protocol our joints lie 14.5 mm on average
from their own centred 5-frame mean where the true motion's lie 5.1 mm from theirs, and on
Kinect v1 depth 17.5 mm where the Kinect SDK's lie 7.3 mm. A causal filter does not buy that
back: its lag costs more than the jitter (One-Euro and exponential smoothing,
``docs/experiments.md``). A centred window
has no lag, at the price of N frames of latency, which a recording tracked as a file does not
notice; so ``runtime-track`` smooths a file with N = 2 and a live stream not at all unless
asked.

The window is binomial (:func:`binomial_weights`: 1 2 1 for N = 1, 1 4 6 4 1 for N = 2, a
Gaussian of variance N / 2 frames). It runs over consecutive written frames with a pose; a
frame without one (``lost``) ends the run, and a frame near a run's ends is averaged over as
many frames on each side as it has there (its first and last frames are kept as fitted), so
that no window leans to one side: half a frame of lead or lag costs more than smoothing buys.
Neighbours are written frames, not stream indices: live with ``--fixed-lag`` set, frames
the tracker had no time for are not in the window, so its frames may lie unevenly in time.
Detections are averaged with their neighbours like any frame: a re-initialized pose is a
fresh, noisier fit, and keeping the run whole measured better than breaking it there.

Per frame: the joints are averaged joint by joint over the frames that have that joint; the
pose q by DoF, the root's rotation as unit quaternions aligned with the centre frame's (no
joint angle's range spans a full turn, so the others average as numbers and stay inside their
limits). Status, errors and the observed flags are the centre frame's own. Joints and q are
averaged separately, so a smoothed frame's joints agree with its q's to about a millimetre,
not exactly.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from .rotations import matrix_to_quat, quat_to_rotvec, rotvec_to_matrix
from .writer_stage import WriterStage

__all__ = [
    "FILE_FIXED_LAG",
    "MAX_FIXED_LAG",
    "binomial_weights",
    "smooth_joints",
    "smooth_pose",
    "FixedLagSmoother",
    "smoothed_estimates",
]

FILE_FIXED_LAG = 2
"""``runtime-track``'s window radius for a recording tracked as a file (frames): the best of
1, 2 and 3 on the two synthetic tuning sets (``docs/experiments.md``, thirty-second session)."""

MAX_FIXED_LAG = 30
"""The largest radius ``runtime-track`` takes (a second of latency at 30 frames/s)."""


def binomial_weights(radius: int) -> np.ndarray:
    """(2 radius + 1,) binomial coefficients of ``2 radius`` summing to 1; ``[1.]`` for 0."""
    if radius < 0:
        raise ValueError(f"radius must be >= 0, got {radius}")
    w = np.ones(1)
    for _ in range(2 * radius):
        w = np.convolve(w, [1.0, 1.0])
    return w / w.sum()


def smooth_joints(joints: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted mean of (W, J, 3) joints over the W frames, joint by joint over the frames
    where that joint is finite (weights renormalized); NaN where none is. (J, 3)."""
    finite = np.isfinite(joints).all(-1)  # (W, J)
    w = np.where(finite, weights[:, None], 0.0)
    total = w.sum(0)  # (J,)
    mean = (np.where(finite[..., None], joints, 0.0) * w[..., None]).sum(0)
    return np.where(total[:, None] > 0, mean / np.where(total > 0, total, 1.0)[:, None], np.nan)


def smooth_pose(q: np.ndarray, weights: np.ndarray, centre: int) -> np.ndarray:
    """Weighted mean of (W, 34) poses: DoFs as numbers, the root rotation (3:6, a rotation
    vector) as the normalized mean of unit quaternions flipped to the centre frame's
    hemisphere. ``weights`` (W,) sum to 1. (34,)."""
    q = np.asarray(q, dtype=np.float64)
    out = weights @ q
    quats = matrix_to_quat(rotvec_to_matrix(q[:, 3:6]))  # (W, 4)
    quats = quats * np.where(quats @ quats[centre] < 0, -1.0, 1.0)[:, None]
    mean = weights @ quats
    out[3:6] = quat_to_rotvec(mean / np.linalg.norm(mean))
    return out


@dataclass
class _Frame:
    index: int
    time: float
    status: str
    joints: np.ndarray | None
    q: np.ndarray | None
    errors: dict
    observed: np.ndarray | None


class FixedLagSmoother(WriterStage):
    """Wraps a result writer (:class:`~runtime.export.results.ResultWriter` or
    :class:`~runtime.export.live.LiveOutput`) with the same calls; each frame reaches it
    ``radius`` frames late, smoothed (module docstring). :meth:`close` writes the frames
    still held, so an interrupted run keeps every frame it computed.

    Args:
        writer: what the smoothed frames are written to.
        radius: N, frames each side (0: frames pass through unchanged, undelayed).
    """

    def __init__(self, writer, radius: int) -> None:
        self.writer = writer
        self.radius = int(radius)
        self.weights = binomial_weights(self.radius)
        self._run: deque[_Frame] = deque()  # the current run's last 2N + 1 frames or fewer
        self._held = 0  # how many of them, the newest, are not written yet
        writer.extra["fixed_lag_frames"] = self.radius

    def write_frame(
        self, index: int, time: float, status: str, joints: np.ndarray | None,
        q: np.ndarray | None, errors: dict[str, float], observed: np.ndarray | None = None,
    ) -> None:  # fmt: skip
        """As the wrapped writer's ``write_frame``; the frame is written once N more frames
        of its run have come (or the run ends, or the writer closes)."""
        frame = _Frame(
            index, time, status,
            None if joints is None else np.asarray(joints, dtype=np.float64),
            None if q is None else np.asarray(q, dtype=np.float64),
            errors, observed,
        )  # fmt: skip
        posed = status != "lost" and frame.joints is not None
        if self.radius == 0 or not posed:
            self._flush()
            self._run.clear()
            self._emit(frame)
            return
        self._run.append(frame)
        self._held += 1
        if self._held > self.radius:
            self._release()
        while len(self._run) > 2 * self.radius + 1:
            self._run.popleft()

    def _release(self) -> None:
        """Write the oldest held frame, with the neighbours the run has around it."""
        n = len(self._run)
        k = n - self._held  # the frame's place in the run
        # As many neighbours on each side (a lopsided window would lag or lead): near a
        # run's ends, fewer. The run before k is all in the deque or at least N long.
        r = min(self.radius, k, n - 1 - k)
        w = binomial_weights(r) if r != self.radius else self.weights
        window = [self._run[i] for i in range(k - r, k + r + 1)]
        centre = self._run[k]
        joints = smooth_joints(np.stack([f.joints for f in window]), w)
        q = centre.q
        has_q = np.array([f.q is not None for f in window])
        if q is not None and has_q.sum() > 1:  # over the frames with a pose (shotton: none)
            qs = np.stack([f.q for f in window if f.q is not None])
            q = smooth_pose(qs, w[has_q] / w[has_q].sum(), int(has_q[:r].sum()))
        self._held -= 1
        self._emit(
            _Frame(centre.index, centre.time, centre.status, joints, q, centre.errors,
                   centre.observed)
        )  # fmt: skip

    def _flush(self) -> None:
        while self._held > 0:
            self._release()

    def _emit(self, f: _Frame) -> None:
        self.writer.write_frame(
            f.index, f.time, f.status, f.joints, f.q, f.errors, observed=f.observed
        )

    def close(self) -> dict:
        """Write the frames still held, then close the wrapped writer (its summary)."""
        try:
            self._flush()
        finally:
            summary = self.writer.close()
        return summary


class _Released:
    """A writer that keeps what the smoother releases, for :func:`smoothed_estimates`."""

    def __init__(self):
        self.extra: dict = {}
        self.rows: list[tuple[int, np.ndarray | None, np.ndarray | None]] = []

    def write_frame(self, index, time, status, joints, q, errors, observed=None) -> None:
        self.rows.append((index, joints, q))

    def close(self) -> dict:
        return {}


def smoothed_estimates(pairs, radius: int):
    """``(frame, pose)`` pairs (a :meth:`runtime.api.Tracker.track_stream` iteration: ``frame``
    with an ``index``, ``pose`` a :class:`~runtime.estimator.PoseEstimate`) with each pose's
    joints and q smoothed as :class:`FixedLagSmoother` writes them, each pair yielded
    ``radius`` pairs late. If ``pairs`` raises, the pairs held are yielded first."""
    import dataclasses

    sink = _Released()
    smoother = FixedLagSmoother(sink, radius)
    held: dict[int, tuple] = {}

    def released():
        for index, joints, q in sink.rows:
            frame, pose = held.pop(index)
            if pose.joints is not None:
                pose = dataclasses.replace(pose, joints=joints, q=q)
            yield frame, pose
        sink.rows.clear()

    try:
        for frame, pose in pairs:
            held[frame.index] = (frame, pose)
            smoother.write_frame(frame.index, 0.0, pose.status, pose.joints, pose.q, {})
            yield from released()
    except Exception:
        smoother.close()
        yield from released()
        raise
    finally:  # a break in the caller's loop ends the source's iteration (its reader) now
        close = getattr(pairs, "close", None)
        if close is not None:
            close()
    smoother.close()
    yield from released()
