"""Clothing over the rendered body (train.synth.garments): leg gaps closed, silhouettes grown,
nothing drawn when off."""

from __future__ import annotations

import numpy as np
import pytest
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.labels import PART_NAMES
from depthmocap.train.synth.frame import SceneConfig
from depthmocap.train.synth.garments import (
    GarmentConfig,
    close_leg_gaps,
    dress_body,
    thicken_silhouette,
)

INTR = Intrinsics.kinect_v1(320)
L_THIGH, R_THIGH = PART_NAMES.index("l_thigh_lower"), PART_NAMES.index("r_thigh_lower")
L_FOREARM, PELVIS = PART_NAMES.index("l_forearm"), PART_NAMES.index("pelvis")


def _two_bars(left_label: int, right_label: int, d_left: float, d_right: float, gap_px: int):
    """Two 6-px bars in rows 100-139 with ``gap_px`` background columns between them."""
    depth = np.zeros((INTR.height, INTR.width), np.float32)
    labels = np.zeros(depth.shape, np.uint8)
    a0, a1 = 150, 156
    b0 = a1 + gap_px
    depth[100:140, a0:a1], labels[100:140, a0:a1] = d_left, left_label
    depth[100:140, b0 : b0 + 6], labels[100:140, b0 : b0 + 6] = d_right, right_label
    return depth, labels, a1, b0


def test_gap_between_legs_closed_with_interpolated_depth_and_each_legs_label():
    depth, labels, a1, b0 = _two_bars(L_THIGH, R_THIGH, 2.0, 2.05, gap_px=4)
    d, lab = close_leg_gaps(depth, labels, INTR, max_gap_m=0.05, max_depth_step_m=0.1)
    # 4 px at 2.025 m is 2.8 cm: closed on every row of the bars, nowhere else.
    assert np.all(lab[100:140, a1:b0] > 0) and np.all(d[100:140, a1:b0] > 0)
    assert np.count_nonzero(lab) == np.count_nonzero(labels) + 40 * 4
    # Depth runs linearly from edge to edge (t = 1/5 .. 4/5 of the way).
    t = (np.arange(a1, b0) - (a1 - 1)) / (b0 - (a1 - 1))
    np.testing.assert_allclose(d[120, a1:b0], 2.0 + 0.05 * t, atol=1e-6)
    # The half next to each leg carries that leg's label.
    assert list(lab[120, a1:b0]) == [L_THIGH, L_THIGH, R_THIGH, R_THIGH]
    # The inputs are left alone.
    assert np.count_nonzero(labels[100:140, a1:b0]) == 0


@pytest.mark.parametrize(
    ("left", "right", "d_right", "max_gap", "why"),
    [
        (L_THIGH, R_THIGH, 2.0, 0.02, "wider than the gap closed"),
        (L_THIGH, R_THIGH, 2.2, 0.05, "legs too far apart in depth"),
        (L_FOREARM, R_THIGH, 2.0, 0.05, "a forearm beside a leg is not a trouser leg"),
        (L_THIGH, L_THIGH, 2.0, 0.05, "both edges the same leg"),
        (PELVIS, R_THIGH, 2.0, 0.05, "the pelvis is not a leg"),
    ],
)
def test_gap_left_open(left, right, d_right, max_gap, why):
    depth, labels, _, _ = _two_bars(left, right, 2.0, d_right, gap_px=4)
    d, lab = close_leg_gaps(depth, labels, INTR, max_gap_m=max_gap, max_depth_step_m=0.1)
    np.testing.assert_array_equal(lab, labels, err_msg=why)
    np.testing.assert_array_equal(d, depth, err_msg=why)


def test_silhouette_grown_by_the_thickness_at_its_depth():
    depth = np.zeros((INTR.height, INTR.width), np.float32)
    labels = np.zeros(depth.shape, np.uint8)
    depth[120, 160], labels[120, 160] = 2.0, PELVIS
    # 2 cm at 2 m is 2.88 px (fx 287.9): every pixel within that radius is grown.
    d, lab = thicken_silhouette(depth, labels, INTR, thickness_m=0.02)
    vv, uu = np.nonzero(lab)
    r2 = (vv - 120) ** 2 + (uu - 160) ** 2
    radius = 0.02 * INTR.fx / 2.0
    assert r2.max() <= radius**2
    expected = sum(1 for a in range(-3, 4) for b in range(-3, 4) if a * a + b * b <= radius**2)
    assert len(vv) == expected == 25
    assert np.all(lab[vv, uu] == PELVIS) and np.all(d[vv, uu] == 2.0)
    # Nothing grown for zero thickness.
    d0, lab0 = thicken_silhouette(depth, labels, INTR, thickness_m=0.0)
    np.testing.assert_array_equal(lab0, labels)


def test_grown_pixels_never_cover_a_surface():
    depth = np.full((INTR.height, INTR.width), 5.0, np.float32)  # a wall, no label
    labels = np.zeros(depth.shape, np.uint8)
    depth[120, 160], labels[120, 160] = 2.0, PELVIS
    d, lab = thicken_silhouette(depth, labels, INTR, thickness_m=0.05)
    np.testing.assert_array_equal(lab, labels)
    np.testing.assert_array_equal(d, depth)


def test_off_draws_nothing_and_changes_nothing():
    depth, labels, _, _ = _two_bars(L_THIGH, R_THIGH, 2.0, 2.0, gap_px=4)
    rng = np.random.default_rng(5)
    d, lab = dress_body(depth, labels, INTR, GarmentConfig(), rng)
    assert d is depth and lab is labels
    assert rng.random() == np.random.default_rng(5).random()  # the stream is untouched
    assert SceneConfig().garments.probability == 0.0  # evaluation recordings stay bare


def test_always_on_closes_and_grows():
    depth, labels, a1, b0 = _two_bars(L_THIGH, R_THIGH, 2.0, 2.0, gap_px=4)
    cfg = GarmentConfig(probability=1.0, thickness_m=(0.01, 0.01), leg_gap_m=(0.05, 0.05))
    d, lab = dress_body(depth, labels, INTR, cfg, np.random.default_rng(0))
    assert np.all(lab[100:140, a1:b0] > 0)
    assert lab[99, 152] == L_THIGH and lab[140, b0 + 2] == R_THIGH  # grown above and below
    assert np.count_nonzero(lab) > np.count_nonzero(labels) + 40 * 4


@pytest.mark.parametrize(
    "bad",
    [
        {"probability": 1.5},
        {"thickness_m": (0.03, 0.01)},
        {"leg_gap_m": (-0.01, 0.1)},
        {"max_depth_step_m": 0.0},
    ],
)
def test_invalid_config_is_a_clear_error(bad):
    with pytest.raises(ValueError, match="garments"):
        GarmentConfig(**bad).validate()
