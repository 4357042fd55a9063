"""The tracker's label term: capsule offsets (golden values), its Jacobian (autograd), the
gate, label pooling, and that labels pull a misplaced arm back."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.runtime.raycast import part_labels, render_body, segment_geometry
from depthmocap.runtime.tracker import (
    Tracker,
    TrackerConfig,
    TrackerConfigError,
    TrackerError,
    label_term,
)
from depthmocap.runtime.tracker.gauss_newton import rows_jacobian
from depthmocap.runtime.tracker.label_term import capsule_offsets, label_rows
from depthmocap.runtime.tracker.observation import label_term_pixels, observe, person_window
from depthmocap.runtime.tracker.tracker import CROP_MARGIN, SILHOUETTE_MAX_PX
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import (
    forward_kinematics,
    named_joint_positions,
    pose_update,
    rest_pose,
)
from depthmocap.shared.labels import PART_SEGMENT

pytestmark = pytest.mark.usefixtures("one_thread")

INTR = Intrinsics.kinect_v1(160)
D = {n: i for i, n in enumerate(sk.DOF_NAMES)}


def _pose(dtype=torch.float64) -> torch.Tensor:
    q = rest_pose(1, root_position=(0.0, 0.1, 2.4), dtype=dtype)
    q[0, D["l_humerus_abd"]] = math.radians(50)
    q[0, D["l_radius_flex"]] = math.radians(40)
    q[0, D["r_femur_flex"]] = math.radians(30)
    return q


def _part_labels(q: torch.Tensor, body: BodyShape) -> torch.Tensor:
    """Exact forest-style part labels (H, W) of the rendered pose."""
    return part_labels(render_body(q, body, INTR), body)[0]


def test_capsule_offsets_golden_values():
    # A capsule along local z from 0 to 1 m, radius 0.1 m, caps of 0.1 m, at the origin.
    eye = torch.eye(3, dtype=torch.float64)
    points = torch.tensor(
        [[0.3, 0.0, 0.5], [0.05, 0.0, 0.5], [0.0, 0.0, 1.5], [0.0, -0.2, -0.3]],
        dtype=torch.float64,
    )
    n = len(points)
    signed, direction = capsule_offsets(
        points, eye.expand(n, 3, 3), torch.zeros(n, 3, dtype=torch.float64), eye.expand(n, 3, 3),
        torch.tensor([[0.0, 1.0]], dtype=torch.float64).expand(n, 2),
        torch.full((n, 3), 0.1, dtype=torch.float64),
    )  # fmt: skip
    torch.testing.assert_close(signed, torch.tensor([0.2, -0.05, 0.4, math.hypot(0.2, 0.3) - 0.1],
                                                    dtype=torch.float64))  # fmt: skip
    expected = torch.tensor(
        [[1.0, 0, 0], [1.0, 0, 0], [0, 0, 1.0], [0, -0.2, -0.3]], dtype=torch.float64
    )
    torch.testing.assert_close(direction, expected / expected.norm(dim=-1, keepdim=True))


def _labelled_observation(q_obs: torch.Tensor, body: BodyShape, factor: int = 1):
    depth = render_body(q_obs, body, INTR).depth
    segments = torch.as_tensor(PART_SEGMENT)[_part_labels(q_obs, body)][None]
    return observe(depth, depth > 0, INTR, factor, 10.0, None, segments)


def test_label_rows_jacobian_matches_autograd(monkeypatch):
    body = BodyShape.default(torch.float64)
    q = _pose()
    q_obs = q.clone()
    q_obs[0, D["l_humerus_abd"]] += 0.15  # the observed arm is 5-10 cm from the model's
    obs = _labelled_observation(q_obs, body)
    geom = segment_geometry(body, q)
    monkeypatch.setattr(label_term, "MAX_LABEL_PIXELS", 60)
    monkeypatch.setattr(label_term, "LABEL_GATE_M", 1.0)
    cfg = TrackerConfig()
    rows = label_rows(forward_kinematics(q, body), geom, obs, cfg)
    assert len(rows) > 20 and set(rows.segment.tolist()) <= set(range(7, 15))
    analytic = rows_jacobian(forward_kinematics(q, body), rows)
    points = rows.points + rows.residual[:, None] * rows.direction  # back to the pixels

    def signed(dq):
        kin = forward_kinematics(pose_update(q, dq[None]), body)
        rot, origin = geom.frames(kin)
        k = rows.segment
        return capsule_offsets(points, rot[0, k], origin[0, k], geom.basis[k],
                               geom.span[k], geom.scale[k])[0]  # fmt: skip

    torch.testing.assert_close(signed(torch.zeros(34, dtype=torch.float64)), rows.residual)
    numeric = torch.autograd.functional.jacobian(signed, torch.zeros(34, dtype=torch.float64))
    # The row predicts how the model point moves towards the pixel: minus the distance's change.
    torch.testing.assert_close(analytic, -numeric, atol=1e-6, rtol=1e-4)


def test_label_rows_gate_and_missing_labels(monkeypatch):
    body = BodyShape.default(torch.float64)
    q = _pose()
    geom, kin = segment_geometry(body, q), forward_kinematics(q, body)
    obs = _labelled_observation(q, body)
    monkeypatch.setattr(label_term, "MAX_LABEL_PIXELS", 100)
    rows = label_rows(kin, geom, obs, TrackerConfig())
    assert len(rows) > 0 and bool((rows.weight > 0).all())
    assert float(rows.residual.abs().max()) < 0.02  # the model is where its labels are
    monkeypatch.undo()  # the default cap from here on
    # Far from every labelled limb: all gated out.
    moved = q.clone()
    moved[0, 0] += 0.5
    far = label_rows(forward_kinematics(moved, body), geom, obs, TrackerConfig())
    assert len(far) > 0 and bool((far.weight == 0).all())
    # Torso labels only, or no labels at all: no rows.
    torso = obs.labels.clone()
    torso[torso >= 7] = 2
    obs.labels = torso
    assert len(label_rows(kin, geom, obs, TrackerConfig())) == 0
    obs.labels = None
    assert len(label_rows(kin, geom, obs, TrackerConfig())) == 0


def test_labels_are_pooled_like_the_silhouette():
    depth = torch.zeros(1, 40, 60)
    depth[:, 5:35, 10:50] = 2.0
    labels = torch.arange(40 * 60).reshape(1, 40, 60)
    window = (8, 48, 4, 36)  # u0, u1, v0, v1
    obs = observe(depth, depth > 0, Intrinsics(60, 40, 50.0, 50.0, 30.0, 20.0), 2, 5.0, window,
                  labels)  # fmt: skip
    assert obs.labels.shape == obs.depth.shape
    i, j = 3, 5
    assert int(obs.labels[0, i, j]) == int(labels[0, 4 + 2 * i, 8 + 2 * j])


def test_label_term_pulls_a_misplaced_arm_back():
    """The model's left arm starts 25 degrees lower than the observed one (wrist 21 cm off).
    Without the extra depth term, depth and silhouette alone leave the wrist 5 cm off; the
    labelled pixels bring it within 1 cm."""
    body = BodyShape.default(torch.float64)
    q_true = _pose()
    depth = render_body(q_true, body, INTR).depth[0]
    labels = _part_labels(q_true, body)
    q_start = q_true.clone()
    q_start[0, D["l_humerus_abd"]] -= math.radians(25)
    wrist = sk.JOINT_NAMES.index("l_wrist")
    true_wrist = named_joint_positions(forward_kinematics(q_true, body))[0, wrist]
    errors = {}
    for use in (False, True):
        cfg = TrackerConfig(use_labels=use, iterations=6, use_extra_depth=False)
        tracker = Tracker(body, INTR, cfg, dtype=torch.float64)
        res = tracker.step(depth, depth > 0, q_start[0], labels=labels)
        kin = forward_kinematics(res.q[None], body)
        errors[use] = float((named_joint_positions(kin)[0, wrist] - true_wrist).norm())
    assert errors[True] < 0.02 < 0.04 < errors[False]
    labelled = Tracker(body, INTR, TrackerConfig(use_labels=True))
    for bad in (labels[:-1], labels + 20, labels - 1):
        with pytest.raises(TrackerError, match="labels"):
            labelled.step(depth, depth > 0, q_start[0], labels=bad)


@pytest.mark.parametrize("bad", [{"sigma_label_m": 0.0}, {"sigma_prior_m": -0.1},
                                 {"sigma_depth_m": float("nan")}])  # fmt: skip
def test_bad_noise_scales_are_rejected(bad):
    with pytest.raises(TrackerConfigError, match="positive and finite"):
        TrackerConfig(**bad)


def test_the_compiled_term_gives_the_torch_rows_bit_for_bit(assert_same_rows, monkeypatch):
    """runtime.tracker.label_kernel (one compiled call, CPU float32) against the torch code
    it replaces, on a batch of poses off the labelled observation by different amounts,
    thinned and not, the gate biting: the same rows to the bit."""
    pytest.importorskip("depthmocap.runtime.tracker.label_kernel")
    from depthmocap.runtime.tracker.tracker import expand_observation

    body = BodyShape.default(torch.float32)
    q_obs = _pose(torch.float32)
    obs = expand_observation(_labelled_observation(q_obs, body, 2), 3)
    q = q_obs.repeat(3, 1)
    q[1, D["l_humerus_abd"]] += 0.3
    q[2, 0] += 0.2  # most pixels beyond the gate
    kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
    cfg = TrackerConfig()
    for cap in (40, 100000):
        monkeypatch.setattr(label_term, "MAX_LABEL_PIXELS", cap)
        got = label_rows(kin, geom, obs, cfg)
        with monkeypatch.context() as m:  # the torch code (its sampling still compiled)
            m.setattr(label_term, "compiled_float32", lambda name, *t: None)
            want = label_rows(kin, geom, obs, cfg)
        assert len(want) > 30 and bool((want.weight == 0).any() and (want.weight > 0).any())
        assert_same_rows(got, want, cap)


def test_the_label_gate_drops_unsure_labels_only():
    """``label_min_posterior``: the label term skips the labels whose confidence is under
    the gate and reads the others; the observation keeps every label (the observed-joint
    support reads them); no confidence (ground-truth labels) gates nothing, and a gate of 0
    ignores the confidence."""
    body = BodyShape.default(torch.float64)
    q = _pose()
    depth = render_body(q, body, INTR).depth[0]
    labels = _part_labels(q, body)
    confidence = torch.full(labels.shape, 0.9)
    confidence[:, : labels.shape[1] // 2] = 0.3  # the image's left half unsure
    gated = Tracker(body, INTR, TrackerConfig(use_labels=True, label_min_posterior=0.5,
                                              downsample=1), dtype=torch.float64)  # fmt: skip
    plain = Tracker(body, INTR, TrackerConfig(use_labels=True, downsample=1), dtype=torch.float64)
    obs = gated.observe(depth, depth > 0, labels, confidence)
    full = plain.observe(depth, depth > 0, labels)
    assert torch.equal(obs.labels, full.labels) and full.label_sure is None
    read, everything = label_term_pixels(obs), label_term_pixels(full)
    sure = (confidence >= 0.5)[None]
    u0, u1, v0, v1 = person_window(depth[None] > 0, 1, CROP_MARGIN, int(SILHOUETTE_MAX_PX) + 2)
    assert torch.equal(read, everything & sure[:, v0:v1, u0:u1])
    assert int(everything.sum()) > int(read.sum()) > 0
    assert gated.observe(depth, depth > 0, labels).label_sure is None
    assert plain.observe(depth, depth > 0, labels, confidence).label_sure is None
    with pytest.raises(TrackerError, match="confidence"):
        gated.observe(depth, depth > 0, labels, confidence[:-1])
    # The rows: the gated term reads the sure pixels' rows only.
    kin, geom = forward_kinematics(q, body), segment_geometry(body, q)
    rows = label_rows(kin, geom, obs, gated.cfg)
    assert 0 < len(rows) < len(label_rows(kin, geom, full, plain.cfg))


@pytest.mark.parametrize("gate", [-0.1, 1.0, float("nan")])
def test_bad_label_gates_are_rejected(gate):
    with pytest.raises(TrackerConfigError, match="label_min_posterior"):
        TrackerConfig(label_min_posterior=gate)
