"""The runner-up: the pose a choice did not take, fitted on and switched to when it wins."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depthmocap.runtime.estimator import estimate_frame
from depthmocap.runtime.hybrid import RunnerUpConfig
from depthmocap.runtime.hybrid import hybrid_config as config_from_mapping
from depthmocap.runtime.hybrid.runner_up import RunnerUp, runner_up_verdict
from depthmocap.shared.config import ConfigError
from test_hybrid import (
    FakeResult,
    FakeTracker,
    frame_of,
    make_hybrid,
    scene,  # noqa: F401  (the fixture)
)


def test_verdict_table():
    cfg = RunnerUpConfig(frames=8, margin=0.2, confirm_frames=2)
    assert runner_up_verdict(1.5, 1.2, 0, cfg) == (1, False)  # won by 0.3: one win
    assert runner_up_verdict(1.5, 1.2, 1, cfg) == (2, True)  # the second in a row: switch
    assert runner_up_verdict(1.5, 1.35, 1, cfg) == (0, False)  # within the margin: no win
    assert runner_up_verdict(1.5, 1.3, 1, cfg) == (0, False)  # exactly the margin: no win
    assert runner_up_verdict(math.nan, 0.1, 1, cfg) == (0, False)  # NaN on either side
    assert runner_up_verdict(1.5, math.nan, 1, cfg) == (0, False)
    once = RunnerUpConfig(margin=0.0, confirm_frames=1)
    assert runner_up_verdict(1.0, 0.99, 0, once) == (1, True)


def test_history_and_expiry():
    q0, q1 = torch.zeros(34), torch.ones(34)
    r = RunnerUp(q0, None, 10, None, 10)
    moved = r.moved_on(q1, 11, 1)
    assert moved.q is q1 and moved.q_prev is q0 and (moved.index, moved.index_prev) == (11, 10)
    assert moved.born == 10 and moved.wins == 1
    cfg = RunnerUpConfig(frames=3)
    assert not r.expired(13, cfg) and r.expired(14, cfg)


@pytest.mark.parametrize(
    "values, match",
    [({"frames": 0}, "frames"), ({"margin": -0.1}, "margin"), ({"margin": math.nan}, "margin"),
     ({"confirm_frames": 0}, "confirm_frames")],
)  # fmt: skip
def test_bad_settings_are_rejected(values, match):
    with pytest.raises(ConfigError, match=match):
        RunnerUpConfig(**values)
    with pytest.raises(ConfigError, match=match):
        config_from_mapping({"runner_up": values})


def test_the_preset_can_switch_it_on():
    cfg = config_from_mapping({"runner_up": {"frames": 5}})
    assert cfg.runner_up == RunnerUpConfig(frames=5)
    assert config_from_mapping({}).runner_up is None  # off unless asked for


class PreferringTracker(FakeTracker):
    """The fake tracker whose fits from ``good`` fit well (1 cm depth error) and from any other
    pose pass only just (2.4 cm; Wei's 2.5 cm test); the listed calls fail (5 cm)."""

    def __init__(self, fail_calls=()):
        super().__init__(fail_calls=fail_calls, surface_mm=1e4)
        self.good: torch.Tensor | None = None

    def step(self, depth, mask, q_prev, q_prev2=None, labels=None):
        self.calls += 1
        good = self.good is not None and torch.allclose(q_prev, self.good)
        err = 5.0 if self.calls in self.fail else (1.0 if good else 2.4)
        return FakeResult(q_prev.clone(), err, 0.95, self.surface_mm)


def run_switch(scene, runner_up, frames=6):  # noqa: F811
    """Frame 0 detected (its pose fits well from then on); frame 1 tracked; frame 2's track
    fails and the detection (a real refit) is taken; the detection's track only just passes
    after that. Returns the estimates, the estimator and the first detection's pose."""
    q, depth, labels, mask = scene
    tracker = PreferringTracker(fail_calls={2})
    est, _ = make_hybrid(scene, tracker, refine_iterations=1, keep_better=True,
                         runner_up=runner_up)  # fmt: skip
    got = [estimate_frame(est, frame_of(depth, 0, mask))]
    tracker.good = est.state.q_prev.clone()
    got += [estimate_frame(est, frame_of(depth, i, mask)) for i in range(1, frames)]
    return got, est, tracker.good


def test_the_track_switches_to_a_runner_up_that_keeps_fitting_better(scene):  # noqa: F811
    got, est, first = run_switch(scene, RunnerUpConfig(frames=8, margin=0.2, confirm_frames=2))
    assert [g.status for g in got] == ["detected", "tracked", "detected"] + ["tracked"] * 3
    # Frame 3: the runner-up (the old track) wins once; frame 4: twice, the track switches.
    assert "runner_up_fitted" in got[3].errors and "runner_up_taken" not in got[3].errors
    assert got[4].errors["runner_up_taken"] == 1.0
    np.testing.assert_allclose(got[4].q, first.double().numpy(), atol=1e-6)
    assert got[4].errors["depth_error_cm"] == 1.0  # the runner-up's own fit is reported
    # The track goes on from the runner-up's history; no runner-up is left to fit.
    assert torch.allclose(est.state.q_prev2, first) and est.state.runner_up is None
    assert "runner_up_fitted" not in got[5].errors
    np.testing.assert_allclose(got[5].q, first.double().numpy(), atol=1e-6)


@pytest.mark.parametrize(
    "runner_up", [None, RunnerUpConfig(confirm_frames=3), RunnerUpConfig(frames=1),
                  RunnerUpConfig(margin=0.6)],
)  # fmt: skip
def test_no_switch_when_off_unconfirmed_expired_or_within_the_margin(scene, runner_up):  # noqa: F811
    """Off; a third win needed within frames 3-4; carried for one frame only; a margin wider
    than the 0.56 the runner-up wins by: the detection's track goes on."""
    got, est, first = run_switch(scene, runner_up, frames=5)
    assert not any("runner_up_taken" in g.errors for g in got)
    assert not np.allclose(got[4].q, first.double().numpy(), atol=1e-6)
    fitted = [i for i, g in enumerate(got) if "runner_up_fitted" in g.errors]
    expected = {None: [], 1: [3]}.get(None if runner_up is None else runner_up.frames, [3, 4])
    assert fitted == expected


def test_a_kept_track_carries_the_detection_and_a_lost_frame_forgets_it(scene):  # noqa: F811
    """The track fails but fits better than the detection (surface 0): kept, and the
    refined detection becomes the runner-up with no history; a frame without a person drops
    it with the rest of the track."""
    q, depth, labels, mask = scene
    tracker = FakeTracker(fail_calls={2}, surface_mm=0.0)
    est, _ = make_hybrid(scene, tracker, refine_iterations=1, keep_better=True,
                         runner_up=RunnerUpConfig())  # fmt: skip
    got = [estimate_frame(est, frame_of(depth, i, mask)) for i in range(3)]
    assert got[2].status == "tracked" and "kept_over_detector" in got[2].errors
    runner = est.state.runner_up
    assert runner is not None and runner.q_prev is None and runner.born == 2
    assert not torch.equal(runner.q, est.state.q_prev)  # the detection's pose, not the track's
    estimate_frame(est, frame_of(depth * 0, 3, torch.zeros_like(mask)))
    assert est.state.runner_up is None
