"""The compiled Gauss-Newton iteration (runtime.tracker.iteration_kernel) against the term-by-term
iteration it replaces on the CPU: the same poses, steps and signals, bit for bit, for one pose
with the prior, a batch of starts on one frame, a batch of bodies, labels, and each term
switched off; and where it must not run (float64, autograd)."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from depthmocap.runtime.raycast import render_body, segment_geometry
from depthmocap.runtime.tracker import TrackerConfig
from depthmocap.runtime.tracker import tracker as tracker_module
from depthmocap.runtime.tracker.tracker import expand_observation, fit_frames
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, rest_pose

pytest.importorskip("numba")
from depthmocap.runtime.tracker import iteration_kernel  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_thread")

D = {n: i for i, n in enumerate(sk.DOF_NAMES)}


def _observation(make_pose, render_frame, labels: bool = True):
    """A float32 frame of the test pose with depth noise and forest-like labels (the true
    segments with a tenth of the limb pixels swapped to the other side), its pose and body."""
    body = BodyShape.default(torch.float32)
    q_true = make_pose(torch.float32)
    obs = render_frame(q_true, body)
    gen = torch.Generator().manual_seed(3)
    noise = 0.01 * torch.randn(obs.depth.shape, generator=gen)
    depth = torch.where(obs.valid, obs.depth + noise, obs.depth)
    points = obs.points * (depth / obs.depth.clamp_min(1e-6))[..., None]
    obs = dataclasses.replace(obs, depth=depth, points=points)
    if labels:
        seg = render_body(q_true, body, obs.intr).segment
        swap = torch.rand(seg.shape, generator=gen) < 0.1
        limb = seg >= sk.FIRST_LIMB_SEGMENT
        other = torch.where(limb & swap, seg.flip(-1).clamp_min(sk.FIRST_LIMB_SEGMENT), seg)
        obs = dataclasses.replace(obs, labels=torch.where(obs.valid, other, -1))
    return obs, q_true, body


def _start(q_true: torch.Tensor, shift: float) -> torch.Tensor:
    q = q_true.clone()
    q[:, 0] += 0.03 * shift
    for name in ("l_humerus_abd", "r_femur_flex", "l_radius_flex"):
        q[:, D[name]] += 0.25 * shift
    return q


def _both(monkeypatch, *args, **kwargs):
    """fit_frames term by term, then compiled (counting the compiled calls)."""
    calls = []
    real = iteration_kernel.iteration_cpu

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(iteration_kernel, "iteration_cpu", counted)
    monkeypatch.setattr(tracker_module, "FUSED_ITERATION", False)
    reference = fit_frames(*args, **kwargs)
    assert not calls
    monkeypatch.setattr(tracker_module, "FUSED_ITERATION", True)
    fused = fit_frames(*args, **kwargs)
    return reference, fused, len(calls)


def _assert_same(a, b):
    assert torch.equal(a.q, b.q), (a.q - b.q).abs().max()
    assert a.iterations == b.iterations
    assert torch.equal(a.steps, b.steps) and torch.equal(a.converged, b.converged)
    for f in dataclasses.fields(a.signals):
        x, y = getattr(a.signals, f.name), getattr(b.signals, f.name)
        assert torch.equal(x, y), f.name


def test_one_pose_with_the_prior(monkeypatch, make_pose, render_frame):
    obs, q_true, body = _observation(make_pose, render_frame)
    q_prev, q_prev2 = _start(q_true, 1.0), _start(q_true, 1.6)
    ref, fused, calls = _both(monkeypatch, obs, q_prev, q_prev2, body, TrackerConfig())
    assert calls == ref.iterations >= 2
    _assert_same(ref, fused)


def test_a_batch_of_starts_on_one_frame(monkeypatch, make_pose, render_frame):
    obs, q_true, body = _observation(make_pose, render_frame)
    starts = torch.cat([_start(q_true, s) for s in (-1.0, 0.0, 0.7, 1.5)])
    ref, fused, calls = _both(
        monkeypatch, expand_observation(obs, 4), starts, None, body, TrackerConfig()
    )
    assert calls == ref.iterations >= 2
    _assert_same(ref, fused)


def test_a_batch_of_bodies(monkeypatch, make_pose, render_frame):
    """The size search's refits: start k fitted with body k."""
    obs, q_true, body = _observation(make_pose, render_frame)
    bodies = body.scaled(torch.tensor([0.9, 1.0, 1.1]))
    starts = q_true.expand(3, -1).clone()
    geom = segment_geometry(bodies, starts)
    ref, fused, calls = _both(
        monkeypatch, expand_observation(obs, 3), starts, None, bodies, TrackerConfig(), geom
    )
    assert calls >= 1
    _assert_same(ref, fused)


