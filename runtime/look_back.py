"""Look-back refits: doubtful frames fitted again backwards in time from the clean frame after
them (``runtime-track --look-back N``; on for a file, off live).

Why: where the forward track goes wrong (a limb left behind at the start of a fast motion,
a detection that puts an arm in the wrong place) Wei's tests fail or the detector is asked,
and the hybrid can only choose between the track and a detection; on the frames it cannot
fix, neither is right (``docs/experiments.md``, forty-fifth session). A few frames later the
track is clean again. Seen from there the same stretch is entered from its other end, with
the limbs already in place, so a fit that starts from the later pose and predicts the motion
backwards is a hypothesis of its own, not the loser of a choice already made. On the broad
tuning sets those backward fits beat the forward pose by badness on four frames in five of
the doubtful ones they were tried on, and where they did the joints were 57 -> 39 mm
(``docs/experiments.md``, forty-seventh session).

What is doubtful (:func:`is_doubtful`): a detection, or a track the detector was asked about
(kept over a detection, rechecked, confirmed, or kept while the detector waited). A clean
frame (:func:`is_clean`) is a track that passed its tests without a second opinion.

How: estimates are held up to ``frames`` behind the newest. When a clean frame follows a run
of held doubtful ones, the run (and up to ``lead_in`` clean frames before it, where a
track may already have drifted before its tests failed) is refitted newest to oldest, each
frame from the poses of the two after it (the clean frame's successor gives the first fit
its velocity, when it is clean too). A refit replaces the held estimate when its badness is
lower (the same sum of the three signals over their thresholds the hybrid's choices read);
it keeps the frame's status (the forward track did need the detector there: a tracking
failure stays one) and is flagged ``looked_back``. The forward track is never touched: the
next frames are estimated exactly as without look-back. A frame leaves the hold when
``frames`` newer ones have arrived, or at :meth:`LookBack.flush` (end of stream, or an
interrupted run: nothing estimated is lost).

The sweep (``sweep_margin``, shipped at 0.1): half of the frames with a joint called observed
yet over 20 cm off are clean tracks, which the run refits never revisit. So every frame is
refitted backwards once, in blocks: when the oldest held frame would leave unswept, every
unswept frame but the newest is refitted newest to oldest, each from the two chosen poses
after it (one backward track, continued from whichever pose won), and a refit whose badness is
lower by more than the margin replaces the estimate (status kept, flagged ``swept``). The
margin keeps the many refits that fit a hair better (a second fit from a near pose usually
does) from replacing poses for nothing. A file's mean frame costs 1.18 times as much; report
set 42.80 -> 41.82 mm, 45 / 39 / 39 recordings better by over 1 mm and 3 / 3 / 2 worse at
the three trust regions (``docs/experiments.md``, forty-eighth session).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from depthmocap.shared.config import ConfigError, field_doc

if TYPE_CHECKING:
    from .estimator import PoseEstimate
    from .frame import Frame


class RefitsFromLater(Protocol):
    """What a :class:`LookBack` needs of an estimator (the hybrid's,
    :class:`~runtime.hybrid.estimator.HybridEstimator`)."""

    def refit_from_later(
        self, frame: Frame, later: PoseEstimate, later2: PoseEstimate | None,
        velocity_scale: float,
    ) -> tuple[PoseEstimate, float]:  # fmt: skip
        """``frame`` fitted from the poses of the two frames after it, and the fit's badness."""

    def badness_of(self, estimate: PoseEstimate) -> float:
        """The badness of an estimate's own fit (NaN when unknown)."""


__all__ = [
    "DOUBT_FLAGS",
    "MAX_LOOK_BACK",
    "LookBack",
    "LookBackConfig",
    "RefitsFromLater",
    "file_hold",
    "is_clean",
    "is_doubtful",
    "looked_back",
    "refit_span",
]

MAX_LOOK_BACK = 60
"""The longest hold ``runtime-track`` takes (two seconds at 30 frames/s)."""


@dataclass
class LookBackConfig:
    """The hybrid's look-back (``HybridConfig.look_back``; module docstring)."""

    frames: int = field_doc(
        12,
        "estimates held behind the newest when a recording is read as a file (0.4 s at 30 "
        "frames/s; at most frames - 1 before a clean frame can be revised from it). A live "
        "stream, or --realtime, is not held unless runtime-track --look-back says so",
    )
    lead_in: int = field_doc(
        2,
        "clean frames before a doubtful run refitted with it: a track drifts a frame or two "
        "before its tests fail",
    )
    suspect_badness: float | None = field_doc(
        None,
        "a track that passed with a badness above this is doubted too, though the detector was "
        "not asked about it (None: only detections and tracks the detector was asked about). "
        "A way to drop the recheck (keep_better.recheck_badness: null) at half its price: "
        "tuning set 36.34 mm with the recheck, 38.26 without, 37.27 without and 2.4 here, "
        "tracking failure 6.46 -> 3.72% (docs/experiments.md, forty-seventh session)",
    )

    sweep_margin: float | None = field_doc(
        0.1,
        "also refit every held frame backwards, clean ones included, in blocks of the hold's "
        "depth, each from the two chosen poses after it, and keep a refit whose badness is "
        "lower by more than this (None: only the doubtful runs). One more tracker fit a frame "
        "(a file's mean frame x1.18); report set 42.80 -> 41.82 mm, precision 93.30 -> "
        "93.54% (docs/experiments.md, forty-eighth session)",
    )

    def __post_init__(self) -> None:
        if not 0 <= self.frames <= MAX_LOOK_BACK:
            raise ConfigError(f"look_back.frames must be 0-{MAX_LOOK_BACK}, got {self.frames}")
        if self.lead_in < 0:
            raise ConfigError(f"look_back.lead_in must be >= 0, got {self.lead_in}")
        b = self.suspect_badness
        if b is not None and not b >= 0:
            raise ConfigError(f"look_back.suspect_badness must be >= 0 or null, got {b}")
        m = self.sweep_margin
        if m is not None and not m >= 0:
            raise ConfigError(f"look_back.sweep_margin must be >= 0 or null, got {m}")


