"""The One-Euro filter against golden values (a constant, a step, a ramp, its cutoff), its
SO(3) form at the rotation-vector wrap, and the pose/joint smoother."""

from __future__ import annotations

import math

import numpy as np
import pytest
from depthmocap.runtime.export.one_euro import (
    OneEuroFilter,
    PoseSmoother,
    RotationOneEuroFilter,
    SmoothingConfig,
    alpha,
)
from depthmocap.runtime.export.rotations import (
    matrix_to_quat,
    matrix_to_rotvec,
    quat_to_matrix,
    rotvec_to_matrix,
)
from depthmocap.shared import skeleton as sk

DT = 1 / 30


def run(cfg: SmoothingConfig, xs, dt: float = DT) -> np.ndarray:
    f = OneEuroFilter(cfg)
    return np.array([f(x, dt) for x in xs], dtype=np.float64)


def test_alpha_golden():
    # alpha = 1 / (1 + tau / T_e), tau = 1 / (2 pi fc): 2 pi / (2 pi + 30) at 1 Hz, 30 Hz.
    assert alpha(1.0, DT) == pytest.approx(0.17317071954915414, abs=1e-15)
    assert alpha(1.0, DT) == pytest.approx(2 * math.pi / (2 * math.pi + 30), abs=1e-15)


def test_constant_passes_unchanged():
    out = run(SmoothingConfig(min_cutoff=0.5, beta=2.0), [0.3] * 50)
    np.testing.assert_allclose(out, 0.3, rtol=0, atol=1e-15)


def test_step_without_beta_is_a_first_order_low_pass():
    out = run(SmoothingConfig(min_cutoff=1.0, beta=0.0), [0.0] + [1.0] * 10)
    # 1 - (1 - a)^n with a = 0.1731707...; golden values computed by hand from the equations.
    assert out[0] == 0.0
    np.testing.assert_allclose(out[[1, 2, 10]], [0.1731707, 0.3163533, 0.8506661], atol=1e-7)
    a = alpha(1.0, DT)
    np.testing.assert_allclose(out[1:], 1 - (1 - a) ** np.arange(1, 11), rtol=1e-14)


def test_step_with_beta_raises_the_cutoff():
    # n=1: dx = 30/s, dx^ = a_d * 30 = 5.19512, fc = 1 + 0.1 * 5.19512 = 1.519512 Hz,
    # alpha(fc) = 0.2414162: faster than the 0.1731707 of beta = 0.
    f = OneEuroFilter(SmoothingConfig(min_cutoff=1.0, beta=0.1, d_cutoff=1.0))
    out = [float(f(x, DT)) for x in [0.0, 1.0, 1.0, 1.0]]
    np.testing.assert_allclose(out, [0.0, 0.2414162, 0.4162062, 0.5452699], atol=1e-7)
    # After the step the raw speed is 0: dx^ decays by (1 - a_d) per step.
    a_d = alpha(1.0, DT)
    assert float(f.cutoff) == pytest.approx(1.0 + 0.1 * 30 * a_d * (1 - a_d) ** 2, rel=1e-12)


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_ramp_lags_by_speed_over_two_pi_cutoff(beta):
    # Slope v = 1 m/s: the speed estimate converges to v, fc to min_cutoff + beta v, and a
    # first-order low pass follows a ramp with the steady lag v tau = v / (2 pi fc).
    f = OneEuroFilter(SmoothingConfig(min_cutoff=1.0, beta=beta, d_cutoff=1.0))
    for i in range(600):
        y = f(i * DT, DT)
    assert float(f.cutoff) == pytest.approx(1.0 + beta, rel=1e-9)
    assert 599 * DT - float(y) == pytest.approx(1 / (2 * math.pi * (1.0 + beta)), rel=1e-9)
    # Golden: 0.1591549 m at beta 0, 0.0795775 m at beta 1.
    assert 599 * DT - float(y) == pytest.approx([0.1591549, 0.0795775][int(beta)], abs=1e-7)


def test_gain_at_the_cutoff_frequency():
    # beta = 0: a sine at fc comes out with the gain of the discrete first-order low pass,
    # |a / (1 - (1 - a) e^{-i w T})|, close to the continuous filter's 1/sqrt(2) at 300 Hz.
    fc, rate = 1.0, 300.0
    t = np.arange(0, 20, 1 / rate)
    out = run(SmoothingConfig(min_cutoff=fc, beta=0.0), np.sin(2 * np.pi * fc * t), 1 / rate)
    a = alpha(fc, 1 / rate)
    gain = abs(a / (1 - (1 - a) * np.exp(-2j * np.pi * fc / rate)))
    measured = np.abs(out[t > 10]).max()
    assert measured == pytest.approx(gain, rel=2e-3)
    assert measured == pytest.approx(1 / math.sqrt(2), rel=0.02)


