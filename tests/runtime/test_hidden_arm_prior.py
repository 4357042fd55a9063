"""Hidden-arm prior: label shares, weights and the pull's normal-equation terms."""

from __future__ import annotations

import math

import pytest
import torch

from runtime.raycast import render_body
from runtime.tracker import Tracker, TrackerConfig
from runtime.tracker.hidden_arm_prior import (
    REST_ARM_DEG,
    arm_label_shares,
    hidden_arm_weights,
    rest_pull_system,
)
from shared import skeleton as sk
from shared.body import BodyShape
from shared.camera import Intrinsics
from shared.kinematics import rest_pose

pytestmark = pytest.mark.usefixtures("one_thread")

SEG = {n: i for i, n in enumerate(sk.SEGMENT_NAMES)}
D = {n: i for i, n in enumerate(sk.DOF_NAMES)}
ARM = ("humerus_abd", "humerus_flex", "humerus_twist", "radius_flex")


def test_arm_label_shares_golden():
    seg = torch.full((2, 4, 5), -1, dtype=torch.int64)
    person = torch.zeros(2, 4, 5, dtype=torch.bool)
    person[0, :, :] = True  # 20 person pixels
    seg[0, 0, :3] = SEG["l_upper_arm"]
    seg[0, 1, :2] = SEG["l_forearm"]
    seg[0, 2, 0] = SEG["r_forearm"]
    seg[0, 3, :] = SEG["pelvis"]
    seg[1, 0, 0] = SEG["l_forearm"]  # frame 1 has no person: the label does not count
    shares = arm_label_shares(seg, person)
    assert shares.shape == (2, 2)
    torch.testing.assert_close(
        shares, torch.tensor([[5 / 20, 1 / 20], [0.0, 0.0]], dtype=torch.float64)
    )


def test_hidden_arm_weights_only_on_hidden_arms(dtype):
    shares = torch.tensor([[0.0, 0.2], [0.05, 0.009]], dtype=torch.float64)
    like = torch.zeros(2, sk.NUM_DOFS, dtype=dtype)
    w2 = hidden_arm_weights(shares, 0.01, 0.5, like)
    assert w2.dtype == dtype and w2.shape == (2, sk.NUM_DOFS)
    expect = torch.zeros(2, sk.NUM_DOFS, dtype=dtype)
    expect[0, [D[f"l_{n}"] for n in ARM]] = 4.0
    expect[1, [D[f"r_{n}"] for n in ARM]] = 4.0
    torch.testing.assert_close(w2, expect)


def test_rest_pull_system_is_the_gradient_of_the_pull(dtype):
    """rhs = -0.5 d/dq of sum w2 (rest - q)^2 and diag = its half second derivative."""
    torch.manual_seed(0)
    q = (torch.rand(1, sk.NUM_DOFS, dtype=torch.float64) - 0.5).requires_grad_(True)
    w2 = hidden_arm_weights(torch.tensor([[0.0, 0.5]]), 0.01, 0.2, q.detach())
    diag, rhs = rest_pull_system(q, w2)
    rest = torch.tensor([math.radians(a) for a in REST_ARM_DEG], dtype=torch.float64)
    left = [D[f"l_{n}"] for n in ARM]
    energy = (w2[:, left] * (rest - q[:, left]) ** 2).sum()
    (grad,) = torch.autograd.grad(energy, q)
    torch.testing.assert_close(rhs.detach(), -0.5 * grad)
    torch.testing.assert_close(diag, w2)
    assert rhs[0, [D[f"r_{n}"] for n in ARM]].abs().max() == 0


def test_tracker_moves_a_hidden_arm_towards_rest_and_leaves_a_seen_one():
    """A frame whose labels show no left arm, tracked with the priors alone: with the pull on,
    the left elbow unbends towards the relaxed pose; the right arm, which the labels show, is
    not pulled."""
    intr = Intrinsics.kinect_v1(160)
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, root_position=(0.0, 0.1, 2.6), dtype=torch.float64)
    r = render_body(q, body, intr)
    depth = r.depth[0]
    labels = torch.where(r.segment[0] >= 0, 3, 0)  # every pixel "chest": no arm seen ...
    labels[r.segment[0] == SEG["r_forearm"]] = 11  # ... but the right forearm (part 11)
    start = q[0].clone()
    start[D["l_radius_flex"]] = start[D["r_radius_flex"]] = math.radians(60)
    out = {}
    for share in (0.0, 0.01):
        cfg = TrackerConfig(
            use_labels=True, hidden_arm_share=share, sigma_hidden_arm_rad=0.05,
            use_depth=False, use_extra_depth=False, use_silhouette=False,
        )  # fmt: skip
        res = Tracker(body, intr, cfg, dtype=torch.float64).step(
            depth, depth > 0, start, labels=labels
        )
        out[share] = torch.rad2deg(res.q[[D["l_radius_flex"], D["r_radius_flex"]]]).tolist()
    assert out[0.0][0] == pytest.approx(60.0, abs=1.0)  # nothing but the prior: stays
    # Equal noise scales (constant-acceleration prior and pull): halfway from 60 to 20 degrees.
    assert out[0.01][0] == pytest.approx(40.0, abs=0.5)
    # The seen arm follows its labels alike (coupled to the other only through the trunk).
    assert out[0.01][1] == pytest.approx(out[0.0][1], abs=0.5)
