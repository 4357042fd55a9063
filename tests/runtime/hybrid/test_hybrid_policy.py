"""The hybrid's switching policy as tables: pure functions of signals and counters."""

from __future__ import annotations

import math

import pytest
from depthmocap.runtime.hybrid import (
    Decision,
    Detection,
    FailureThresholds,
    KeepBetterConfig,
    choose,
    judge_track,
)
from depthmocap.runtime.tracker.signals import FitSignals

SHIPPED = FailureThresholds(3.0, 0.7, 80.0)
GOOD = FitSignals(1.0, 0.95, 30.0)  # badness 1/3 + 0.05/0.3 + 30/80 = 0.875
SUSPECT = FitSignals(2.5, 0.8, 60.0)  # passes, badness 2.25
FAILED = FitSignals(4.0, 0.9, 20.0)  # depth error over epsilon1


@pytest.mark.parametrize(
    "signals, keep, failed, recheck",
    [
        (GOOD, None, False, False),
        (FAILED, None, True, False),
        (SUSPECT, KeepBetterConfig(recheck_badness=2.0), False, True),
        (SUSPECT, KeepBetterConfig(recheck_badness=2.4), False, False),
        (GOOD, KeepBetterConfig(recheck_badness=0.0), False, True),
        (SUSPECT, None, False, False),  # rechecks need keep_better
        (FitSignals(math.nan, 0.95, 30.0), None, True, False),  # NaN fails
    ],
)
def test_judge_track(signals, keep, failed, recheck):
    verdict = judge_track(signals, SHIPPED.badness(signals), SHIPPED, keep)
    assert (verdict.failed, verdict.recheck) == (failed, recheck)
    assert verdict.run_detector == (failed or recheck)


KEEP = KeepBetterConfig(compare_all_tests=True)
SURFACE_ONLY = KeepBetterConfig(compare_all_tests=False)
AGREE = KeepBetterConfig(compare_all_tests=True, agree_within_m=0.05)
BETTER = FitSignals(1.0, 0.9, 60.0)  # badness 1.42 < FAILED badness 1.92; surface 60 > 20
WORSE = FitSignals(3.5, 0.6, 90.0)


@pytest.mark.parametrize(
    "track, detection, keep, expected",
    [
        # Better by badness: taken; worse: the track stays.
        (FAILED, Detection(True, BETTER), KEEP, Decision(False)),
        (FAILED, Detection(True, WORSE), KEEP, Decision(True)),
        # By the surface error alone the same detection loses.
        (FAILED, Detection(True, BETTER), SURFACE_ONLY, Decision(True)),
        # Not refined: nothing to compare, taken.
        (FAILED, Detection(True, None), KEEP, Decision(False)),
        # Nobody found: keep the track and forget the per-track memories.
        (FAILED, Detection(False), KEEP, Decision(True, forget=True)),
        # A margin over a passed (rechecked) track: better by 0.83 (2.25 - 1.42) passes 0.8,
        # not 0.9; a failed track (1.92) gives way to the same detection whatever the margin.
        (
            SUSPECT,
            Detection(True, BETTER),
            KeepBetterConfig(True, take_margin=0.8),
            Decision(False),
        ),
        (SUSPECT, Detection(True, BETTER), KeepBetterConfig(True, take_margin=0.9), Decision(True)),
        (FAILED, Detection(True, BETTER), KeepBetterConfig(True, take_margin=0.9), Decision(False)),
        # A better detection within agree_within_m of the track found the same pose: the
        # track is kept as confirmed; farther, or unmeasured, it is taken; a worse one stays
        # refused whatever its gap.
        (FAILED, Detection(True, BETTER, 0.04), AGREE, Decision(True, agreed=True)),
        (FAILED, Detection(True, BETTER, 0.05), AGREE, Decision(True, agreed=True)),
        (FAILED, Detection(True, BETTER, 0.06), AGREE, Decision(False)),
        (FAILED, Detection(True, BETTER, None), AGREE, Decision(False)),
        (FAILED, Detection(True, BETTER, 0.04), KEEP, Decision(False)),
        (FAILED, Detection(True, WORSE, 0.04), AGREE, Decision(True)),
        (FAILED, Detection(True, None, 0.04), AGREE, Decision(True, agreed=True)),
    ],
)
def test_choose(track, detection, keep, expected):
    assert choose(track, detection, SHIPPED, keep) == expected


@pytest.mark.parametrize("margin", [-0.1, math.nan, math.inf])
def test_take_margin_must_be_a_finite_non_negative_number(margin):
    with pytest.raises(ValueError, match="take_margin"):
        KeepBetterConfig(take_margin=margin)


def test_take_margin_needs_the_badness_comparison():
    with pytest.raises(ValueError, match="take_margin needs compare_all_tests"):
        KeepBetterConfig(compare_all_tests=False, take_margin=0.15)
    assert KeepBetterConfig(compare_all_tests=False).take_margin == 0.0


def test_badness_and_failure_on_the_thresholds():
    on_all = FitSignals(3.0, 0.7, 80.0)
    assert SHIPPED.badness(on_all) == pytest.approx(3.0)
    assert not SHIPPED.failed(on_all)  # the tests are inclusive
    assert SHIPPED.failed(FitSignals(3.0, 0.7, 80.1))
