"""Where the forest sees each joint's parts: the k-th nearest labelled pixel and the count."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.labels import PART_NAMES
from depthmocap.shared.part_evidence import (
    JOINT_PARTS,
    image_part_evidence,
    part_distances,
    part_membership,
)

J = len(sk.JOINT_NAMES)


def test_every_joint_has_parts_the_forest_knows():
    assert set(JOINT_PARTS) == set(sk.JOINT_NAMES)
    member = part_membership()
    assert member.shape == (len(PART_NAMES), J)
    assert not member[0].any()  # background is nobody's part
    assert member.any(0).all()
    assert member[PART_NAMES.index("l_forearm"), sk.JOINT_NAMES.index("l_wrist")]
    assert not member[PART_NAMES.index("r_forearm"), sk.JOINT_NAMES.index("l_wrist")]


def test_the_k_th_nearest_pixel_of_the_joint_s_parts_golden():
    forearm = PART_NAMES.index("l_forearm")
    head = PART_NAMES.index("head")
    # Six l_forearm pixels 0.1..0.6 m along x from the origin; one head pixel at the origin.
    points = torch.cat([torch.tensor([[0.1 * (i + 1), 0.0, 0.0] for i in range(6)]),
                        torch.zeros(1, 3)]).double()  # fmt: skip
    labels = torch.tensor([forearm] * 6 + [head])
    joints = torch.zeros(J, 3, dtype=torch.float64)
    near, count = part_distances(points, labels, joints, k=5)
    wrist, elbow = sk.JOINT_NAMES.index("l_wrist"), sk.JOINT_NAMES.index("l_elbow")
    assert near[wrist].item() == pytest.approx(0.5) and count[wrist].item() == 6
    assert near[elbow].item() == pytest.approx(0.5)  # the forearm is one of the elbow's parts
    h = sk.JOINT_NAMES.index("head")
    assert math.isinf(near[h].item()) and count[h].item() == 1  # fewer than k head pixels
    near1, _ = part_distances(points, labels, joints, k=1)
    assert near1[h].item() == 0.0 and near1[wrist].item() == pytest.approx(0.1)
    with pytest.raises(ValueError, match="k"):
        part_distances(points, labels, joints, k=0)


def test_a_value_outside_the_classes_is_nobody_s_part():
    forearm = PART_NAMES.index("l_forearm")
    points = torch.zeros(6, 3, dtype=torch.float64)
    labels = torch.tensor([forearm] * 5 + [len(PART_NAMES)])
    near, count = part_distances(points, labels, torch.zeros(J, 3, dtype=torch.float64))
    r_shank = sk.JOINT_NAMES.index("r_ankle")  # the last class's joint
    assert count[sk.JOINT_NAMES.index("l_wrist")].item() == 5 and count[r_shank].item() == 0
    assert math.isinf(near[r_shank].item())


def test_no_pixels_at_all_gives_inf_and_zero():
    near, count = part_distances(torch.zeros(0, 3), torch.zeros(0, dtype=torch.long),
                                 torch.zeros(J, 3))  # fmt: skip
    assert torch.isinf(near).all() and (count == 0).all()


@pytest.mark.parametrize("compiled", [True, False])
def test_an_image_s_evidence_reads_only_the_labelled_person_pixels(compiled, monkeypatch):
    if compiled:
        pytest.importorskip("numba")
    else:  # the torch path, as on a GPU or without numba
        import depthmocap.shared.part_evidence as module

        monkeypatch.setattr(module, "compiled_module", lambda name: None)
    intr = Intrinsics(fx=100.0, fy=100.0, cx=2.0, cy=2.0, width=5, height=5)
    depth = torch.full((5, 5), 2.0)
    depth[0, 0] = 0.0  # no reading
    labels = torch.full((5, 5), PART_NAMES.index("head"), dtype=torch.long)
    labels[4] = 0  # background row
    mask = torch.ones(5, 5, dtype=torch.bool)
    mask[:, 4] = False  # not the person
    joints = torch.zeros(J, 3, dtype=torch.float64)
    joints[sk.JOINT_NAMES.index("head")] = torch.tensor([0.0, 0.0, 2.0])  # the centre pixel
    ev = image_part_evidence(depth, mask, labels, intr, joints)
    h = sk.JOINT_NAMES.index("head")
    assert ev.shape == (J, 2) and ev.dtype == torch.float64
    assert ev[h, 1].item() == 4 * 4 - 1  # rows 0-3, columns 0-3, less the missing reading
    # Nearest: the centre pixel itself (0), then its four neighbours (0.02 m): the 5th is one.
    assert ev[h, 0].item() == pytest.approx(0.02, rel=1e-6)


def test_the_compiled_pass_gives_the_torch_path_s_evidence():
    pytest.importorskip("numba")
    from depthmocap.shared.camera import depth_to_points

    intr = Intrinsics.kinect_v1(160)
    g = torch.Generator().manual_seed(0)
    depth = torch.zeros(intr.height, intr.width)
    depth[30:100, 60:90] = 2.5 + 0.3 * torch.rand(70, 30, generator=g)
    depth[50, 70] = 0.0
    mask = depth > 0
    mask[80:85, 60:70] = False
    labels = torch.randint(0, len(PART_NAMES), depth.shape, generator=g) * mask
    joints = torch.rand(J, 3, generator=g, dtype=torch.float64) * torch.tensor([0.4, 1.2, 0.3])
    joints += torch.tensor([0.0, -0.6, 2.5], dtype=torch.float64)
    labels[labels == PART_NAMES.index("head")] = 0  # a joint with no pixels of its parts
    labels[40:45, 60:90] = len(PART_NAMES) + 5  # not a class: nobody's part on either path
    compiled = image_part_evidence(depth, mask, labels, intr, joints)
    keep = mask & (depth > 0) & (labels > 0)
    points = depth_to_points(depth[None], intr)[0][keep].double()
    near, count = part_distances(points, labels[keep], joints)
    torch.testing.assert_close(compiled[:, 0], near, rtol=0, atol=1e-12)
    torch.testing.assert_close(compiled[:, 1], count)
    assert math.isinf(compiled[sk.JOINT_NAMES.index("head"), 0].item())
