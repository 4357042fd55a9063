"""Settings of the hybrid tracker/detector (Wei section 5), as a tree.

``HybridConfig`` holds the failure tests, how a detection is weighed against the track
(``keep_better``), the hidden-arm search (``arm_search``), and the detector's and tracker's own
settings. A mechanism that is off is ``None`` (``null`` in a preset), never an infinite
threshold. ``HybridConfig()`` is the shipped system; the sections' own classes default to
Wei's values where the paper has them (``FailureThresholds()`` is 2.5 cm, 0.9).
``docs/experiments.md`` records why each value is what it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from depthmocap.runtime.detector.config import DetectorConfig
from depthmocap.runtime.look_back import LookBackConfig
from depthmocap.runtime.tracker.config import TrackerConfig
from depthmocap.runtime.tracker.signals import FitSignals
from depthmocap.shared.config import ConfigError, field_doc

from .behind_model import BehindModelConfig
from .body_scale import BodyScaleConfig

__all__ = [
    "ArmSearchConfig",
    "BodyScaleConfig",
    "FailureThresholds",
    "HybridConfig",
    "HybridError",
    "KeepBetterConfig",
    "MisplacedArmConfig",
]


class HybridError(ConfigError):
    """Bad settings or inputs of the hybrid estimator."""


def _check(ok: bool, what: str, got: object) -> None:
    if not ok:
        raise HybridError(f"hybrid settings: {what}, got {got!r}")


@dataclass
class FailureThresholds:
    """When a tracked frame has failed (Wei section 5), and how bad a fit is."""

    epsilon1_cm: float = field_doc(
        2.5, "tracking fails above this mean depth / extra-depth error, cm (Wei: 2.5)"
    )
    epsilon2: float = field_doc(
        0.9, "tracking fails below this silhouette overlap |R and O| / |R or O| (Wei: 0.9)"
    )
    epsilon3_mm: float | None = field_doc(
        None,
        "tracking also fails when the 97% quantile of the observed points' distances to the "
        "model exceeds this, mm: a limb left behind (not in Wei; None: no such test)",
    )

    lost_overlap: float | None = field_doc(
        None,
        "a frame whose chosen fit (kept track or refined detection) overlaps the observed "
        "silhouette less than this is reported lost and the track restarts: the model "
        "explains almost none of what was segmented, so it is not the person's pose (not in "
        "Wei; None: never)",
    )

    def __post_init__(self) -> None:
        # badness divides by the thresholds; a NaN would silently switch a test off.
        _check(self.epsilon1_cm > 0, "epsilon1_cm must be > 0", self.epsilon1_cm)
        lo = self.lost_overlap
        _check(lo is None or 0 <= lo < 1, "lost_overlap must be in [0, 1) or None", lo)
        _check(0 <= self.epsilon2 < 1, "epsilon2 must be in [0, 1)", self.epsilon2)
        e3 = self.epsilon3_mm
        _check(e3 is None or e3 > 0, "epsilon3_mm must be > 0 or None", e3)

    def failed(self, s: FitSignals) -> bool:
        """Wei's two tests, plus the surface-error test when it is set (NaN fails)."""
        e3 = math.inf if self.epsilon3_mm is None else self.epsilon3_mm
        return not (
            s.depth_error_cm <= self.epsilon1_cm
            and s.overlap >= self.epsilon2
            and s.surface_error_q97_mm <= e3
        )

    def badness(self, s: FitSignals) -> float:
        """The signals in units of their thresholds, summed: 0 is a perfect fit, a fit on
        every threshold scores the number of tests (the surface term only when it is set)."""
        score = s.depth_error_cm / self.epsilon1_cm + (1.0 - s.overlap) / max(
            1.0 - self.epsilon2, 1e-6
        )
        if self.epsilon3_mm is not None:
            score += s.surface_error_q97_mm / self.epsilon3_mm
        return score


