"""Observed against inferred joints (runtime.tracker.joint_support): a golden one-pixel case,
plain view, a hidden far arm, an occluder, resolution independence and the tracker's output."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker import Tracker, TrackerConfig, TrackerConfigError
from depthmocap.runtime.tracker.joint_support import (
    JOINT_SUPPORT,
    joint_support_cm2,
    observed_joints,
)
from depthmocap.runtime.tracker.observation import observe
from depthmocap.runtime.tracker.regions import Regions, classify, rendered_points
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import named_joint_positions, rest_pose
from depthmocap.shared.so3 import matrix_to_rotvec, rotvec_to_matrix

pytestmark = pytest.mark.usefixtures("one_thread")

J = {n: i for i, n in enumerate(sk.JOINT_NAMES)}


def _front(dtype=torch.float64) -> torch.Tensor:
    return rest_pose(1, root_position=(0.0, 0.1, 2.5), dtype=dtype)


def _turned(q: torch.Tensor, angle: float) -> torch.Tensor:
    turn = rotvec_to_matrix(torch.tensor([[0.0, angle, 0.0]], dtype=q.dtype))
    out = q.clone()
    out[:, 3:6] = matrix_to_rotvec(turn @ rotvec_to_matrix(q[:, 3:6]))
    return out


def _support(q: torch.Tensor, intr: Intrinsics, depth: torch.Tensor | None = None):
    """Support of the poses ``q`` against an observation: their own rendering, or ``depth``."""
    body = BodyShape.default(q.dtype)
    render = render_body(q, body, intr)
    observed = render.depth if depth is None else depth
    obs = observe(observed, observed > 0, intr, 1, 10.0)
    return joint_support_cm2(render, classify(render, obs, 0.08, True), intr), render


def test_table_names_every_joint_with_existing_segments():
    assert tuple(JOINT_SUPPORT) == sk.JOINT_NAMES
    for segments, radius in JOINT_SUPPORT.values():
        assert segments and all(s in sk.SEGMENT_NAMES for s in segments) and radius > 0


def test_one_good_pixel_adds_its_footprint_to_the_joints_near_it():
    """Golden value: a single G pixel on the left forearm next to the wrist counts z^2/(fx fy)
    at the wrist (and at the elbow only if within 10 cm of it), nowhere else."""
    intr = Intrinsics.kinect_v1(160)
    q = _front()
    body = BodyShape.default(torch.float64)
    render = render_body(q, body, intr)
    wrist = named_joint_positions(render.kin)[0, J["l_wrist"]]
    on_forearm = render.segment[0] == sk.SEGMENT_NAMES.index("l_forearm")
    idx = on_forearm.nonzero()
    pts, _ = rendered_points(render, torch.cat([idx.new_zeros(len(idx), 1), idx], 1), intr)
    pick = int((pts - wrist).norm(dim=-1).argmin())
    v, u = idx[pick].tolist()
    good = torch.zeros_like(render.mask)
    good[0, v, u] = True
    empty = torch.zeros_like(good)
    regions = Regions(good, empty, empty, empty, empty, torch.zeros_like(render.depth))
    area = joint_support_cm2(render, regions, intr)[0]
    z = float(render.depth[0, v, u])
    expected = z * z / (intr.fx * intr.fy) * 1e4
    assert float(area[J["l_wrist"]]) == pytest.approx(expected, rel=1e-9)
    elbow = named_joint_positions(render.kin)[0, J["l_elbow"]]
    near_elbow = float((pts[pick] - elbow).norm()) < 0.10
    assert float(area[J["l_elbow"]]) == pytest.approx(expected if near_elbow else 0.0)
    others = [j for n, j in J.items() if n not in ("l_wrist", "l_elbow")]
    assert float(area[others].abs().sum()) == 0.0


def test_plain_view_observes_every_joint_profile_infers_the_far_arm():
    intr = Intrinsics.kinect_v1(160)
    q = torch.cat([_front(), _turned(_front(), math.pi / 2)])
    area, _ = _support(q, intr)
    flags = observed_joints(area, TrackerConfig().observed_joint_area_cm2)
    assert flags.shape == (2, 16) and bool(flags[0].all())
    # Turned by +90 degrees about y the right arm is behind the torso (see limb_visibility).
    assert not bool(flags[1, J["r_elbow"]]) and not bool(flags[1, J["r_wrist"]])
    for name in ("l_elbow", "l_wrist", "head", "pelvis", "l_knee", "l_ankle"):
        assert bool(flags[1, J[name]]), name


def test_an_occluder_in_front_of_a_wrist_makes_it_inferred():
    """A board 40 cm in front of the left hand: the camera sees the board, not the hand."""
    intr = Intrinsics.kinect_v1(160)
    q = _front()
    q[0, sk.DOF_NAMES.index("l_humerus_abd")] = 1.2  # the arm out to the side
    area, render = _support(q, intr)
    wrist = named_joint_positions(render.kin)[0, J["l_wrist"]]
    u = float(intr.fx * wrist[0] / wrist[2] + intr.cx)
    v = float(intr.fy * wrist[1] / wrist[2] + intr.cy)
    depth = render.depth.clone()
    vv, uu = torch.meshgrid(torch.arange(intr.height), torch.arange(intr.width), indexing="ij")
    board = ((uu - u).abs() < 8) & ((vv - v).abs() < 8) & (depth[0] > 0)
    depth[0][board] = depth[0][board] - 0.4
    hidden, _ = _support(q, intr, depth)
    limit = TrackerConfig().observed_joint_area_cm2
    assert bool(observed_joints(area, limit)[0].all())
    flags = observed_joints(hidden, limit)[0]
    assert not bool(flags[J["l_wrist"]])
    assert bool(flags[J["r_wrist"]]) and bool(flags[J["l_shoulder"]])


def test_area_does_not_depend_on_the_working_resolution():
    q = _front()
    fine, _ = _support(q, Intrinsics.kinect_v1(320))
    coarse, _ = _support(q, Intrinsics.kinect_v1(160))
    ratio = coarse[0] / fine[0]
    assert bool(((ratio > 0.8) & (ratio < 1.25)).all()), ratio


def test_tracker_step_reports_observed_joints_and_checks_the_threshold():
    body = BodyShape.default(torch.float64)
    intr = Intrinsics.kinect_v1(320)
    q = _front()
    depth = render_body(q, body, intr).depth[0]
    res = Tracker(body, intr, dtype=torch.float64).step(depth, depth > 0, q[0])
    assert res.observed.shape == (16,) and res.observed.dtype == torch.bool
    assert bool(res.observed.all())
    never = Tracker(body, intr, TrackerConfig(observed_joint_area_cm2=1e9), dtype=torch.float64)
    assert not bool(never.step(depth, depth > 0, q[0]).observed.any())
    for bad in (-1.0, math.nan):
        with pytest.raises(TrackerConfigError, match="observed_joint_area_cm2"):
            TrackerConfig(observed_joint_area_cm2=bad)


def test_forest_labels_on_another_body_group_do_not_confirm_a_joint():
    """A hidden arm laid on the torso renders at the torso's depth: only the labels tell. The
    left arm labelled as chest loses its wrist and elbow; the same arm labelled as its
    forearm or upper arm (the forest's usual confusion near the elbow) keeps them."""
    intr = Intrinsics.kinect_v1(160)
    q = _front()
    q[0, sk.DOF_NAMES.index("l_humerus_abd")] = 1.2
    body = BodyShape.default(torch.float64)
    render = render_body(q, body, intr)
    obs = observe(render.depth, render.mask, intr, 1, 10.0)
    regions = classify(render, obs, 0.08, True)
    limit = TrackerConfig().observed_joint_area_cm2
    left_arm = [sk.SEGMENT_NAMES.index(n) for n in ("l_upper_arm", "l_forearm")]
    on_arm = torch.isin(render.segment, torch.tensor(left_arm))

    as_rendered = render.segment.clone()
    assert bool(observed_joints(joint_support_cm2(render, regions, intr, as_rendered), limit).all())
    swapped = torch.where(on_arm, left_arm[0] + left_arm[1] - render.segment, render.segment)
    area = joint_support_cm2(render, regions, intr, swapped)
    assert bool(observed_joints(area, limit).all())
    chest = torch.where(on_arm, sk.SEGMENT_NAMES.index("chest"), render.segment)
    flags = observed_joints(joint_support_cm2(render, regions, intr, chest), limit)[0]
    assert not bool(flags[J["l_wrist"]]) and not bool(flags[J["l_elbow"]])
    assert bool(flags[J["r_wrist"]]) and bool(flags[J["head"]])
    unlabelled = torch.full_like(render.segment, -1)
    assert not bool(
        observed_joints(joint_support_cm2(render, regions, intr, unlabelled), limit).any()
    )


def test_the_compiled_support_equals_torch_to_the_bit(monkeypatch):
    """CPU float32: the compiled loop (runtime.tracker.support_kernel) gives the torch code's
    areas to the bit, with labels (some off-group, some none) and without, on a batch of
    poses against another pose's observation."""
    pytest.importorskip("numba")
    import depthmocap.runtime.tracker.joint_support as js

    intr = Intrinsics.kinect_v1(160)
    body = BodyShape.default(torch.float32)
    q = _front(torch.float32).repeat(3, 1)
    q[1] = _turned(q[1:2], 0.6)[0]
    q[2, sk.DOF_NAMES.index("l_humerus_abd")] = 1.0
    observed = render_body(_turned(_front(torch.float32), 0.2), body, intr).depth.expand(3, -1, -1)
    render = render_body(q, body, intr)
    regions = classify(render, observe(observed, observed > 0, intr, 1, 10.0), 0.08, True)
    g = torch.Generator().manual_seed(0)
    noise = torch.randint(-1, sk.NUM_SEGMENTS, render.segment.shape, generator=g)
    labels = torch.where(torch.rand(noise.shape, generator=g) < 0.2, noise, render.segment)
    compiled = [joint_support_cm2(render, regions, intr, lab) for lab in (labels, None)]
    monkeypatch.setattr(js, "compiled_float32", lambda *a: None)
    reference = [joint_support_cm2(render, regions, intr, lab) for lab in (labels, None)]
    for a, b in zip(compiled, reference, strict=True):
        assert a.dtype == torch.float64 and a.shape == (3, len(sk.JOINT_NAMES))
        assert bool((b > 0).any()) and torch.equal(a, b)
