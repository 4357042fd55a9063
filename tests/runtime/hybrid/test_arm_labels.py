"""Arm start poses and the forest's arm share for the hidden-arm search of the hybrid."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.runtime.hybrid.arm_labels import (
    ARM_FLEXION_DEG,
    ELBOW_FLEXION_DEG,
    agreement_from_distances,
    arm_candidates,
    arm_label_agreement,
    arm_label_conflict,
    arm_pixel_fraction,
    arm_pixels,
    label_conflict_from_distances,
    near_other_arm,
    near_other_arm_from_distances,
)
from depthmocap.runtime.raycast import segment_distances, segment_geometry
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import (
    clamp_to_limits,
    forward_kinematics,
    named_joint_positions,
    rest_pose,
)
from depthmocap.shared.labels import PART_NAMES

ARM_DOFS = {
    side: [
        sk.DOF_NAMES.index(f"{side}_{n}")
        for n in ("humerus_abd", "humerus_flex", "humerus_twist", "radius_flex")
    ]  # fmt: skip
    for side in "lr"
}


@pytest.mark.parametrize("side", ["l", "r"])
def test_arm_candidates_change_only_that_arm(side):
    q = rest_pose(1, (0.1, 0.0, 2.5))[0]
    q[sk.DOF_NAMES.index(f"{side}_humerus_twist")] = 0.7
    q[sk.DOF_NAMES.index("lower_back_y")] = 0.2
    out = arm_candidates(q, side)
    assert out.shape == (len(ARM_FLEXION_DEG) * len(ELBOW_FLEXION_DEG), sk.NUM_DOFS)
    others = [i for i in range(sk.NUM_DOFS) if i not in ARM_DOFS[side]]
    torch.testing.assert_close(out[:, others], q[others].expand(len(out), -1))
    flex, elbow = out[:, ARM_DOFS[side][1]], out[:, ARM_DOFS[side][3]]
    starts = [(f, e) for f in ARM_FLEXION_DEG for e in ELBOW_FLEXION_DEG]
    expected = [(math.radians(f), math.radians(e)) for f, e in starts]
    torch.testing.assert_close(torch.stack([flex, elbow], 1), torch.tensor(expected))
    assert (out[:, ARM_DOFS[side][0]] == 0).all() and (out[:, ARM_DOFS[side][2]] == 0).all()
    torch.testing.assert_close(out, clamp_to_limits(out))
    assert len({tuple(row.tolist()) for row in out}) == len(out)  # all starts distinct


def test_arm_candidates_reject_unknown_side():
    with pytest.raises(ValueError, match="side"):
        arm_candidates(torch.zeros(sk.NUM_DOFS), "x")


def test_arm_pixel_fraction_counts_both_arm_classes_inside_the_mask():
    labels = torch.zeros(4, 5, dtype=torch.int64)
    labels[0, :2] = 8  # left upper arm
    labels[1, 0] = 10  # left forearm
    labels[2, :3] = 9  # right upper arm
    labels[3, 4] = 8  # left upper arm, but outside the mask
    mask = torch.ones(4, 5, dtype=torch.bool)
    mask[3, 4] = False
    assert arm_pixel_fraction(labels, mask, "l") == pytest.approx(3 / 19)
    assert arm_pixel_fraction(labels, mask, "r") == pytest.approx(3 / 19)
    assert arm_pixel_fraction(labels, torch.zeros_like(mask), "l") == 0.0


def test_arm_pixel_fraction_leaves_out_explained_pixels():
    labels = torch.full((2, 5), 8, dtype=torch.int64)  # all left upper arm
    mask = torch.ones(2, 5, dtype=torch.bool)
    explained = torch.zeros_like(mask)
    explained[0] = True
    assert arm_pixel_fraction(labels, mask, "l", explained) == pytest.approx(5 / 10)
    assert arm_pixel_fraction(labels, mask, "l", torch.zeros_like(mask)) == 1.0


def _rest(dtype):
    """The default body at rest 2.5 m in front of the camera: body, pose (1, 34), its
    kinematics and named joints (J, 3)."""
    body = BodyShape.default()
    q = rest_pose(1, (0.0, 0.0, 2.5), dtype=dtype)
    kin = forward_kinematics(q, body.to(dtype=dtype))
    return body, q, kin, named_joint_positions(kin)[0]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_near_other_arm_is_measured_from_the_other_arm_surface(dtype):
    body, _, kin, joints = _rest(dtype)
    r_elbow = joints[sk.JOINT_NAMES.index("r_elbow")]
    l_elbow = joints[sk.JOINT_NAMES.index("l_elbow")]
    # Along the camera's z axis from the right elbow: inside the arm, just outside, far out.
    points = torch.stack(
        [r_elbow, r_elbow - r_elbow.new_tensor([0, 0, 0.12]), r_elbow.new_tensor([0, 0, 1.0])]
    )
    near_r = near_other_arm(points, kin, body, "l", 0.05)  # measured from the right arm
    assert near_r.tolist() == [True, False, False]
    assert near_other_arm(points, kin, body, "l", 0.5).tolist() == [True, True, False]
    # Seen from the right arm's side the other arm is the left one, far from these points.
    assert not near_other_arm(points, kin, body, "r", 0.05).any()
    assert near_other_arm(l_elbow[None], kin, body, "r", 0.05).tolist() == [True]
    # Any leading shape, e.g. an image of points.
    assert near_other_arm(points.reshape(3, 1, 3), kin, body, "l", 0.05).shape == (3, 1)


def test_arm_pixels_are_both_arm_classes_of_one_side_inside_the_mask():
    labels = torch.tensor([[8, 10, 9, 0], [8, 11, 10, 8]])
    mask = torch.ones(2, 4, dtype=torch.bool)
    mask[1, 3] = False
    assert arm_pixels(labels, mask, "l").tolist() == [[True, True, False, False]] + [
        [True, False, True, False]
    ]
    assert arm_pixels(labels, mask, "r").tolist() == [[False, False, True, False]] + [
        [False, True, False, False]
    ]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_arm_label_agreement_is_the_share_of_labels_on_that_arm(dtype):
    body, q, kin, joints = _rest(dtype)
    elbow, wrist = (joints[sk.JOINT_NAMES.index(f"l_{j}")] for j in ("elbow", "wrist"))
    # Three points on the left forearm's axis (inside it), one 30 cm in front of the elbow.
    points = torch.stack(
        [elbow, 0.5 * (elbow + wrist), wrist, elbow - elbow.new_tensor([0, 0, 0.3])]
    )
    assert float(arm_label_agreement(points, kin, body, "l", 0.05)[0]) == pytest.approx(0.75)
    assert float(arm_label_agreement(points, kin, body, "r", 0.05)[0]) == 0.0
    # A batch of poses: the left arm raised forward takes the forearm away from the points.
    raised = q.repeat(2, 1)
    raised[1, sk.DOF_NAMES.index("l_humerus_flex")] = math.radians(90)
    out = arm_label_agreement(
        points, forward_kinematics(raised, body.to(dtype=dtype)), body, "l", 0.05
    )
    assert out.shape == (2,) and out.dtype == dtype
    assert float(out[0]) == pytest.approx(0.75) and float(out[1]) < 0.5
    assert math.isnan(float(arm_label_agreement(points[:0], kin, body, "l", 0.05)[0]))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_arm_label_conflict_is_the_share_of_the_arm_s_points_labelled_otherwise(dtype):
    body, q, kin, joints = _rest(dtype)
    elbow, wrist, head = (joints[sk.JOINT_NAMES.index(j)] for j in ("l_elbow", "l_wrist", "head"))
    # Three points on the left forearm's axis, one in the head, one 30 cm in front of the
    # elbow: only the first three are the arm's.
    points = torch.stack(
        [elbow, 0.5 * (elbow + wrist), wrist, head, elbow - elbow.new_tensor([0, 0, 0.3])]
    )
    names = ("l_forearm", "chest", "l_upper_arm", "head", "l_forearm")
    labels = torch.tensor([PART_NAMES.index(n) for n in names])
    share, count = arm_label_conflict(points, labels, kin, body, "l", 0.03)
    assert count.tolist() == [3] and float(share[0]) == pytest.approx(1 / 3)
    assert share.dtype == dtype
    # The right arm explains none of them; the left arm raised forward leaves them too.
    share, count = arm_label_conflict(points, labels, kin, body, "r", 0.03)
    assert count.tolist() == [0] and math.isnan(float(share[0]))
    raised = q.repeat(2, 1)
    raised[1, sk.DOF_NAMES.index("l_humerus_flex")] = math.radians(90)
    share, count = arm_label_conflict(
        points, labels, forward_kinematics(raised, body.to(dtype=dtype)), body, "l", 0.03
    )
    assert count.tolist() == [3, 0] and float(share[0]) == pytest.approx(1 / 3)
    # Every point labelled as the arm: no conflict.
    arm = torch.full_like(labels, PART_NAMES.index("l_upper_arm"))
    assert float(arm_label_conflict(points, arm, kin, body, "l", 0.03)[0][0]) == 0.0
    # The other arm's labels count as something else unless left/right swaps are forgiven.
    swapped = labels.clone()
    swapped[1] = PART_NAMES.index("r_forearm")
    assert float(arm_label_conflict(points, swapped, kin, body, "l", 0.03)[0][0]) == (
        pytest.approx(1 / 3)
    )
    forgiven = arm_label_conflict(points, swapped, kin, body, "l", 0.03, other_arm_counts=False)
    assert float(forgiven[0][0]) == 0.0 and forgiven[1].tolist() == [3]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_one_distance_evaluation_serves_every_arm_test(dtype):
    """The arm search evaluates the person's points' distances to the parts once and reads
    every test from them: the same results as each test evaluating its own, to the bit."""
    body, q, kin, joints = _rest(dtype)
    body = body.to(dtype=dtype)
    gen = torch.Generator().manual_seed(1)
    # Points scattered 5 cm around every joint: on the arms, the torso, and between them.
    near = joints[torch.arange(400) % joints.shape[0]]
    points = near + 0.05 * torch.randn(400, 3, generator=gen, dtype=torch.float64).to(dtype)
    labels = torch.randint(0, len(PART_NAMES), (400,), generator=gen)
    geom = segment_geometry(body, body.lengths)
    signed = segment_distances(points[None], kin, body, geom)
    assert torch.equal(signed, segment_distances(points[None], kin, body))
    nearest = signed.min(-1)
    chosen = torch.rand(400, generator=gen) > 0.5
    for side in "lr":
        assert torch.equal(
            near_other_arm_from_distances(signed[0], side, 0.05),
            near_other_arm(points, kin, body, side, 0.05),
        )
        assert torch.equal(
            agreement_from_distances(signed[:, chosen], side, 0.05),
            arm_label_agreement(points[chosen], kin, body, side, 0.05, geom),
        )
        for counts in (True, False):
            want = arm_label_conflict(points, labels, kin, body, side, 0.03, counts, geom)
            got = label_conflict_from_distances(signed, labels, side, 0.03, counts, nearest)
            assert int(got[1][0]) > 10 and torch.equal(got[1], want[1])
            torch.testing.assert_close(got[0], want[0], rtol=0, atol=0)
