"""Fixed-lag smoothing of the output (runtime/export/fixed_lag.py): golden weights, averages
that keep straight-line motion and turns through 180 degrees, the delay line's order, runs
and flushing, and runtime-track's default per source."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
from depthmocap.runtime.export.fixed_lag import (
    FILE_FIXED_LAG,
    FixedLagSmoother,
    binomial_weights,
    smooth_joints,
    smooth_pose,
)
from depthmocap.runtime.track_cli import fixed_lag_frames

J = 16


class _Sink:
    """A result writer that keeps what reaches it."""

    def __init__(self):
        self.extra, self.rows, self.closed = {}, [], False

    @property
    def frames(self):
        return len(self.rows)

    def write_frame(self, index, time, status, joints, q, errors, observed=None):
        self.rows.append({"index": index, "status": status, "joints": joints, "q": q,
                          "errors": errors, "observed": observed})  # fmt: skip

    def close(self):
        self.closed = True
        return {"frames": len(self.rows)}


def _frame(i, speed=0.01):
    joints = np.arange(J * 3, dtype=np.float64).reshape(J, 3) * 0.01 + i * speed
    q = np.zeros(34)
    q[:3] = [0.1 * i, 0.0, 2.5]
    q[3:6] = [0.0, 0.05 * i, 0.0]  # a steady turn about y
    q[6:] = 0.01 * i
    return joints, q


def _feed(smoother, statuses, speed=0.01, wobble=None):
    for i, status in enumerate(statuses):
        joints, q = _frame(i, speed)
        if wobble is not None:
            joints = joints + wobble[i]
        lost = status == "lost"
        smoother.write_frame(
            i, i / 30, status, None if lost else joints, None if lost else q, {"i": i},
            None if lost else np.full(J, i % 2 == 0),
        )  # fmt: skip


def test_binomial_weights_golden():
    np.testing.assert_allclose(binomial_weights(0), [1.0])
    np.testing.assert_allclose(binomial_weights(1), [0.25, 0.5, 0.25])
    np.testing.assert_allclose(binomial_weights(2), np.array([1, 4, 6, 4, 1]) / 16)
    assert binomial_weights(7).sum() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="radius"):
        binomial_weights(-1)


def test_smooth_joints_skips_missing_joints_and_keeps_all_missing_as_nan():
    joints = np.zeros((3, 2, 3))
    joints[:, 0] = [[0, 0, 1], [0, 0, 2], [0, 0, 4]]
    joints[:, 1] = np.nan
    joints[1, 1] = [1, 1, 1]
    joints[2, 0, 1] = np.nan  # one coordinate missing: the joint is missing in that frame
    out = smooth_joints(joints, binomial_weights(1))
    np.testing.assert_allclose(out[0], [0, 0, (0.25 * 1 + 0.5 * 2) / 0.75])
    np.testing.assert_allclose(out[1], [1, 1, 1])
    assert np.isnan(smooth_joints(np.full((3, 1, 3), np.nan), binomial_weights(1))).all()


def test_smooth_pose_averages_angles_and_turns_through_half_a_turn():
    q = np.zeros((3, 34))
    q[:, 6] = [0.1, 0.2, 0.6]
    q[:, :3] = [[0, 0, 1], [0, 0, 2], [0, 0, 3]]
    # About z through 180 degrees: pi - 0.1, pi, and pi + 0.1 written as -(pi - 0.1).
    q[:, 5] = [np.pi - 0.1, np.pi, -(np.pi - 0.1)]
    out = smooth_pose(q, binomial_weights(1), centre=1)
    assert out[6] == pytest.approx(0.25 * 0.1 + 0.5 * 0.2 + 0.25 * 0.6)
    np.testing.assert_allclose(out[:3], [0, 0, 2])
    assert abs(out[5]) == pytest.approx(np.pi, abs=1e-9)  # not 0: the naive mean's answer
    np.testing.assert_allclose(out[3:5], 0, atol=1e-12)


def test_smooth_pose_symmetric_turn_keeps_the_centre_rotation():
    q = np.zeros((5, 34))
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    q[:, 3:6] = axis * np.array([0.6, 0.8, 1.0, 1.2, 1.4])[:, None]
    out = smooth_pose(q, binomial_weights(2), centre=2)
    np.testing.assert_allclose(out[3:6], axis * 1.0, atol=1e-12)


def test_straight_line_motion_passes_unchanged_and_late():
    sink = _Sink()
    smoother = FixedLagSmoother(sink, 2)
    _feed(smoother, ["tracked"] * 3)
    assert sink.frames == 1  # frame 0 has no neighbour before it: written as it is
    for i in range(3, 8):
        joints, q = _frame(i)
        smoother.write_frame(i, i / 30, "tracked", joints, q, {"i": i}, np.full(J, i % 2 == 0))
    assert [r["index"] for r in sink.rows] == [0, 1, 2, 3, 4, 5]
    smoother.close()
    assert sink.closed and [r["index"] for r in sink.rows] == list(range(8))
    for r in sink.rows:
        joints, q = _frame(r["index"])
        np.testing.assert_allclose(r["joints"], joints, atol=1e-12)
        np.testing.assert_allclose(r["q"], q, atol=1e-12)
        assert r["errors"] == {"i": r["index"]}
        np.testing.assert_array_equal(r["observed"], np.full(J, r["index"] % 2 == 0))
    assert sink.extra["fixed_lag_frames"] == 2


def test_jitter_is_averaged_and_ends_keep_symmetric_windows():
    rng = np.random.default_rng(0)
    wobble = rng.normal(0, 0.01, (10, J, 3))
    sink = _Sink()
    smoother = FixedLagSmoother(sink, 2)
    _feed(smoother, ["tracked"] * 10, speed=0.0, wobble=wobble)
    smoother.close()
    base = _frame(0, 0.0)[0]
    got = np.stack([r["joints"] for r in sink.rows]) - base
    np.testing.assert_allclose(got[0], wobble[0], atol=1e-12)  # no neighbour before it
    np.testing.assert_allclose(got[1], np.einsum("f,fjc->jc", [0.25, 0.5, 0.25], wobble[:3]))
    np.testing.assert_allclose(got[5], np.einsum("f,fjc->jc", binomial_weights(2), wobble[3:8]))
    np.testing.assert_allclose(got[9], wobble[9], atol=1e-12)
    assert np.abs(got[2:8]).mean() < 0.7 * np.abs(wobble[2:8]).mean()


def test_a_frame_without_a_pose_ends_the_run_in_order():
    sink = _Sink()
    smoother = FixedLagSmoother(sink, 1)
    wobble = np.zeros((7, J, 3))
    wobble[2] = 0.3  # the last frame before the loss must not reach frame 4's window
    _feed(smoother, ["tracked", "tracked", "detected", "lost", "tracked", "tracked", "tracked"],
          speed=0.0, wobble=wobble)  # fmt: skip
    assert [r["index"] for r in sink.rows] == [0, 1, 2, 3, 4, 5]
    lost = sink.rows[3]
    assert lost["status"] == "lost" and lost["joints"] is None and lost["q"] is None
    base = _frame(0, 0.0)[0]
    np.testing.assert_allclose(sink.rows[1]["joints"] - base, 0.25 * 0.3, atol=1e-12)
    np.testing.assert_allclose(sink.rows[2]["joints"] - base, 0.3, atol=1e-12)  # run's end
    np.testing.assert_allclose(sink.rows[4]["joints"], base, atol=1e-12)
    assert sink.rows[2]["status"] == "detected"
    smoother.close()
    assert [r["index"] for r in sink.rows] == list(range(7))


def test_radius_zero_passes_every_frame_through_at_once():
    sink = _Sink()
    smoother = FixedLagSmoother(sink, 0)
    rng = np.random.default_rng(1)
    wobble = rng.normal(0, 0.01, (4, J, 3))
    _feed(smoother, ["tracked", "detected", "lost", "tracked"], wobble=wobble)
    assert len(sink.rows) == 4
    np.testing.assert_array_equal(sink.rows[1]["joints"], _frame(1)[0] + wobble[1])
    assert sink.extra["fixed_lag_frames"] == 0


def test_close_writes_held_frames_even_when_the_writer_fails_after():
    class Failing(_Sink):
        def close(self):
            super().close()
            raise OSError("disk full")

    sink = Failing()
    smoother = FixedLagSmoother(sink, 2)
    _feed(smoother, ["tracked"] * 2)
    with pytest.raises(OSError):
        smoother.close()
    assert [r["index"] for r in sink.rows] == [0, 1]


@pytest.mark.parametrize(
    ("given", "realtime", "live", "expected"),
    [(None, False, False, FILE_FIXED_LAG), (None, True, False, 0), (None, False, True, 0),
     (1, True, False, 1), (0, False, False, 0)],
)  # fmt: skip
def test_runtime_track_default_per_source(given, realtime, live, expected):
    args = argparse.Namespace(fixed_lag=given, realtime=realtime)
    stream = argparse.Namespace(is_live=live)
    assert fixed_lag_frames(args, stream) == expected


def test_estimate_notes_reach_the_writer_through_the_smoother():
    class Noting(_Sink):
        notes = 0

        def note_estimated(self):
            self.notes += 1

    sink = Noting()
    smoother = FixedLagSmoother(sink, 2)
    smoother.note_estimated()
    smoother.note_estimated()
    assert sink.notes == 2
    FixedLagSmoother(_Sink(), 2).note_estimated()  # a writer without notes ignores them
