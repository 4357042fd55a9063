"""The hybrid's switching policy as pure functions of the fits' signals (Wei section 5).

Two decisions per frame, both free of state and tensors so that tables can test them:

1. :func:`judge_track`: has the tracked fit failed, or should the detector question it anyway
   (a recheck)? Either way the detector runs.
2. :func:`choose`: given the detection, keep the track or take the detection? Wei always takes
   the detection; with ``keep_better`` it is taken only when it fits better (than a track
   that passed its tests, by more than ``take_margin`` in badness) and, with
   ``agree_within_m``, lands farther than that from the track's pose.

The estimator (:mod:`runtime.hybrid.estimator`) calls both and keeps what carries over frames.
"""

from __future__ import annotations

from dataclasses import dataclass

from depthmocap.runtime.tracker.signals import FitSignals

from .config import FailureThresholds, KeepBetterConfig

__all__ = ["Decision", "Detection", "TrackVerdict", "behind", "choose", "judge_track"]


@dataclass(frozen=True)
class TrackVerdict:
    """Whether a tracked frame ``failed`` its tests, and whether it is ``recheck``-ed anyway."""

    failed: bool
    recheck: bool

    @property
    def run_detector(self) -> bool:
        return self.failed or self.recheck


@dataclass(frozen=True)
class Detection:
    """What :func:`choose` needs of a detection.

    Attributes:
        found: the detector found a person (enough labelled pixels).
        signals: the refined detection's signals, None when it was not refined (nothing to
            compare: the detection is taken).
        gap_m: the largest distance between a model joint of the detection and the track's
            (None: not measured, ``keep_better.agree_within_m`` off).
    """

    found: bool
    signals: FitSignals | None = None
    gap_m: float | None = None


@dataclass(frozen=True)
class Decision:
    """Keep the track (``keep_track``) or take the detection; ``forget``: the detector found
    no one, so per-track memories (cooldowns) are dropped; ``agreed``: the track is kept
    because the better detection found the same pose (it confirms the track rather than
    being refused)."""

    keep_track: bool
    forget: bool = False
    agreed: bool = False


def behind(index: int, index_prev: int | None) -> bool:
    """Whether the stream skipped frames between the last pose (frame ``index_prev``, None:
    no pose yet) and frame ``index``: a live stream whose newest frame wins fell behind. A
    file keeps every frame, so it never is."""
    return index_prev is not None and index - index_prev > 1


def judge_track(
    signals: FitSignals,
    badness: float,
    failure: FailureThresholds,
    keep_better: KeepBetterConfig | None,
) -> TrackVerdict:
    """The tests on a tracked frame (``badness``: its signals' ``failure.badness``)."""
    recheck = (
        keep_better is not None
        and keep_better.recheck_badness is not None
        and badness > keep_better.recheck_badness
    )
    return TrackVerdict(failure.failed(signals), recheck)


def choose(
    track: FitSignals,
    detection: Detection,
    failure: FailureThresholds,
    keep_better: KeepBetterConfig,
) -> Decision:
    """Keep the track or take the detection (module docstring)."""
    if not detection.found:
        return Decision(keep_track=True, forget=True)
    worse = detection.signals is not None
    if worse and keep_better.compare_all_tests:
        # The margin guards a track that passed its tests (a recheck): a failed one has no
        # continuity worth keeping over any better fit.
        margin = 0.0 if failure.failed(track) else keep_better.take_margin
        worse = failure.badness(detection.signals) >= failure.badness(track) - margin
    elif worse:
        worse = detection.signals.surface_error_q97_mm >= track.surface_error_q97_mm
    agree, gap = keep_better.agree_within_m, detection.gap_m
    if not worse and agree is not None and gap is not None and gap <= agree:
        # The tests fired on a fit the model explains poorly whatever the pose (a deep
        # squat): a detection that lands on the same pose shows the track was not lost, and
        # taking it would only restart the motion prior.
        return Decision(keep_track=True, agreed=True)
    return Decision(keep_track=worse)
