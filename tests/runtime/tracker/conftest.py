"""Fixtures shared by the tracker's test files: a bent test pose, its observation, and short
sequences rendered from the cylinder model (all at 320 x 240, Kinect v1 intrinsics)."""

from __future__ import annotations

from collections.abc import Callable

import pytest
import torch
from depthmocap.bench.scenes import camera_motion
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker.observation import Observation, observe
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import rest_pose

INTR = Intrinsics.kinect_v1(320)
D = {n: i for i, n in enumerate(sk.DOF_NAMES)}


def _pose(dtype=torch.float64) -> torch.Tensor:
    q = rest_pose(1, root_position=(0.05, 0.1, 2.4), dtype=dtype)
    q[0, 3:6] = torch.tensor([3.0, 0.2, -0.1], dtype=dtype)
    for name, value in (
        ("l_humerus_abd", 0.7),
        ("l_radius_flex", 0.9),
        ("r_humerus_flex", 0.5),
        ("r_femur_flex", 0.4),
        ("r_tibia_flex", 0.6),
        ("lower_back_y", 0.2),
        ("l_femur_abd", 0.2),
        ("head_y", 0.3),
    ):
        q[0, D[name]] = value
    return q


def _frame(q: torch.Tensor, body: BodyShape, intr: Intrinsics = INTR) -> Observation:
    depth = render_body(q, body, intr).depth
    return observe(depth, depth > 0, intr, 2, 12.0)


def _sequence(name: str, frames: int, dtype=torch.float32):
    body = BodyShape.default(dtype)
    truth = camera_motion(name, frames, seed=0).to(dtype)
    depth = render_body(truth, body, INTR).depth
    return body, truth, depth, depth > 0


@pytest.fixture
def make_pose() -> Callable[..., torch.Tensor]:
    """A fresh (1, 34) pose with bent arms, legs, back and head, 2.4 m from the camera."""
    return _pose


@pytest.fixture
def render_frame() -> Callable[..., Observation]:
    """The observation (downsampled by 2) of a pose rendered from the body model."""
    return _frame


@pytest.fixture
def render_sequence() -> Callable[..., tuple]:
    """``(body, truth, depth, mask)`` of a ``bench.scenes.camera_motion`` sequence rendered
    from the default body."""
    return _sequence


def _off_truth_batch(changes: list[dict[str, float]], details: bool = True):
    """``(body, obs, q, render)`` in float32: the test pose's observation as a batch of
    ``1 + len(changes)`` views, the poses the truth followed by the truth with each
    ``{dof name: added value}`` of ``changes``, and their rendering."""
    from depthmocap.runtime.tracker.tracker import expand_observation

    body = BodyShape.default(torch.float32)
    truth = _pose(torch.float32)
    obs = expand_observation(_frame(truth, body), 1 + len(changes))
    q = truth.repeat(1 + len(changes), 1)
    for k, change in enumerate(changes, 1):
        for name, value in change.items():
            q[k, D[name]] += value
    return body, obs, q, render_body(q, body, obs.intr, details=details)


@pytest.fixture
def off_truth_batch() -> Callable[..., tuple]:
    """``off_truth_batch(changes, details=True) -> (body, obs, q, render)``: a batch of poses
    off the test pose by ``changes`` (one dict of DoF offsets per extra pose), rendered, and
    the test pose's observation for each (the compiled terms' bit-for-bit tests)."""
    return _off_truth_batch


def _assert_same_rows(got, want, context=None) -> None:
    for name in ("batch", "points", "segment", "direction", "residual", "weight"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and torch.equal(a, b), (context, name)


@pytest.fixture
def assert_same_rows() -> Callable[..., None]:
    """``assert_same_rows(got, want, context)``: two terms' ``Rows`` equal field by field, in
    dtype and to the bit (a compiled term against the torch code it replaces)."""
    return _assert_same_rows