@pytest.mark.parametrize(
    "flags",
    [
        {"use_depth": False},
        {"use_extra_depth": False},
        {"use_silhouette": False},
        {"use_labels": False},
        {"use_prior": False},
        {"use_collision": False},
        {"occlusion_handling": False},
        {
            "use_depth": False,
            "use_extra_depth": False,
            "use_silhouette": False,
            "use_labels": False,
        },
    ],
    ids=lambda f: "+".join(f),
)
def test_each_term_off(monkeypatch, make_pose, render_frame, flags):
    obs, q_true, body = _observation(make_pose, render_frame)
    cfg = dataclasses.replace(TrackerConfig(iterations=3), **flags)
    ref, fused, calls = _both(monkeypatch, obs, _start(q_true, 1.0), q_true, body, cfg)
    assert calls == ref.iterations
    _assert_same(ref, fused)


def test_with_leg_collision(monkeypatch, render_frame):
    """The collision term's leg samples (``leg_collision``), from a start with the right leg
    swung in across the left: the same fit to the bit, and the shanks come apart."""
    body = BodyShape.default(torch.float32)
    q_true = rest_pose(1, root_position=(0.0, 0.1, 2.4))
    q_true[0, D["r_femur_abd"]] = -0.07
    start = q_true.clone()
    start[0, D["r_femur_abd"]] = -0.26
    obs = render_frame(q_true, body)
    cfg = TrackerConfig(iterations=3, use_collision=True, leg_collision=True)
    ref, fused, calls = _both(monkeypatch, obs, start, start, body, cfg)
    assert calls == ref.iterations
    _assert_same(ref, fused)
    without = fit_frames(obs, start, start, body, dataclasses.replace(cfg, leg_collision=False))
    ankles = [sk.JOINT_NAMES.index(n) for n in ("l_ankle", "r_ankle")]

    def apart(q):
        j = named_joint_positions(forward_kinematics(q, body))[0, ankles]
        return float((j[0] - j[1]).norm())

    assert apart(ref.q) > apart(without.q)
    # The tolerance setting reaches both paths: the same fit to the bit, and a tolerance deeper
    # than any overlap here leaves the legs as without the term.
    for tolerance, same_as_without in ((0.02, False), (1.0, True)):
        deep = dataclasses.replace(cfg, leg_collision_tolerance_m=tolerance)
        ref, fused, _ = _both(monkeypatch, obs, start, start, body, deep)
        _assert_same(ref, fused)
        assert torch.equal(ref.q, without.q) == same_as_without


def test_with_the_pose_prior(monkeypatch, make_pose, render_frame):
    """The learned pose prior's equations are added after the collision term's on both paths."""
    obs, q_true, body = _observation(make_pose, render_frame)
    starts = torch.cat([_start(q_true, s) for s in (-1.0, 0.7)])
    cfg = TrackerConfig(iterations=3, pose_prior_weight=3.0)
    ref, fused, calls = _both(monkeypatch, expand_observation(obs, 2), starts, None, body, cfg)
    assert calls == ref.iterations
    _assert_same(ref, fused)
    plain = fit_frames(expand_observation(obs, 2), starts, None, body, TrackerConfig(iterations=3))
    assert not torch.equal(plain.q, fused.q)


def test_without_labels(monkeypatch, make_pose, render_frame):
    obs, q_true, body = _observation(make_pose, render_frame, labels=False)
    ref, fused, _ = _both(monkeypatch, obs, _start(q_true, 1.0), None, body, TrackerConfig())
    _assert_same(ref, fused)


def test_not_where_it_cannot_match(monkeypatch, make_pose, render_frame):
    """float64 takes the term-by-term path; so would poses or a body that need gradients."""
    obs, q_true, body = _observation(make_pose, render_frame)
    calls = []
    monkeypatch.setattr(iteration_kernel, "iteration_cpu", lambda *a, **k: calls.append(1))
    obs64 = dataclasses.replace(
        obs, depth=obs.depth.double(), points=obs.points.double(), distance=obs.distance.double(),
        distance_grad=obs.distance_grad.double(),
    )  # fmt: skip
    body64 = body.to(torch.float64)
    fit_frames(obs64, q_true.double(), None, body64, TrackerConfig(iterations=1))
    assert not calls
    geom = segment_geometry(body, q_true)
    assert tracker_module._fused_iteration(obs, q_true, body, geom) is iteration_kernel
    q = q_true.clone().requires_grad_(True)
    assert tracker_module._fused_iteration(obs, q, body, geom) is None
    lengths = body.lengths.clone().requires_grad_(True)
    grad_body = dataclasses.replace(body, lengths=lengths)
    assert tracker_module._fused_iteration(obs, q_true, grad_body, geom) is None
