"""Distances from joints to where the person leaves the image."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.image_cut import cut_pixels, image_cut_distance_m

INTR = Intrinsics(width=40, height=30, fx=50.0, fy=50.0, cx=19.5, cy=14.5)


def _point(u: float, v: float, z: float) -> list[float]:
    """The camera-frame point that projects to pixel (u, v) at depth z."""
    return [(u - INTR.cx) * z / INTR.fx, (v - INTR.cy) * z / INTR.fy, z]


def test_cut_pixels_are_the_person_s_pixels_on_the_outermost_rows_and_columns():
    mask = torch.zeros(30, 40, dtype=torch.bool)
    mask[10:20, 0:5] = True  # touches the left column
    mask[12:15, 15:20] = True  # inside: not a cut
    uv = cut_pixels(mask)
    assert uv.shape == (10, 2)
    assert (uv[:, 0] == 0).all() and set(uv[:, 1].tolist()) == set(range(10, 20))
    assert cut_pixels(torch.zeros(30, 40, dtype=torch.bool)).shape == (0, 2)


def test_distance_golden_in_pixels_times_depth():
    mask = torch.zeros(30, 40, dtype=torch.bool)
    mask[10, 0] = True  # one pixel of the person on the left edge
    joints = torch.tensor([_point(30.0, 10.0, 2.0), _point(3.0, 14.0, 4.0)], dtype=torch.float64)
    d = image_cut_distance_m(mask, joints, INTR)
    assert d[0].item() == pytest.approx(30.0 * 2.0 / 50.0)  # 30 px at 2 m
    assert d[1].item() == pytest.approx(5.0 * 4.0 / 50.0)  # (3, 4) px away at 4 m


def test_a_whole_person_is_infinitely_far_from_a_cut_and_a_joint_behind_the_camera_at_it():
    mask = torch.zeros(30, 40, dtype=torch.bool)
    mask[5:25, 10:30] = True
    joints = torch.tensor([[_point(20.0, 15.0, 3.0), [0.0, 0.0, -1.0]]], dtype=torch.float64)
    d = image_cut_distance_m(mask, joints, INTR)
    assert d.shape == (1, 2) and math.isinf(d[0, 0].item()) and d[0, 1].item() == 0.0
    mask[29, 20] = True  # now the person reaches the bottom row
    d = image_cut_distance_m(mask, joints, INTR)
    assert d[0, 0].item() == pytest.approx(14.0 * 3.0 / 50.0) and d[0, 1].item() == 0.0


def test_batches_and_a_mask_of_another_image_is_refused():
    mask = torch.zeros(30, 40, dtype=torch.bool)
    mask[0, 20] = True
    joints = torch.tensor(_point(20.0, 8.0, 2.5), dtype=torch.float64).expand(2, 3, 3)
    d = image_cut_distance_m(mask, joints, INTR)
    assert d.shape == (2, 3) and torch.allclose(d, torch.full_like(d, 8.0 * 2.5 / 50.0))
    with pytest.raises(ValueError, match="intrinsics"):
        image_cut_distance_m(torch.zeros(30, 41, dtype=torch.bool), joints, INTR)
