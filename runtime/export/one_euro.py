"""The One-Euro filter (Casiez, Roussel and Vogel, "1 Euro Filter: A Simple Speed-based
Low-pass Filter for Noisy Input in Interactive Systems", CHI 2012) for the live outputs.

A first-order low-pass filter whose cutoff rises with speed: still poses lose their jitter,
fast motion keeps little lag. Per sample ``x_i`` at time step ``T_e`` (seconds):

    alpha(fc)  = 1 / (1 + tau / T_e),   tau = 1 / (2 pi fc)
    dx_i       = (x_i - x_(i-1)) / T_e                      (raw speed, 0 at the first sample)
    dx^_i      = alpha(d_cutoff) dx_i + (1 - alpha(d_cutoff)) dx^_(i-1)
    fc_i       = min_cutoff + beta |dx^_i|
    x^_i       = alpha(fc_i) x_i + (1 - alpha(fc_i)) x^_(i-1)      (x^_0 = x_0)

Every coordinate is filtered on its own (its own speed and cutoff). The speed is the raw
difference of successive samples, as in the authors' reference implementation, so a ramp of
slope v is followed with the steady lag ``v / (2 pi (min_cutoff + beta |v|))``.

Poses (:class:`PoseSmoother`) are filtered in their own coordinates: the root position and the
28 joint angles of q as above (the angles are per-DoF, bounded by their limits, and change
little from frame to frame, so they never wrap), and the root orientation on SO(3), where the
difference ``x_i - x^_(i-1)`` is the rotation vector of ``R^_(i-1)^T R_i`` and the update turns
``R^`` by ``alpha`` of it. That is wrap-free: a person facing the camera has the root rotation
vector (pi, 0, 0), right at the point where rotation vectors jump to (-pi, 0, 0).

Tuning (the paper's procedure): with ``beta = 0`` lower ``min_cutoff`` until a still person no
longer jitters, then raise ``beta`` until fast moves no longer lag. Speeds are in metres or
radians per second, so one ``beta`` serves positions and angles alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from depthmocap.shared.config import field_doc

from .rotations import matrix_to_rotvec, rotvec_to_matrix

__all__ = ["SmoothingConfig", "OneEuroFilter", "RotationOneEuroFilter", "PoseSmoother", "alpha"]


@dataclass
class SmoothingConfig:
    """Parameters of the One-Euro filter of the live outputs (``runtime-track --smooth``)."""

    min_cutoff: float = field_doc(
        1.0,
        "cutoff frequency at rest, Hz: lower removes more jitter from a still pose but lags "
        "more on slow moves",
    )
    beta: float = field_doc(
        1.0,
        "speed coefficient, 1/(m or rad): the cutoff grows by beta * |speed| (m/s, rad/s); "
        "higher follows fast moves with less lag",
    )
    d_cutoff: float = field_doc(1.0, "cutoff frequency of the speed estimate, Hz")

    def validate(self) -> None:
        for name in ("min_cutoff", "d_cutoff"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"smoothing {name} must be a positive number of Hz, got {v}")
        if not (math.isfinite(self.beta) and self.beta >= 0):
            raise ValueError(f"smoothing beta must be >= 0, got {self.beta}")


def alpha(cutoff, dt: float):
    """Smoothing factor of a first-order low-pass with ``cutoff`` (Hz) at step ``dt`` (s)."""
    tau = 1.0 / (2.0 * np.pi * cutoff)
    return 1.0 / (1.0 + tau / dt)


class OneEuroFilter:
    """One-Euro filter of arrays of a fixed shape, each element on its own.

    Args:
        config: the filter parameters.
    Attributes:
        cutoff: the cutoff (Hz) of the last step, per element (None before the first).
    """

    def __init__(self, config: SmoothingConfig | None = None) -> None:
        self.config = config or SmoothingConfig()
        self.config.validate()
        self.reset()

    def reset(self) -> None:
        """Forget the past: the next sample passes through unchanged."""
        self._x_raw: np.ndarray | None = None
        self._x_hat: np.ndarray | None = None
        self._dx_hat: np.ndarray | None = None
        self.cutoff: np.ndarray | None = None

    def __call__(self, x, dt: float) -> np.ndarray:
        """Filter sample ``x`` taken ``dt`` seconds after the previous one."""
        x = np.array(x, dtype=np.float64)
        if self._x_hat is None:
            self._x_raw, self._x_hat, self._dx_hat = x, x.copy(), np.zeros_like(x)
            self.cutoff = np.full_like(x, self.config.min_cutoff)
            return x.copy()
        cfg = self.config
        dx = (x - self._x_raw) / dt
        self._dx_hat = self._dx_hat + alpha(cfg.d_cutoff, dt) * (dx - self._dx_hat)
        self.cutoff = cfg.min_cutoff + cfg.beta * np.abs(self._dx_hat)
        self._x_hat = self._x_hat + alpha(self.cutoff, dt) * (x - self._x_hat)
        self._x_raw = x
        return self._x_hat.copy()


class RotationOneEuroFilter:
    """One-Euro filter of a rotation on SO(3) (module docstring); rotation vectors in and out.

    The speed is the rotation vector of ``R_(i-1)^T R_i`` over ``dt`` (per axis of the body
    frame), the step turns the filtered rotation ``alpha`` of the way towards the sample.
    """

    def __init__(self, config: SmoothingConfig | None = None) -> None:
        self.config = config or SmoothingConfig()
        self.config.validate()
        self.reset()

    def reset(self) -> None:
        self._r_raw: np.ndarray | None = None
        self._r_hat: np.ndarray | None = None
        self._dx_hat = np.zeros(3)
        self.cutoff: np.ndarray | None = None

    def __call__(self, rotvec, dt: float) -> np.ndarray:
        r = rotvec_to_matrix(np.asarray(rotvec, dtype=np.float64))
        if self._r_hat is None:
            self._r_raw, self._r_hat, self._dx_hat = r, r, np.zeros(3)
            self.cutoff = np.full(3, self.config.min_cutoff)
            return matrix_to_rotvec(r)
        cfg = self.config
        dx = matrix_to_rotvec(self._r_raw.T @ r) / dt
        self._dx_hat = self._dx_hat + alpha(cfg.d_cutoff, dt) * (dx - self._dx_hat)
        self.cutoff = cfg.min_cutoff + cfg.beta * np.abs(self._dx_hat)
        # One rotation, so one factor: the cutoff of its fastest axis.
        a = alpha(float(self.cutoff.max()), dt)
        self._r_hat = self._r_hat @ rotvec_to_matrix(a * matrix_to_rotvec(self._r_hat.T @ r))
        self._r_raw = r
        return matrix_to_rotvec(self._r_hat)


class PoseSmoother:
    """One-Euro filtering of poses q (shared.skeleton layout) and of named joint positions,
    driven by the stream timestamps.

    Args:
        config: the filter parameters.
        fps: the stream's nominal rate; its step is used when timestamps do not increase.
    """

    def __init__(self, config: SmoothingConfig | None = None, fps: float = 30.0) -> None:
        self.config = config or SmoothingConfig()
        self.config.validate()
        self._default_dt = 1.0 / fps if fps and fps > 0 else 1.0 / 30.0
        self._position = OneEuroFilter(self.config)
        self._rotation = RotationOneEuroFilter(self.config)
        self._angles = OneEuroFilter(self.config)
        self._joints = OneEuroFilter(self.config)
        self._t_pose: float | None = None
        self._t_joints: float | None = None

    def reset(self) -> None:
        """Forget the past (a lost frame): the next pose passes through unchanged."""
        for f in (self._position, self._rotation, self._angles, self._joints):
            f.reset()
        self._t_pose = self._t_joints = None

    def _dt(self, t: float, last: float | None) -> float:
        if last is None or not math.isfinite(t) or not t > last:
            return self._default_dt
        return t - last

    def pose(self, t: float, q: np.ndarray) -> np.ndarray:
        """The filtered pose for ``q`` (34,) at stream time ``t`` (seconds)."""
        q = np.asarray(q, dtype=np.float64)
        dt = self._dt(t, self._t_pose)
        self._t_pose = t
        return np.concatenate(
            [self._position(q[0:3], dt), self._rotation(q[3:6], dt), self._angles(q[6:], dt)]
        )

    def joints(self, t: float, joints: np.ndarray) -> np.ndarray:
        """The filtered named joints (J, 3) at stream time ``t``; rows with a non-finite
        coordinate restart the filter and pass through."""
        joints = np.asarray(joints, dtype=np.float64)
        if not np.isfinite(joints).all():
            self._joints.reset()
            self._t_joints = None
            return joints
        dt = self._dt(t, self._t_joints)
        self._t_joints = t
        return self._joints(joints, dt)
