"""The shoulder's two Euler forms: same arm, branch moves, alignment, and the tracker leaving a
form pinned at the limits."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker import Tracker, track_sequence
from depthmocap.runtime.tracker import tracker as tracker_module
from depthmocap.runtime.tracker.shoulder_branch import (
    SHOULDER_DOFS,
    _move_where_roomier,
    _room,
    align_branch,
    move_to_roomier_branch,
    other_branch,
    shoulder_rotations,
)
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import (
    clamp_to_limits,
    forward_kinematics,
    named_joint_positions,
    rest_pose,
)

D = {n: i for i, n in enumerate(sk.DOF_NAMES)}
pytestmark = pytest.mark.usefixtures("one_thread")


def _arms(abd, flex, twist, elbow=0.6, batch=1) -> torch.Tensor:
    q = rest_pose(batch, dtype=torch.float64)
    for side in "lr":
        q[:, D[f"{side}_humerus_abd"]] = abd
        q[:, D[f"{side}_humerus_flex"]] = flex
        q[:, D[f"{side}_humerus_twist"]] = twist
        q[:, D[f"{side}_radius_flex"]] = elbow
    return q


def _deg(q: torch.Tensor) -> list:
    return torch.rad2deg(q[:, SHOULDER_DOFS]).round().tolist()


def test_other_branch_is_the_same_arm():
    body = BodyShape.default(torch.float64)
    q = _arms(2.1, -0.5, 0.7)
    q[0, D["r_humerus_abd"]] = -0.3
    other = other_branch(q)
    assert _deg(other)[0] == [[-60.0, -151.0, -140.0], [163.0, -151.0, -140.0]]
    a, b = forward_kinematics(q, body), forward_kinematics(other, body)
    assert torch.allclose(a.rotations, b.rotations, atol=1e-12)
    assert torch.allclose(named_joint_positions(a), named_joint_positions(b), atol=1e-12)
    assert torch.allclose(shoulder_rotations(q), shoulder_rotations(other), atol=1e-12)


def test_a_pinned_shoulder_moves_to_the_roomier_form():
    pinned = _arms(math.radians(-45), math.radians(180), math.radians(64))
    moved = move_to_roomier_branch(pinned, max_turn=0.7)
    # The other form needs twist -116 degrees; clamped to -100 it turns the arm by 16 degrees.
    assert _deg(moved)[0] == [[135.0, 0.0, -100.0]] * 2
    rel = shoulder_rotations(moved) @ shoulder_rotations(pinned).transpose(-1, -2)
    turn = torch.acos(((rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1))
    assert torch.allclose(turn, torch.full_like(turn, math.radians(16)), atol=1e-9)
    # Too large a turn, or a form with no more room: nothing moves.
    assert torch.equal(move_to_roomier_branch(pinned, max_turn=0.2), pinned)
    relaxed = _arms(0.5, 0.3, 0.1)
    assert torch.equal(move_to_roomier_branch(relaxed), relaxed)
    assert torch.equal(clamp_to_limits(moved), moved)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_shortcut_for_arms_clear_of_the_limits_changes_nothing(dtype):
    # Random shoulders, from well inside the limits to pinned at them, alone and in batches
    # where one pose could move: the shortcut must give exactly the full computation.
    gen = torch.Generator().manual_seed(3)
    lim = torch.as_tensor(sk.DOF_LIMITS, dtype=dtype)
    q = rest_pose(64, dtype=dtype)
    u = torch.rand(64, sk.NUM_DOFS, generator=gen, dtype=dtype)
    q[:, 6:] = lim[6:, 0] + u[:, 6:] * (lim[6:, 1] - lim[6:, 0])
    q[::3, SHOULDER_DOFS.flatten()] = q[::3, SHOULDER_DOFS.flatten()].clamp(-0.5, 0.5)
    clear = (_room(q) + 0.2 >= 1.5).all(-1)
    assert 0 < int(clear.sum()) < 64  # both cases occur
    for batch in (q[clear], q[~clear], q, q[:1], q[clear][:1]):
        full = _move_where_roomier(batch, _room(batch), 0.7, 0.2)
        assert torch.equal(move_to_roomier_branch(batch, 0.7), full)


def test_align_branch_writes_the_frame_before_like_the_frame_after():
    before = _arms(2.0, -0.4, 1.6)
    after = other_branch(_arms(1.95, -0.38, 1.62))  # the next frame, in the other form
    aligned = align_branch(before, after)
    step = (aligned - after)[:, SHOULDER_DOFS]
    assert float(step.abs().max()) < 0.06  # a small motion, not a jump of pi
    assert torch.allclose(shoulder_rotations(aligned), shoulder_rotations(before), atol=1e-12)
    assert torch.equal(align_branch(before, before), before)


def test_tracker_leaves_a_form_pinned_at_the_limits(monkeypatch):
    # Arms lowered sideways from overhead; the track starts in the other form, which leaves
    # the limits (flexion 180) as the arms come down, as the tracker found on rotateArms.
    frames = 10
    intr = Intrinsics.kinect_v1(320)
    body = BodyShape.default()
    abd = torch.linspace(2.5, 1.4, frames, dtype=torch.float64)
    truth = _arms(abd, -0.3, 1.6, elbow=0.5, batch=frames)
    truth[:, 2] = 2.6
    truth = truth.float()
    depth = render_body(truth, body, intr).depth
    start = clamp_to_limits(other_branch(truth[:1].double())).float()[0]
    errors = {}
    for turn in (0.0, 0.7):
        monkeypatch.setattr(tracker_module, "SHOULDER_BRANCH_TURN_RAD", turn)
        q, _ = track_sequence(depth, depth > 0, start, Tracker(body, intr))
        a = named_joint_positions(forward_kinematics(q.double(), body.to(torch.float64)))
        b = named_joint_positions(forward_kinematics(truth.double(), body.to(torch.float64)))
        errors[turn] = float((a - b).norm(dim=-1)[-3:].max()) * 1e3
    assert errors[0.7] < 15.0 < errors[0.0], errors
