"""The hybrid's switching policy as tables: pure functions of signals and counters."""

from __future__ import annotations

import math

import pytest
from depthmocap.runtime.hybrid import (
    MAX_TURN_FRAMES,
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
    "signals, passed, keep, failed, recheck",
    [
        (GOOD, 1, None, False, False),
        (FAILED, 1, None, True, False),
        (SUSPECT, 1, KeepBetterConfig(recheck_badness=2.0), False, True),
        (SUSPECT, 1, KeepBetterConfig(recheck_badness=2.4), False, False),
        (GOOD, 1, KeepBetterConfig(recheck_badness=0.0), False, True),
        (SUSPECT, 9, None, False, False),  # rechecks need keep_better
        (FitSignals(math.nan, 0.95, 30.0), 1, None, True, False),  # NaN fails
    ],
)
def test_judge_track(signals, passed, keep, failed, recheck):
    verdict = judge_track(signals, SHIPPED.badness(signals), passed, SHIPPED, keep)
    assert (verdict.failed, verdict.recheck) == (failed, recheck)
    assert verdict.run_detector == (failed or recheck)


KEEP = KeepBetterConfig(compare_all_tests=True, max_turn_rad=1.6)
N = MAX_TURN_FRAMES
SURFACE_ONLY = KeepBetterConfig(compare_all_tests=False)
BETTER = FitSignals(1.0, 0.9, 60.0)  # badness 1.42 < FAILED badness 1.92; surface 60 > 20
WORSE = FitSignals(3.5, 0.6, 90.0)


@pytest.mark.parametrize(
    "track, detection, failed, turned, keep, expected",
    [
        # Better by badness: taken; worse: the track stays.
        (FAILED, Detection(True, BETTER, 0.1), True, 0, KEEP, Decision(False, 0)),
        (FAILED, Detection(True, WORSE, 0.1), True, 0, KEEP, Decision(True, 0)),
        # By the surface error alone the same detection loses.
        (FAILED, Detection(True, BETTER, 0.1), True, 0, SURFACE_ONLY, Decision(True, 0)),
        # Not refined: nothing to compare, taken.
        (FAILED, Detection(True, None, 0.1), True, 0, KEEP, Decision(False, 0)),
        # Turned round: not taken, counted while the track keeps failing ...
        (FAILED, Detection(True, BETTER, 3.0), True, 0, KEEP, Decision(True, 1)),
        # ... until it has turned MAX_TURN_FRAMES times in a row.
        (FAILED, Detection(True, BETTER, 3.0), True, N - 2, KEEP, Decision(True, N - 1)),
        (FAILED, Detection(True, BETTER, 3.0), True, N - 1, KEEP, Decision(False, N)),
        # A recheck never turns the track, nor counts.
        (FAILED, Detection(True, BETTER, 3.0), False, N - 1, KEEP, Decision(True, 0)),
        # No limit on the turn.
        (FAILED, Detection(True, BETTER, 3.0), True, 0, SURFACE_ONLY, Decision(True, 0)),
        # Nobody found: keep the track and forget the per-track memories.
        (FAILED, Detection(False), True, 2, KEEP, Decision(True, 0, forget=True)),
    ],
)
def test_choose(track, detection, failed, turned, keep, expected):
    assert choose(track, detection, failed, turned, SHIPPED, keep) == expected


def test_badness_and_failure_on_the_thresholds():
    on_all = FitSignals(3.0, 0.7, 80.0)
    assert SHIPPED.badness(on_all) == pytest.approx(3.0)
    assert not SHIPPED.failed(on_all)  # the tests are inclusive
    assert SHIPPED.failed(FitSignals(3.0, 0.7, 80.1))