DOUBT_FLAGS = ("kept_over_detector", "rechecked", "confirmed_by_detector", "detector_waited")
"""``errors`` flags of a track the detector was asked about (:mod:`runtime.hybrid.estimator`)."""


def is_doubtful(estimate: PoseEstimate, suspect: bool = False) -> bool:
    """A pose worth a second look: a detection, a track the detector was asked about, or
    (``suspect``) a track whose fit the caller found suspect."""
    if estimate.q is None:
        return False
    asked = estimate.status == "detected" or any(k in estimate.errors for k in DOUBT_FLAGS)
    return asked or suspect


def is_clean(estimate: PoseEstimate, suspect: bool = False) -> bool:
    """A track that passed its tests with no second opinion (and is not ``suspect``): a pose
    to look back from."""
    return (
        estimate.status == "tracked"
        and estimate.q is not None
        and not is_doubtful(estimate, suspect)
    )


def refit_span(doubtful: list[bool], clean: list[bool], lead_in: int) -> int:
    """How many of the held estimates before the newest one to refit backwards (0: none).

    Args:
        doubtful, clean: per held estimate, oldest first, the newest one last; the newest is
            where the refits start from, so it must be clean and the one before it doubtful.
    Returns:
        the length of the run of doubtful estimates right before the newest, plus up to
        ``lead_in`` clean ones before the run, within what is held.
    """
    n = len(doubtful)
    if n < 2 or not clean[-1] or not doubtful[-2]:
        return 0
    k = n - 2
    while k - 1 >= 0 and doubtful[k - 1]:
        k -= 1
    lead = 0
    while lead < lead_in and k - 1 >= 0 and clean[k - 1]:
        k, lead = k - 1, lead + 1
    return n - 1 - k


def _settings(estimator) -> LookBackConfig | None:
    """The estimator's look-back settings (the hybrid's ``cfg.look_back``; None: off or none)."""
    return getattr(getattr(estimator, "cfg", None), "look_back", None)


def file_hold(estimator) -> int:
    """Frames a file's estimates are held for ``estimator``'s look-back by default: its
    settings' ``look_back.frames``; 0 when it cannot refit or has the look-back off. (A live
    stream is not held unless asked: ``runtime-track --look-back``.)"""
    cfg = _settings(estimator)
    return cfg.frames if cfg is not None and hasattr(estimator, "refit_from_later") else 0