@dataclass
class KeepBetterConfig:
    """After a failed test (or a recheck), the detector's pose replaces the track only when it
    explains the frame better (not in Wei: his switch always takes the detector's)."""

    compare_all_tests: bool = field_doc(
        False,
        "compare the two fits by their badness (all three signals over their thresholds) "
        "instead of the surface error alone",
    )
    recheck_badness: float | None = field_doc(
        None,
        "also run the detector on a passed frame whose badness exceeds this (None: never)",
    )
    wait_frames: int = field_doc(
        0,
        "after the detector's pose was refused (the track kept), the detector is not run "
        "again for this many frames: a failed or suspect track is kept meanwhile (0: it runs "
        "on every failed or suspect frame)",
    )
    take_margin: float = field_doc(
        0.0,
        "with compare_all_tests, a detection replaces a track that passed its tests (a "
        "recheck) only when its badness is lower by more than this: fewer re-initializations "
        "for near ties (0: any lower badness; a failed track gives way to any better "
        "detection). Off in the shipped preset: 0.15 cut the tracking failures by a quarter "
        "to two fifths on the tuning and broad sets but not the error, and jog lost 2-5 mm "
        "(docs/experiments.md, twenty-sixth session)",
    )
    confirm_within_m: float | None = field_doc(
        None,
        "when the detector's IK pose puts every joint within this distance (m) of the track's, "
        "it confirms the track: the track is kept (tracked, flagged confirmed_by_detector) and "
        "the detector's refinement is not run (None: the detection is always refined and "
        "weighed)",
    )
    agree_within_m: float | None = field_doc(
        None,
        "when the refined detection that would replace the track puts every joint within this "
        "distance (m) of the track's, the two found the same pose: the track did not fail, it "
        "is kept (tracked, flagged confirmed_by_detector) with its history (None: any better "
        "detection is taken). 0.05 in the shipped preset: tracking failures 6.5 -> 3.8% and "
        "6.7 -> 3.6% on the two tuning sets, joint error 0.2-0.4 mm lower; the report set "
        "5.2 -> 4.2% (docs/experiments.md, forty-ninth session)",
    )

    def __post_init__(self) -> None:
        _check(self.wait_frames >= 0, "keep_better.wait_frames must be >= 0", self.wait_frames)
        for name in ("confirm_within_m", "agree_within_m"):
            c = getattr(self, name)
            _check(c is None or (c > 0 and math.isfinite(c)),
                   f"keep_better.{name} must be > 0 or None", c)  # fmt: skip
        m = self.take_margin
        _check(m >= 0 and math.isfinite(m), "keep_better.take_margin must be >= 0", m)
        # The margin is in badness units; the surface-only comparison would ignore it.
        _check(m == 0 or self.compare_all_tests,
               "keep_better.take_margin needs compare_all_tests: true", m)  # fmt: skip
        b = self.recheck_badness
        _check(b is None or not math.isnan(b), "recheck_badness must be a number or None", b)


@dataclass
class MisplacedArmConfig:
    """The arm search also questions an arm the model shows where the forest sees something
    else: a lost arm laid on a leg or the torso fits the depth and passes every test."""

    conflict: float = field_doc(
        0.7,
        "search an arm when the forest labels more than this share of the person's points it "
        "explains (nearest to it, within 3 cm; at least runtime.hybrid.arm_search."
        "MISPLACED_MIN_POINTS of them) as something else",
    )
    cooldown_frames: int = field_doc(
        0,
        "after a search of a misplaced arm found nothing to take, that arm is not searched as "
        "misplaced again for this many frames",
    )
    relief: float = field_doc(
        0.5,
        "a refit is taken only if the points of its arm labelled otherwise are at most this "
        "fraction of the track's (0-1)",
    )

    def __post_init__(self) -> None:
        _check(0 <= self.conflict <= 1, "misplaced.conflict must be in [0, 1]", self.conflict)
        _check(self.cooldown_frames >= 0, "misplaced.cooldown_frames must be >= 0",
               self.cooldown_frames)  # fmt: skip
        _check(0 <= self.relief <= 1, "misplaced.relief must be in [0, 1]", self.relief)


@dataclass
class ArmSearchConfig:
    """When a suspect fit's model hides an arm the forest sees, refit the frame from a few arm
    poses and keep the best fit (not in Wei; :mod:`runtime.hybrid.arm_search`, whose
    constants say when an arm counts as hidden, partly shown or seen)."""

    badness: float = field_doc(1.9, "search only when the track's badness exceeds this")
    other_arm_margin_m: float = field_doc(
        0.05,
        "labelled arm pixels within this distance of the model's other arm do not count as "
        "seeing the arm (m; 0: all count): in profile the far arm's labels land on the near arm",
    )
    agreement_slack: float | None = field_doc(
        0.1,
        "a refit is taken only if its share of the arm's labelled pixels within 5 cm is at "
        "least the track's minus this (None: no such check)",
    )
    misplaced: MisplacedArmConfig | None = field_doc(
        None, "search arms the model shows on pixels the forest calls something else (None: off)"
    )
    cooldown_frames: int = field_doc(
        0,
        "after a search of an arm found no refit to take, that arm is not searched again for "
        "this many frames (0: every suspect frame is searched)",
    )

    def __post_init__(self) -> None:
        _check(not math.isnan(self.badness), "arm_search.badness must be a number", self.badness)
        _check(self.cooldown_frames >= 0, "arm_search.cooldown_frames must be >= 0",
               self.cooldown_frames)  # fmt: skip
        _check(self.other_arm_margin_m >= 0, "arm_search.other_arm_margin_m must be >= 0",
               self.other_arm_margin_m)  # fmt: skip
        s = self.agreement_slack
        _check(s is None or s >= 0, "arm_search.agreement_slack must be >= 0 or None", s)


def _shipped_failure() -> FailureThresholds:
    return FailureThresholds(epsilon1_cm=3.0, epsilon2=0.7, epsilon3_mm=80.0, lost_overlap=0.3)


def _shipped_keep_better() -> KeepBetterConfig:
    return KeepBetterConfig(compare_all_tests=True, recheck_badness=2.4, agree_within_m=0.05)


def _shipped_arm_search() -> ArmSearchConfig:
    return ArmSearchConfig(badness=1.9, misplaced=MisplacedArmConfig(), cooldown_frames=3)


