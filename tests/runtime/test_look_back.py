"""The look-back stage (runtime.look_back): which frames it refits, in which order, from what,
what it replaces, and that nothing estimated is lost."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from depthmocap.runtime.estimator import PoseEstimate
from depthmocap.runtime.look_back import (
    LookBack,
    LookBackConfig,
    is_clean,
    is_doubtful,
    looked_back,
    refit_span,
)
from depthmocap.shared.config import ConfigError


@dataclass
class FakeFrame:
    index: int
    has_person: bool = True


def estimate(tag: float, status="tracked", badness=1.0, **flags) -> PoseEstimate:
    """A pose whose q[0] is ``tag`` and whose fit had ``badness`` (in ``depth_error_cm``)."""
    q = np.zeros(34)
    q[0] = tag
    errors = {"depth_error_cm": badness, **flags}
    return PoseEstimate(q, np.zeros((16, 3)), status, errors)


class FakeEstimator:
    """Refits score ``refit_badness[index]`` (default 0.5) and record what they started from."""

    def __init__(self, refit_badness=None):
        self.refit_badness = refit_badness or {}
        self.calls = []  # (index, later tag, later2 tag or None, velocity scale)

    def refit_from_later(self, frame, later, later2, velocity_scale):
        self.calls.append(
            (frame.index, later.q[0], None if later2 is None else later2.q[0], velocity_scale)
        )
        bad = self.refit_badness.get(frame.index, 0.5)
        return estimate(100 + frame.index, badness=bad), bad

    def badness_of(self, est):
        return est.errors.get("depth_error_cm", math.nan)


def run(stage, items):
    out = []
    for i, est in enumerate(items):
        out += stage.push(FakeFrame(i), est)
    return out


D = dict(status="detected", badness=2.0)  # a re-detection that fitted with badness 2
K = dict(badness=2.0, kept_over_detector=1.0)  # a failed track kept over a detection


@pytest.mark.parametrize(
    ("doubtful", "clean", "lead_in", "span"),
    [
        ([], [], 2, 0),
        ([0, 0], [1, 1], 2, 0),  # nothing doubtful
        ([0, 1], [1, 0], 2, 0),  # the newest is doubtful: nothing to start from
        ([1, 0], [0, 1], 2, 1),
        ([0, 0, 1, 1, 0], [1, 1, 0, 0, 1], 2, 4),  # two doubtful, two clean before
        ([0, 0, 0, 1, 1, 0], [1, 1, 1, 0, 0, 1], 1, 3),
        ([0, 1, 0, 1, 0], [1, 0, 1, 0, 1], 2, 2),  # lead-in stops at the earlier doubtful
        ([0, 1, 0], [0, 0, 1], 2, 1),  # lead-in only over clean frames (a lost one stops it)
    ],
)
def test_refit_span_table(doubtful, clean, lead_in, span):
    assert refit_span([bool(d) for d in doubtful], [bool(c) for c in clean], lead_in) == span


def test_doubtful_and_clean():
    assert is_doubtful(estimate(0, **D)) and not is_clean(estimate(0, **D))
    assert is_doubtful(estimate(0, **K)) and not is_clean(estimate(0, **K))
    assert is_doubtful(estimate(0, rechecked=1.0))
    assert not is_doubtful(estimate(0)) and is_clean(estimate(0))
    gone = PoseEstimate(None, None, "lost")
    assert not is_doubtful(gone) and not is_clean(gone)


def test_zero_frames_passes_every_estimate_through_at_once():
    stage = LookBack(FakeEstimator(), 0)
    for i, est in enumerate([estimate(0, **D), estimate(1)]):
        assert stage.push(FakeFrame(i), est) == [(FakeFrame(i), est)]
    assert stage.flush() == []


def test_estimates_leave_in_order_held_frames_deep():
    stage = LookBack(FakeEstimator(), 3)
    items = [estimate(i) for i in range(6)]
    out = run(stage, items)
    assert [f.index for f, _ in out] == [0, 1, 2]  # three held behind the newest
    rest = stage.flush()
    assert [f.index for f, _ in out + rest] == list(range(6))


def test_a_doubtful_run_is_refitted_backwards_from_the_clean_frame_after_it():
    fake = FakeEstimator(refit_badness={3: 0.5, 2: 3.0, 1: 0.1, 0: 0.1})
    stage = LookBack(fake, 8, lead_in=1)
    items = [estimate(0), estimate(1), estimate(2, **D), estimate(3, **K), estimate(4), estimate(5)]
    out = run(stage, items) + stage.flush()
    # Refits start when frame 5 arrives: frame 4 is the clean pose, frame 5 its velocity;
    # newest first, each from the refit after it (taken or not); one lead-in frame (1).
    assert fake.calls == [(3, 4.0, 5.0, 1.0), (2, 103.0, 4.0, 1.0), (1, 102.0, 103.0, 1.0)]
    by_index = {f.index: e for f, e in out}
    assert by_index[3].q[0] == 103 and by_index[3].errors["looked_back"] == 1.0
    assert by_index[3].status == "tracked"  # a kept track's status stays
    assert by_index[2].q[0] == 2 and "looked_back" not in by_index[2].errors  # 3.0 > 2.0
    assert by_index[1].q[0] == 101  # the lead-in frame fitted better backwards (0.1 < 1.0)
    assert by_index[0].q[0] == 0  # before the lead-in: not refitted
    assert (stage.refits, stage.revised) == (3, 2)


def test_a_refit_replaces_only_a_worse_fit_and_keeps_the_status():
    fake = FakeEstimator(refit_badness={1: 0.5, 0: 2.5})
    stage = LookBack(fake, 8, lead_in=0)
    items = [estimate(0, **D), estimate(1, **D), estimate(2), estimate(3)]
    out = dict((f.index, e) for f, e in run(stage, items) + stage.flush())
    assert out[1].q[0] == 101 and out[1].status == "detected"  # 0.5 < 2.0: replaced
    assert out[0].q[0] == 0  # 2.5 > 2.0: kept
    assert (stage.refits, stage.revised) == (2, 1)


def test_an_unknown_forward_badness_is_never_replaced():
    fake = FakeEstimator(refit_badness={0: 0.0})
    stage = LookBack(fake, 4, lead_in=0)
    out = run(stage, [estimate(0, **{**D, "badness": math.nan}), estimate(1)]) + stage.flush()
    assert out[0][1].q[0] == 0 and stage.refits == 1 and stage.revised == 0


def test_flush_looks_back_from_the_last_frame_without_a_velocity():
    fake = FakeEstimator()
    stage = LookBack(fake, 8, lead_in=0)
    run(stage, [estimate(0), estimate(1, **D), estimate(2)])
    assert fake.calls == []  # frame 2's successor has not come yet
    out = stage.flush()
    assert fake.calls == [(1, 2.0, None, 1.0)]
    assert [e.q[0] for _, e in out] == [0, 101, 2]


def test_a_frame_without_a_person_ends_the_refits():
    fake = FakeEstimator()
    stage = LookBack(fake, 8, lead_in=0)
    frames = [FakeFrame(0), FakeFrame(1, has_person=False), FakeFrame(2), FakeFrame(3)]
    items = [estimate(0, **D), estimate(1, **D), estimate(2, **D), estimate(3)]
    for f, e in zip(frames, items, strict=True):
        stage.push(f, e)
    stage.flush()
    assert [c[0] for c in fake.calls] == [2]


def test_only_held_frames_are_revised():
    fake = FakeEstimator()
    stage = LookBack(fake, 3, lead_in=2)
    items = [estimate(i, **D) for i in range(6)] + [estimate(6), estimate(7)]
    out = run(stage, items) + stage.flush()
    # When frame 7 arrives, frames 4-7 are held: 6 is the clean pose, 4 and 5 are refitted.
    assert [c[0] for c in fake.calls] == [5, 4]
    assert [e.q[0] for _, e in out] == [0, 1, 2, 3, 104, 105, 6, 7]


def test_the_velocity_follows_a_live_stream_s_frame_indices():
    fake = FakeEstimator()
    stage = LookBack(fake, 8, lead_in=0)
    for i, e in [(0, estimate(0, **D)), (2, estimate(2)), (3, estimate(3))]:
        stage.push(FakeFrame(i), e)
    # Frame 0 lies two frames before frame 2, whose velocity spans one frame (2 -> 3).
    assert fake.calls == [(0, 2.0, 3.0, 2.0)]


def test_looked_back_yields_what_is_held_before_the_source_s_error():
    def pairs():
        yield FakeFrame(0), estimate(0)
        yield FakeFrame(1), estimate(1, **D)
        raise OSError("stream broke")

    seen = []
    with pytest.raises(OSError, match="stream broke"):
        for frame, _ in looked_back(pairs(), LookBack(FakeEstimator(), 8)):
            seen.append(frame.index)
    assert seen == [0, 1]


def test_looked_back_passes_everything_on_in_order():
    items = [(FakeFrame(i), estimate(i, **(D if i in (2, 3) else {}))) for i in range(7)]
    out = list(looked_back(iter(items), LookBack(FakeEstimator(), 4, lead_in=0)))
    assert [f.index for f, _ in out] == list(range(7))
    assert [e.q[0] for _, e in out] == [0, 1, 102, 103, 4, 5, 6]


@pytest.mark.parametrize("bad", [dict(frames=-1), dict(frames=61), dict(lead_in=-1)])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ConfigError):
        LookBackConfig(**bad)
    if "frames" in bad and bad["frames"] < 0:
        with pytest.raises(ValueError):
            LookBack(FakeEstimator(), bad["frames"])


def test_a_suspect_track_is_doubted_when_asked():
    """With suspect_badness, a passed track fitted worse than it is refitted too (its own
    badness is its ``depth_error_cm`` here); without, it is a clean frame."""
    items = [estimate(0), estimate(1, badness=3.0), estimate(2), estimate(3)]
    fake = FakeEstimator()
    stage = LookBack(fake, 8, lead_in=0, suspect_badness=2.5)
    out = dict((f.index, e) for f, e in run(stage, items) + stage.flush())
    assert [c[0] for c in fake.calls] == [1] and out[1].q[0] == 101
    plain = FakeEstimator()
    stage = LookBack(plain, 8, lead_in=0)
    run(stage, items)
    stage.flush()
    assert plain.calls == []
    with pytest.raises(ConfigError):
        LookBackConfig(suspect_badness=-1.0)


@pytest.mark.parametrize(
    ("given", "realtime", "live", "held", "expected"),
    [(None, False, False, 12, 12), (None, True, False, 12, 0), (None, False, True, 12, 0),
     (None, False, False, None, 0), (5, True, False, 12, 5), (0, False, False, 12, 0)],
)  # fmt: skip
def test_runtime_track_holds_a_file_by_default_and_a_live_stream_not(
    given, realtime, live, held, expected
):
    import argparse
    from types import SimpleNamespace

    from depthmocap.runtime.track_cli import look_back_frames

    args = argparse.Namespace(look_back=given, realtime=realtime)
    stream = argparse.Namespace(is_live=live)
    cfg = None if held is None else LookBackConfig(frames=held)
    estimator = SimpleNamespace(cfg=SimpleNamespace(look_back=cfg), refit_from_later=None)
    assert look_back_frames(args, stream, estimator) == expected


def test_a_sweep_refits_every_frame_once_in_blocks_from_the_newest():
    """sweep_margin: when the oldest held frame would leave unswept, every unswept frame but
    the newest is refitted newest to oldest, each from the two chosen poses after it; the
    rest at the end of the stream. Each frame once, the last one never (nothing after it)."""
    fake = FakeEstimator(refit_badness={i: 0.5 for i in range(10)} | {4: 0.95, 6: 3.0})
    stage = LookBack(fake, 3, lead_in=0, sweep_margin=0.1)
    out = dict((f.index, e) for f, e in run(stage, [estimate(i) for i in range(8)]) + stage.flush())
    # Frame 3 arrives with 0-3 held: 2, 1, 0 from 3. Frame 6 arrives with 3-6 held: 5, 4, 3
    # from 6; frame 6's refit is worse (3.0), so frame 5 starts from 6's own pose and 5's
    # refit (taken) gives 4 its start. At the end: 6 from 7.
    assert [(c[0], c[1], c[2]) for c in fake.calls] == [
        (2, 3.0, None), (1, 102.0, 3.0), (0, 101.0, 102.0),
        (5, 6.0, None), (4, 105.0, 6.0), (3, 4.0, 105.0),
        (6, 7.0, None),
    ]  # fmt: skip
    assert [out[i].q[0] for i in range(8)] == [100, 101, 102, 103, 4, 105, 6, 7]
    # Frame 4's refit (0.95) is better than its 1.0 by less than the margin: not taken.
    assert out[0].errors["swept"] == 1.0 and "swept" not in out[4].errors
    assert (stage.refits, stage.revised) == (7, 5)


def test_a_sweep_keeps_the_status_and_restarts_after_a_frame_without_a_pose():
    fake = FakeEstimator()
    stage = LookBack(fake, 8, lead_in=0, sweep_margin=0.0)
    items = [estimate(0, status="detected"), estimate(1), PoseEstimate(None, None, "lost"),
             estimate(3), estimate(4)]  # fmt: skip
    out = dict((f.index, e) for f, e in run(stage, items) + stage.flush())
    # The look-back refits the detection 0 from 1 when 2 arrives; at the end the sweep: 3
    # from 4; 2 has no pose, so 1 is not refitted but starts the chain again; 0 from 1.
    assert [c[0] for c in fake.calls] == [0, 3, 0]
    assert out[0].status == "detected" and out[0].q[0] == 100 and out[2].q is None
    with pytest.raises(ConfigError):
        LookBackConfig(sweep_margin=-0.1)