class LookBack:
    """Holds a stream's estimates ``frames`` deep and revises doubtful ones (module docstring).

    Args:
        estimator: the stream's estimator (the hybrid's: its tracker and tests refit the
            frames).
        suspect_badness: a track whose own badness exceeds this is doubted too (None: no).
        frames: how many frames an estimate is held behind the newest (0: passed through);
            at most ``frames - 1`` frames before a clean one can be revised from it.
        lead_in: clean frames before a doubtful run refitted with it.
    """

    def __init__(
        self,
        estimator: RefitsFromLater,
        frames: int,
        lead_in: int = 2,
        suspect_badness: float | None = None,
        sweep_margin: float | None = None,
    ) -> None:
        if frames < 0 or lead_in < 0:
            raise ValueError(f"look-back frames and lead-in must be >= 0, got {frames}, {lead_in}")
        self.estimator, self.frames, self.lead_in = estimator, frames, lead_in
        self.suspect_badness, self.sweep_margin = suspect_badness, sweep_margin
        self._held: deque[tuple[Frame, PoseEstimate]] = deque()
        self._unswept = 0  # the newest held estimates no sweep has refitted yet
        self.refits = 0  # frames refitted backwards so far
        self.revised = 0  # of those, frames whose estimate was replaced

    @classmethod
    def for_estimator(cls, estimator, frames: int) -> LookBack | None:
        """A look-back holding ``frames`` with ``estimator``'s settings (their defaults when it
        has none), or None when ``frames`` is 0 or the estimator cannot refit."""
        if frames == 0 or not hasattr(estimator, "refit_from_later"):
            return None
        cfg = _settings(estimator) or LookBackConfig()
        return cls(estimator, frames, cfg.lead_in, cfg.suspect_badness, cfg.sweep_margin)

    def push(self, frame: Frame, estimate: PoseEstimate) -> list[tuple[Frame, PoseEstimate]]:
        """Hold ``frame``'s estimate; returns the (frame, estimate) pairs that leave the hold,
        oldest first."""
        if self.frames == 0:
            return [(frame, estimate)]
        self._held.append((frame, estimate))
        self._unswept += 1
        # The newest but one is where refits start; the newest gives them their velocity.
        self._look_back(self._held, upto=len(self._held) - 1)
        if len(self._held) > self.frames and self._unswept >= len(self._held):
            self._sweep(self._held)  # the oldest would leave unswept: a block, from the newest
        out = []
        while len(self._held) > self.frames:
            out.append(self._held.popleft())
        return out

    def flush(self) -> list[tuple[Frame, PoseEstimate]]:
        """Everything held, oldest first (the stream ended: the last frame starts a look-back
        of its own, without a velocity)."""
        self._look_back(self._held, upto=len(self._held))
        self._sweep(self._held)
        return self.release()

    def release(self) -> list[tuple[Frame, PoseEstimate]]:
        """Everything held, oldest first, as it stands (no look-back: after an error)."""
        out = list(self._held)
        self._held.clear()
        self._unswept = 0
        return out

    def _suspect(self, estimate: PoseEstimate) -> bool:
        """Whether a track's own fit is worse than ``suspect_badness``."""
        limit = self.suspect_badness
        return limit is not None and self.estimator.badness_of(estimate) > limit

    def _look_back(self, held: deque, upto: int) -> None:
        """Refit the doubtful run before ``held[upto - 1]`` from it (when it is clean)."""
        items = list(held)[:upto]
        suspect = [self._suspect(e) for _, e in items]
        doubtful = [is_doubtful(e, s) for (_, e), s in zip(items, suspect, strict=True)]
        clean = [is_clean(e, s) for (_, e), s in zip(items, suspect, strict=True)]
        span = refit_span(doubtful, clean, self.lead_in)
        if span == 0:
            return
        after = held[upto] if upto < len(held) else None
        clean_after = after is not None and is_clean(after[1], self._suspect(after[1]))
        later, later2 = items[-1], after if clean_after else None
        for i in range(upto - 2, upto - 2 - span, -1):
            frame = held[i][0]
            if not frame.has_person:
                break
            new = self._refit(held, i, later, later2, 0.0, "looked_back")
            later2, later = later, (frame, new)  # the refit, taken or not

    def _sweep(self, held: deque) -> None:
        """Refit the unswept held estimates but the newest backwards from it (``sweep_margin``
        set): each from the two chosen poses after it, replaced by a refit whose badness is
        lower by more than the margin (flagged ``swept``). A frame without a pose (lost, or
        no person) breaks the chain; the next frame with one starts it again."""
        margin, count = self.sweep_margin, min(self._unswept, len(held))
        self._unswept = min(self._unswept, 1)
        if margin is None or count < 2:
            return
        later, later2 = held[-1], None
        for i in range(len(held) - 2, len(held) - 1 - count, -1):
            frame, old = held[i]
            if not (frame.has_person and old.q is not None) or later[1].q is None:
                later, later2 = held[i], None
                continue
            self._refit(held, i, later, later2, margin, "swept")
            later2, later = later, held[i]  # the chosen pose

    def _refit(
        self, held: deque, i: int, later: tuple, later2: tuple | None, margin: float, flag: str
    ) -> PoseEstimate:
        """``held[i]`` refitted from the (frame, estimate) pairs after it (``later2`` None: no
        velocity); the refit replaces it, keeping its status and flagged ``flag``, when its
        badness is lower by more than ``margin``. Returns the refit, taken or not."""
        from .tracker.prior_term import velocity_scale

        frame, old = held[i]
        # Backwards in time: the prior predicts from the later frames to this earlier one.
        ahead = velocity_scale(
            -frame.index, -later[0].index, None if later2 is None else -later2[0].index
        )
        est = self.estimator
        new, badness = est.refit_from_later(
            frame, later[1], None if later2 is None else later2[1], ahead
        )
        self.refits += 1
        if badness < est.badness_of(old) - margin:  # False for an unknown (NaN) badness
            new.status = old.status
            new.errors = {**new.errors, flag: 1.0}
            held[i] = (frame, new)
            self.revised += 1
        return new


def looked_back(
    pairs: Iterable[tuple[Frame, PoseEstimate]], stage: LookBack
) -> Iterator[tuple[Frame, PoseEstimate]]:
    """``pairs`` (a stream's frames and estimates, in order) through ``stage``, each pair
    yielded up to ``stage.frames`` pairs late. If ``pairs`` raises, the pairs held are
    yielded first (as they stand: a stream that broke off gives no clean frame to look back
    from)."""
    try:
        for frame, estimate in pairs:
            yield from stage.push(frame, estimate)
    except Exception:
        yield from stage.release()
        raise
    finally:  # a break in the caller's loop ends the source's iteration (its reader) now
        close = getattr(pairs, "close", None)
        if close is not None:
            close()
    yield from stage.flush()
