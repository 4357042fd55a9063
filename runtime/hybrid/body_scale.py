"""The person's size from the first tracked frames, when no body file is given.

Without a body the tracker fits one average adult to everyone (the training population's,
``runtime.estimator_setup.POPULATION_BODY``), and a person 10% smaller or larger costs more
than the rest of the pipeline together (dev recordings, before the population body: 58.7 mm
with the built-in default body, 47.9 mm with it scaled to the person's true stature, 34.7 mm
with the true body; the population body at the true stature 37.1; ``docs/experiments.md``).
The size is found by analysis by synthesis, as the
pose is: a few tracked frames are refitted with the body tracked scaled by each candidate
factor, and the factor whose fits cover the person's silhouette best wins (the mean overlap
``|R and O| / |R or O|``, peak refined by a parabola through the best grid point and its
neighbours). The silhouette decides because it measures size directly; the depth residual
favours small bodies, which hide inside the observed surface.

The body tracked follows the search as its samples come in (``interim_after``): from the
second sample taken, each sampled frame moves it to the size of the samples read so far, so
a short or tall person is tracked near their size from the 4th frame instead of at the
population's for the search's 22 frames, when the tracking failures were twice the later
rate (broad protocol); the final size is computed as without. Interim sizes stop at the first
sample of a folded body (``interim_max_fold_deg``): a seated body is sized too large, and a
body tracked too large early drew the final size up with it (UTD-MHAD sit to stand).

A seated start is sized too large: a person seated facing the camera shows a lap (both thighs
pointing at the camera, the hands on them, bits of the chair around) that larger capsules
cover better (real Kinect depth, UTD-MHAD sit to stand: 0.08-0.11 above the same person's
median size over the other actions). ``max_fold_deg`` measures only an unfolded body, as
Wei's calibration asks for a T-pose; it is off in the shipped system because waiting for the
person to unfold costs more than it saves on the broad protocol (``docs/experiments.md``,
fifteenth session).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from depthmocap.shared.body import BodyShape
from depthmocap.shared.config import ConfigError, field_doc
from depthmocap.shared.skeleton import JOINT_NAMES

__all__ = ["BodyScaleConfig", "BodyScaleSearch", "fold_angle_deg", "peak_of"]


@dataclass
class BodyScaleConfig:
    """Estimating the person's size from the first tracked frames (runs only when no body
    file is given: ``runtime-track`` and ``depthmocap.Tracker`` switch it off with one)."""

    samples: int = field_doc(8, "tracked frames refitted at each candidate size")
    every: int = field_doc(3, "take every k-th tracked frame, so the samples span a motion")
    min_scale: float = field_doc(0.84, "smallest factor tried on the body tracked")
    max_scale: float = field_doc(1.16, "largest factor tried on the body tracked")
    step: float = field_doc(0.04, "spacing of the factors tried")
    iterations: int = field_doc(5, "Gauss-Newton iterations of each refit")
    girths: tuple[float, ...] = field_doc(
        (1.0, 1.08, 1.16, 1.24),
        "width factors tried with every size (``BodyShape.girthed``: radii, cross-section "
        "offsets and hip width, lengths kept): the search refits G x S bodies and keeps the "
        "girth whose best overlap is highest, the size peaked within it. (1.0,): the "
        "population body's proportions, the size alone. Real silhouettes are wider than "
        "rendered ones of the same height (clothing, the sensor's edges), and a body widened "
        "only by its size came out too tall: UTD-MHAD's people were sized 6-7% over their "
        "silhouettes' heights, within 1.4% with these girths (with ``girth_samples`` 2: "
        "52.2 -> 49.1 mm; broad report set 42.05 -> 41.39 mm; docs/real_data.md, "
        "fifty-second and fifty-third sessions)",
    )
    girth_samples: int | None = field_doc(
        2,
        "samples refitted at every girth; the girth whose best mean overlap over them is "
        "highest is then kept, and later samples refit its S sizes only (the size comes "
        "from all samples at that girth). None: every sample at every girth. With 4 girths "
        "and 8 samples, 2 costs 126 refits instead of 288 (the size alone: 72) and loses "
        "nothing measured against every sample (UTD-MHAD 49.1 against 49.4 mm, tuning sets "
        "34.60 / 36.63 against 34.92 / 36.82 mm); the whole hybrid's mean frame x0.89 of the "
        "size alone on real depth (fewer detections), x1.01 on rendered people",
    )
    max_fold_deg: float | None = field_doc(
        None,
        "frames whose body is folded more than this are not sampled: both thighs at least "
        "this far from the torso's line (:func:`fold_angle_deg`; standing 0-20 degrees, "
        "walking and jogging under 45, seated or squatting 80-100). None (shipped): every "
        "frame. 60 fixes the size of a take that starts seated (UTD-MHAD: 67.2 -> 65.9 mm "
        "normalized, sit to stand 102.8 -> 86.9) but delays the search where a motion starts "
        "crouched (broad protocol 52.7 -> 54.1 mm, deposit on the floor 59.7 -> 63.9)",
    )
    interim_after: int | None = field_doc(
        1,
        "once this many samples are in, every later sampled frame moves the tracked body to "
        "the size of the samples in so far (read without waiting: the refits of the frame "
        "sampled before), so the person is tracked near their size from the 4th tracked "
        "frame instead of at the population's until the search ends (the 22nd); the final "
        "size still comes from all ``samples`` (so with ``samples`` or more: no interim "
        "size). None: the body changes once, at the end. "
        "1 against None: tuning set 46.4 -> 42.3 mm, tracking failure 9.7 -> 7.0%; size "
        "tuning set 44.5 -> 41.8 mm, 8.9 -> 6.5% (docs/experiments.md, 23rd session)",
    )
    interim_max_fold_deg: float | None = field_doc(
        60.0,
        "interim sizes only while every sample taken so far shows a body folded at most this "
        "much (:func:`fold_angle_deg`); after a folded one the body stays until the final "
        "size. A seated or crouched body is sized too large (its lap covers more), and a body "
        "tracked too large early drew the final size up with it (real depth, seated starts). "
        "None: every sample",
    )
    first_at_once: bool = field_doc(
        False,
        "read the first sample at once (its refits stall that one frame, ~30 ms) and track "
        "at its size from the next frame, instead of a sampling period later",
    )
    sample_detection: bool = field_doc(
        False,
        "with first_at_once, the hybrid samples the detection that starts the track as the "
        "first sample, so the body is sized from the first tracked frame on (a detection's "
        "pose is rougher than a tracked one)",
    )
    extent_check: float | None = field_doc(
        0.067,
        "the stature read off upright frames (:mod:`runtime.hybrid.stature_extent`) replaces "
        "the search's size when the two differ by more than this share of it, either way. "
        "0.067 is the 99th percentile of that gap on the size tuning set, where the search "
        "sizes right (``python -m depthmocap.bench.body_scale_fit``). On real depth it fires "
        "on seated starts, sized on their lap and chair, and on people the search inflates "
        "(UTD-MHAD: 53.5 -> 53.1 mm with the first version, whose gap was not centred; 53.1 "
        "-> 52.2 centred, ``extent_ratio``). None: the search's size stands",
    )
    extent_frames: int = field_doc(
        5, "upright frames whose median extent gives that stature (the first ones seen)"
    )
    extent_ratio: float = field_doc(
        0.9422,
        "the extent's share of the stature (``BodyShape.stature``: soles to the head's top, "
        "standing straight) of the body the search finds for the same person, with the "
        "runtime's mask and tracked joints: the median over the size tuning set's rendered "
        "recordings (``python -m depthmocap.bench.body_scale_fit``; 10-90%: 0.914-0.962), so "
        "that on rendered people the extent's size and the search's agree in the median and "
        "the check's gap is centred (the sizes it gives: 1.8% from the search's on average). "
        "Against the true stature it is 0.9155; the search's body, 3% shorter, is the one "
        "that tracks best (``correction``). The fifty-first session's check used 0.9155, so "
        "on renders the gap sat at +2.9% and a search had to be 10% too large to be caught",
    )
    extent_sizes: bool = field_doc(
        False,
        "the stature read off upright frames sizes the body whenever ``extent_frames`` of them "
        "come, before or after the search ends (the search's size stands only for people "
        "never seen upright, and ``extent_check`` is not read). The search inflates real "
        "people: clothing and the sensor's edges widen the silhouette, and a uniformly "
        "scaled body that covers the width is too tall (UTD-MHAD: search statures 3-7% above "
        "the extents', the Kinect SDK's head-to-ankle spans 8-12% under our bodies'). "
        "UTD-MHAD 53.1 -> 50.2 mm and mean frame x0.92 (the search stops at the 5th upright "
        "frame), but the size tuning set 36.8 -> 37.5 mm: on rendered people the "
        "extent is a noisier size than the search's, so it is off in the shipped preset "
        "(docs/real_data.md, fifty-second session)",
    )
    correction: float = field_doc(
        1.0,
        "factor applied to the size found, kept within min_scale..max_scale (1: none). "
        "python -m depthmocap.bench.body_scale_fit measures the search's stature "
        "error: 3.5 cm short on the training population, but the taller bodies that remove it "
        "track worse (20 size-tuning recordings: 50.4 -> 53.6 mm with 1.034), so none is "
        "shipped",
    )

    def __post_init__(self) -> None:
        ok = (
            self.samples >= 1
            and self.every >= 1
            and self.iterations >= 1
            and 0 < self.min_scale < self.max_scale
            and 0 < self.step <= self.max_scale - self.min_scale
            and 0.5 < self.correction < 2.0
            and (self.max_fold_deg is None or 0.0 < self.max_fold_deg <= 180.0)
            and (self.interim_after is None or self.interim_after >= 1)
            and (self.interim_max_fold_deg is None or 0.0 < self.interim_max_fold_deg <= 180.0)
            and (self.first_at_once or not self.sample_detection)
            and (self.extent_check is None or self.extent_check > 0.0)
            and self.extent_frames >= 1
            and 0.5 < self.extent_ratio <= 1.0
            and len(self.girths) >= 1
            and all(0.5 <= g <= 2.0 for g in self.girths)
            and (self.girth_samples is None or self.girth_samples >= 1)
        )
        if not ok:
            raise ConfigError(
                "body_scale: need samples, every, iterations >= 1 and "
                f"0 < min_scale < max_scale, 0 < step <= their difference, "
                f"0.5 < correction < 2, 0 < max_fold_deg <= 180 or None, "
                f"interim_after >= 1 or None, 0 < interim_max_fold_deg <= 180 or None, "
                f"sample_detection only with first_at_once, extent_check > 0 or None, "
                f"extent_frames >= 1, 0.5 < extent_ratio <= 1, girths in [0.5, 2] (at least one), "
                f"girth_samples >= 1 or None, got {self}"
            )

    def scales(self) -> np.ndarray:
        """(S,) the candidate factors, ``min_scale`` to ``max_scale`` in ``step``."""
        n = int(math.floor((self.max_scale - self.min_scale) / self.step + 1e-9)) + 1
        return self.min_scale + self.step * np.arange(n)


def peak_of(scales: np.ndarray, score: np.ndarray) -> float:
    """The factor where ``score`` (S,) peaks: the best grid point moved to the vertex of the
    parabola through it and its two neighbours (at an end of the grid, that end)."""
    k = int(np.argmax(score))
    if k == 0 or k == len(scales) - 1:
        return float(scales[k])
    # argmax takes the first of equal values, so left < mid >= right: the curvature < 0.
    left, mid, right = score[k - 1], score[k], score[k + 1]
    shift = 0.5 * (left - right) / (left - 2 * mid + right)  # grid steps, within (-0.5, 0.5]
    return float(scales[k] + shift * (scales[k + 1] - scales[k]))


_NECK, _PELVIS = JOINT_NAMES.index("neck"), JOINT_NAMES.index("pelvis")
_HIPS = [JOINT_NAMES.index("l_hip"), JOINT_NAMES.index("r_hip")]
_KNEES = [JOINT_NAMES.index("l_knee"), JOINT_NAMES.index("r_knee")]


def fold_angle_deg(joints: np.ndarray) -> np.ndarray:
    """How far a body is folded at the hips: the smaller of the two thighs' angles (hip to
    knee) from the torso's line (neck to pelvis), in degrees; 0 standing straight, about 90
    seated or in a deep squat, and small when only one leg is raised (a kick, a step).

    Args:
        joints: (..., J, 3) named joints (``shared.skeleton.JOINT_NAMES`` order).

    Returns:
        (...,) angles; NaN where a bone has zero length.
    """
    j = np.asarray(joints, dtype=np.float64)
    down = j[..., _PELVIS, :] - j[..., _NECK, :]
    thighs = j[..., _KNEES, :] - j[..., _HIPS, :]  # (..., 2, 3)
    cos = (thighs * down[..., None, :]).sum(-1) / (
        np.linalg.norm(thighs, axis=-1) * np.linalg.norm(down, axis=-1)[..., None]
    )
    with np.errstate(invalid="ignore"):
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).min(axis=-1)


class BodyScaleSearch:
    """Refits tracked frames of a stream at every candidate size, then picks the factor on
    the default body.

    ``offer(frame, q, fit, joints)`` after each tracked frame: of the frames whose body is
    not folded (``joints``, ``cfg.max_fold_deg``), every ``cfg.every``-th is refitted at
    all S candidate sizes and G girths (``cfg.girths``; G = 1 by default), ``fit(bodies,
    frame, q) -> (G * S,) overlaps`` with ``bodies`` the default body scaled by each factor
    and widened by each girth, girth-major (a batch of G * S: one batched fit), so the cost
    is spread over the first tracked frames instead of stalling one. The sizes returned are
    factors on the default body; :meth:`sized_body` gives the body to track with, at the
    girth found (:attr:`girth`).

    ``fit`` may return a :class:`concurrent.futures.Future` of the overlaps (or anything with
    its ``result()``, such as :class:`~runtime.hybrid.pieces.PiecesInFlight`): the refits then
    run beside the track (the hybrid runs them on a worker thread, off the frame's critical
    path), and a sample is read at the next sampled frame, a whole sampling period later.
    The last sample is read at once: the call that takes the ``cfg.samples``-th frame returns
    the factor (also :attr:`scale`), the overlaps' peak (:attr:`peak`) times
    ``cfg.correction``. With ``cfg.interim_after`` the calls that take a sample before that
    return the factor of the samples read so far (:attr:`interim`), once that many are read:
    the body to track with until the final one. The result does not depend on where the
    overlaps are computed: the same size on the same frame as with an inline ``fit``. A
    search runs once per estimator; :attr:`curves` keeps each sample's (G * S,) overlaps
    for diagnostics.
    """

    def __init__(self, cfg: BodyScaleConfig, body: BodyShape) -> None:
        self.cfg, self.body = cfg, body
        self.factors = cfg.scales()
        self.girths = np.asarray(cfg.girths, dtype=np.float64)
        G, S = len(self.girths), len(self.factors)
        # G x S bodies, girth-major: body g * S + s has size factors[s] and girth girths[g].
        dtype = body.lengths.dtype
        self._all = body.scaled(torch.as_tensor(np.tile(self.factors, G), dtype=dtype)).girthed(
            torch.as_tensor(np.repeat(self.girths, S), dtype=dtype)
        )
        self._row: int | None = None  # the girth kept for later samples (cfg.girth_samples)
        self._kept = self._all  # the bodies later samples refit: that girth's, once kept
        self._score = np.zeros(G * S)  # the overlaps read, summed per body
        self._count = np.zeros(G * S)  # how many samples each body's sum holds
        self.girth = 1.0  # the girth of the sizes returned (the best one's, once read)
        self.samples = 0  # frames refitted so far (their refits started)
        self._pending = None  # the last sample's (G * S,) overlaps, or a Future of them
        self._seen = 0
        self.interim: float | None = None  # the last interim factor returned
        self._folded = False  # a sample taken so far showed a folded body
        self.scale: float | None = None  # the result, once found
        self.peak: float | None = None  # the overlaps' peak, before the correction
        self.curves: list[np.ndarray] = []
        self._extents: list[float] = []  # upright frames' extents (cfg.extent_check)
        self._extent_checked = False
        self.extent_scale: float | None = None  # the factor the extents give, once checked

    @property
    def bodies(self) -> BodyShape:
        """The bodies the next sample refits: all G x S, girth-major, until the girth is kept
        (``cfg.girth_samples``), then that girth's S sizes."""
        return self._kept

    @property
    def searching(self) -> bool:
        """Whether later frames may still change :attr:`scale` (before the size is found,
        and while upright frames' extents are awaited: ``cfg.extent_check``)."""
        return self.scale is None or self._extent_pending

    @property
    def _extent_pending(self) -> bool:
        """Whether the extents are read (``cfg.extent_check`` or ``cfg.extent_sizes``) and
        have not been yet."""
        on = self.cfg.extent_check is not None or self.cfg.extent_sizes
        return on and not self._extent_checked

    @property
    def extents(self) -> tuple[float, ...]:
        """The upright frames' extents collected so far (metres; at most
        ``cfg.extent_frames``)."""
        return tuple(self._extents)

    @property
    def wants_extent(self) -> bool:
        """Whether an upright frame's extent is still wanted (``cfg.extent_check``, fewer
        than ``cfg.extent_frames`` in): the caller measures one only then."""
        return self._extent_pending and len(self._extents) < self.cfg.extent_frames

    @property
    def wants_detection(self) -> bool:
        """Whether a detection starting the track is to be offered as the first sample
        (``cfg.sample_detection`` before any sample is taken)."""
        return self.cfg.sample_detection and self.samples == 0

    def offer(
        self,
        frame,
        q: torch.Tensor,
        fit: Callable[[BodyShape, object, torch.Tensor], object],
        joints: np.ndarray | None = None,
        extent: float | None = None,
    ) -> float | None:
        """A tracked frame, its pose (34,) and its named joints (J, 3) (None: not checked
        for a fold), and the person's extent if the frame is upright
        (:func:`~runtime.hybrid.stature_extent.torso_extent`; None or NaN: not upright);
        returns the factor to track with from now on (the final one, an interim one, or the
        extents' one), None when the body stays."""
        if not self.searching:
            return None
        if self.wants_extent and extent is not None and math.isfinite(extent):
            self._extents.append(float(extent))
        if self.scale is not None or (
            self.cfg.extent_sizes and len(self._extents) >= self.cfg.extent_frames
        ):
            return self._check_extent()
        limit, interim_limit = self.cfg.max_fold_deg, self.cfg.interim_max_fold_deg
        fold = None
        if joints is not None and (limit is not None or interim_limit is not None):
            fold = fold_angle_deg(joints)  # NaN where degenerate: folded for both tests
        folded = interim_limit is not None and fold is not None and not fold <= interim_limit
        if limit is not None and fold is not None and not fold <= limit:
            return None  # folded (or degenerate): not counted towards ``every`` either
        take = self._seen % self.cfg.every == 0
        self._seen += 1
        if not take:
            return None
        if self._pending is not None:
            self._read(self._pending)
        self._pending = fit(self.bodies, frame, q.detach())
        self.samples += 1
        if self.cfg.first_at_once and self.samples == 1 and self.samples < self.cfg.samples:
            self._read(self._pending)
            self._pending = None
        if folded:
            self._folded = True
        if self.samples < self.cfg.samples:
            read = len(self.curves)  # samples whose overlaps are in the score
            first = self.cfg.interim_after
            if first is None or read < first or self._folded:
                return None
            peak, self.girth = self._peak()
            self.interim = self._factor(peak)
            return self.interim
        self._read(self._pending)  # the last sample: the size is wanted now
        self._pending = None
        self.peak, self.girth = self._peak()
        self.scale = self._factor(self.peak)
        self._check_extent()
        return self.scale

    def _check_extent(self) -> float | None:
        """Once ``cfg.extent_frames`` upright extents are in (and the size is found, unless
        ``cfg.extent_sizes``): the factor on the search's body they give
        (:attr:`extent_scale`) becomes the size, with ``cfg.extent_sizes`` always (the
        search ends here if it has not), otherwise if the two differ by more than
        ``cfg.extent_check``; returns the new size, None when it stays."""
        cfg = self.cfg
        if not self._extent_pending or len(self._extents) < cfg.extent_frames:
            return None
        self._extent_checked = True
        stature = float(np.median(self._extents)) / cfg.extent_ratio
        self.extent_scale = stature / float(self.body.stature())
        if not cfg.extent_sizes and abs(self.extent_scale / self.scale - 1.0) <= cfg.extent_check:
            return None
        self._pending = None  # refits still in flight are not read: the size is the extents'
        self.scale = float(np.clip(self.extent_scale, self.factors[0], self.factors[-1]))
        return self.scale

    def _peak(self) -> tuple[float, float]:
        """The size factor and girth of the mean overlaps read: the girth kept, or the one
        whose best mean overlap is highest (on the grid), and the size peaked within it
        (:func:`peak_of`)."""
        rows = self._mean_rows()
        g = int(np.argmax(rows.max(axis=1))) if self._row is None else self._row
        return peak_of(self.factors, rows[g]), float(self.girths[g])

    def sized_body(self, factor: float) -> BodyShape:
        """The body to track with at a size ``factor`` the search returned: the search's body
        scaled by it, at the girth found (:attr:`girth`)."""
        return self.body.scaled(factor).girthed(self.girth)

    def _factor(self, peak: float) -> float:
        """The factor to track with for an overlaps' ``peak``: corrected, within the grid."""
        lo, hi = self.factors[0], self.factors[-1]
        return float(np.clip(peak * self.cfg.correction, lo, hi))

    def _read(self, pending) -> None:
        """Add one sample's overlaps (an array, or a Future of one: its ``result()``) to the
        score: every girth's, or the kept girth's once there is one (a sample is read before
        the next is refitted, so it refitted :attr:`bodies` as they are now). Once
        ``cfg.girth_samples`` samples of every girth are in, the best girth is kept."""
        row = self._row
        result = pending.result() if callable(getattr(pending, "result", None)) else pending
        overlaps = np.asarray(result, dtype=np.float64)
        S = len(self.factors)
        span = slice(None) if row is None else slice(row * S, (row + 1) * S)
        want = self._score[span].shape
        if overlaps.shape != want:
            raise ValueError(f"fit returned {overlaps.shape} overlaps for {want}")
        self._score[span] += overlaps
        self._count[span] += 1
        curve = np.full(self._score.shape, np.nan)  # NaN: a girth not refitted
        curve[span] = overlaps
        self.curves.append(curve)
        n = self.cfg.girth_samples
        if row is None and len(self.girths) > 1 and n is not None and len(self.curves) >= n:
            self._row = int(np.argmax(self._mean_rows().max(axis=1)))
            self._kept = self._all.select(slice(self._row * S, (self._row + 1) * S))

    def _mean_rows(self) -> np.ndarray:
        """(G, S) the mean overlap read of each body (0 where none is read)."""
        return (self._score / np.maximum(self._count, 1)).reshape(len(self.girths), -1)