def test_elements_are_filtered_independently_and_reset_restarts():
    f = OneEuroFilter(SmoothingConfig(min_cutoff=1.0, beta=0.0))
    f(np.zeros(2), DT)
    out = f(np.array([1.0, 0.0]), DT)
    np.testing.assert_allclose(out, [alpha(1.0, DT), 0.0])
    f.reset()
    np.testing.assert_array_equal(f(np.array([5.0, 6.0]), DT), [5.0, 6.0])


@pytest.mark.parametrize("bad", [dict(min_cutoff=0.0), dict(d_cutoff=-1.0), dict(beta=-0.1)])
def test_config_validation(bad):
    with pytest.raises(ValueError):
        OneEuroFilter(SmoothingConfig(**bad))


# ---- rotations ------------------------------------------------------------------------------


def test_rotation_helpers_round_trip():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(200, 3))
    v *= (rng.uniform(0, np.pi, 200) / np.linalg.norm(v, axis=1))[:, None]
    r = rotvec_to_matrix(v)
    np.testing.assert_allclose(matrix_to_rotvec(r), v, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(r)), r, atol=1e-12)
    # 180 degrees about x (a person facing the camera): w = 0, x = 1.
    np.testing.assert_allclose(matrix_to_quat(np.diag([1.0, -1.0, -1.0])), [1, 0, 0, 0])


def test_rotation_filter_is_wrap_free_at_pi():
    # The same rotation (180 degrees about x) written as (pi,0,0) and (-pi,0,0) in turn is a
    # constant: the output must not swing through the identity.
    f = RotationOneEuroFilter(SmoothingConfig(min_cutoff=1.0, beta=1.0))
    for i in range(20):
        out = f([(-1) ** i * np.pi, 0.0, 0.0], DT)
        np.testing.assert_allclose(rotvec_to_matrix(out), np.diag([1.0, -1.0, -1.0]), atol=1e-12)


def test_rotation_filter_follows_a_turn_through_pi_like_the_scalar_filter():
    # Turning about x at 1 rad/s through pi: the rotation vector flips sign there, the
    # filtered angle does not, and lags exactly as the scalar filter lags the angle.
    cfg = SmoothingConfig(min_cutoff=1.0, beta=0.5)
    rot, scalar = RotationOneEuroFilter(cfg), OneEuroFilter(cfg)
    angles = np.pi - 1.0 + np.arange(60) * DT  # 2.14 .. 4.11 rad
    for ang in angles:
        wrapped = (ang + np.pi) % (2 * np.pi) - np.pi  # rotation vector angle in [-pi, pi)
        out = rot([wrapped, 0.0, 0.0], DT)
        ref = float(scalar(ang, DT))
        np.testing.assert_allclose(rotvec_to_matrix(out), rotvec_to_matrix([ref, 0, 0]), atol=1e-9)


def test_pose_smoother_filters_q_by_parts_and_uses_timestamps():
    cfg = SmoothingConfig(min_cutoff=1.0, beta=0.0)
    s = PoseSmoother(cfg, fps=30)
    q0 = np.zeros(sk.NUM_DOFS)
    q0[2], q0[3] = 2.5, np.pi
    np.testing.assert_array_equal(s.pose(0.0, q0), q0)
    q1 = q0.copy()
    q1[0], q1[6] = 0.1, 0.2
    q1[3] = -np.pi  # the same orientation written the other way
    out = s.pose(0.1, q1)  # dt from the timestamps: 0.1 s
    a = alpha(1.0, 0.1)
    np.testing.assert_allclose(out[[0, 6]], [0.1 * a, 0.2 * a], rtol=1e-12)
    np.testing.assert_allclose(rotvec_to_matrix(out[3:6]), np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    s.reset()
    np.testing.assert_array_equal(s.pose(0.2, q1), q1)
    # Joints: a non-finite row restarts the joint filter and passes through.
    j = np.ones((16, 3))
    s.joints(0.0, j)
    np.testing.assert_allclose(s.joints(1 / 30, 2 * j), 1 + alpha(1.0, DT), rtol=1e-12)
    j[3, 1] = np.nan
    assert np.isnan(s.joints(2 / 30, j)[3, 1])