def _shipped_tracker() -> TrackerConfig:
    return TrackerConfig(use_labels=True, use_collision=True)


@dataclass
class HybridConfig:
    """Tracker with detector (re)initialization: the switching tests and both estimators.

    The defaults are the shipped system, the best this project has measured (the values and
    why: docs/experiments.md); ``configs/wei2012.yaml`` holds Wei's own (paper thresholds,
    none of the additions), for ablations. ``configs/hybrid.yaml`` spells the defaults out.
    """

    failure: FailureThresholds = field_doc(
        help="when a tracked frame has failed (Wei: 2.5 cm, 0.9, no surface test)",
        default_factory=_shipped_failure,
    )
    keep_better: KeepBetterConfig | None = field_doc(
        help="weigh a detection against the track instead of always taking it (None: Wei)",
        default_factory=_shipped_keep_better,
    )
    arm_search: ArmSearchConfig | None = field_doc(
        help="refit a hidden or misplaced arm on suspect frames (None: off, as in Wei)",
        default_factory=_shipped_arm_search,
    )
    behind_model: BehindModelConfig | None = field_doc(
        help="drop mask pixels that stay still far behind the tracked body (furniture touching "
        "the person: runtime.hybrid.behind_model; None: off, as in Wei). Shipped on: real "
        "depth 59.8 -> 59.4 mm (sit to stand 97.1 -> 94.2, stand to sit 85.8 -> 79.9), the "
        "synthetic sets within 0.07 mm (docs/experiments.md, twenty-seventh session)",
        default_factory=BehindModelConfig,
    )
    body_scale: BodyScaleConfig | None = field_doc(
        help="estimate the person's size from the first tracked frames when no body file is "
        "given (None: off; runtime-track and depthmocap.Tracker switch it off when given a "
        "body; shipped on: broad protocol 77.9 -> 73.2 mm, docs/experiments.md)",
        default_factory=BodyScaleConfig,
    )
    joint_offsets: str | None = field_doc(
        "joint_offsets.json",
        "move each output joint by its learned offset from the model's (shared.joint_offsets): "
        "a file, relative paths under the shipped models/ folder (None: the model's own "
        "joints; runtime-track and depthmocap.Tracker switch it off when given a body, "
        "whose joints the offsets were not fitted for)",
    )
    joint_confidence: str | None = field_doc(
        "joint_confidence.json",
        "report a joint observed when its learned confidence reaches the file's threshold "
        "(shared.joint_confidence: its confirmed area, its limb's visibility, its "
        "neighbour's area, the frame's fit, its distance to where the person leaves the "
        "image, its offset from the pelvis and where the forest sees its parts; a file, "
        "relative paths under the shipped models/ folder); None: "
        "the tracker's own area test (tracker.observed_joint_area_cm2). Output only: the "
        "poses do not change",
    )
    labels_from_recording: str | None = field_doc(
        None,
        "a synthetic recording whose ground-truth part labels stand in for the forest's "
        "(a diagnostic of what the forest's errors cost; the forest is then not loaded)",
    )
    hold_unseen_limbs: bool = field_doc(
        True,
        "a limb whose elbow and wrist (knee and ankle) the last tracked pose inferred keeps "
        "its angles: the prior predicts them at the last pose, not at their last velocity "
        "(runtime.hybrid.unseen_limbs; not in Wei). Tuning set, mean of trust regions 0.18, "
        "0.2, 0.22 rad: 48.20 -> 47.44 mm, better in each (docs/experiments.md)",
    )
    catch_up: bool = field_doc(
        True,
        "when frames were skipped since the last pose (a live stream that fell behind), a "
        "frame that passed its tests gets no second opinion: no recheck by the detector, no "
        "arm search; a failed frame still recovers. A file keeps every frame, so it never "
        "applies there (runtime.hybrid.estimator; False: always the full recovery). Broad "
        "protocol live, two runs alternated per recording: 57.4 -> 56.2 and 55.1 -> 53.5 "
        "mm, frames skipped 21.5 -> 18.6% and 16.4 -> 14.0% (docs/experiments.md, thirtieth "
        "session)",
    )
    look_back: LookBackConfig | None = field_doc(
        help="a recording read as a file: hold each estimate a few frames and refit the frames "
        "the hybrid doubted (detections, tracks the detector was asked about) backwards from "
        "the clean frame after them, keeping a refit that fits better (runtime.look_back; not "
        "in Wei; None: off). Broad tuning sets at 0.2 rad 38.64 -> 36.34 mm, report set "
        "44.40 -> 42.80 mm (mean of three trust regions), UTD-MHAD 56.3 -> 54.3 mm "
        "(docs/experiments.md, forty-seventh session); with its sweep over every frame "
        "(sweep_margin) 42.80 -> 41.82 mm and 54.3 -> 53.5 mm (forty-eighth session)",
        default_factory=LookBackConfig,
    )
    detector: DetectorConfig = field_doc(help="detector settings", default_factory=DetectorConfig)
    tracker: TrackerConfig = field_doc(
        help="tracker settings (shipped: the label and collision terms on)",
        default_factory=_shipped_tracker,
    )
