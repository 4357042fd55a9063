"""Kinect v1 sensor model: quantization and noise statistics, projector shadows, grazing-angle
dropout, switches, determinism, label masking, and the floor/wall/box background."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import config_from_dict, config_to_dict
from depthmocap.shared.sensor_noise import (
    BackgroundBox,
    BackgroundConfig,
    BackgroundCylinder,
    BackgroundScene,
    KinectNoiseConfig,
    add_floor_and_background,
    apply_kinect_noise,
    box_depth,
    cylinder_depth,
    floor_depth,
    incidence_angle,
    projector_shadow_mask,
    quantize_depth,
    random_background_scene,
    random_holes_mask,
    smooth_disparity,
    wall_depth,
)

INTR80 = Intrinsics.kinect_v1(80)  # 80x60, fx = 71.975
INTR160 = Intrinsics.kinect_v1(160)  # 160x120, fx = 143.95
RNG = np.random.default_rng(0)  # for calls whose result does not depend on it


def only(**on) -> KinectNoiseConfig:
    """All effects off except the given ones (other fields may be overridden too)."""
    return dataclasses.replace(KinectNoiseConfig.disabled(), **on)


def plane(intr: Intrinsics, z: float) -> np.ndarray:
    return np.full((intr.height, intr.width), z, dtype=np.float32)


def box_on_wall(intr, z_box, z_wall, rows, cols) -> np.ndarray:
    """Fronto-parallel wall with a fronto-parallel box (a rectangle of nearer depth)."""
    d = plane(intr, z_wall)
    d[rows[0] : rows[1], cols[0] : cols[1]] = z_box
    return d


@pytest.fixture
def scene():
    """80x60 frame exercising every effect: wall at 3 m, box at 1.5 m, floor seen at grazing
    angles at the bottom, a patch beyond range and one too near; labels nonzero everywhere."""
    wall_floor, _ = add_floor_and_background(
        np.zeros((60, 80), np.float32), None, INTR80, 0.5, 0.0, scene=BackgroundScene(3.0)
    )
    d = wall_floor.copy()
    d[15:35, 30:50] = 1.5
    d[:5, :10] = 5.0
    d[:5, 70:] = 0.3
    labels = np.full(d.shape, 2, np.uint8)
    labels[15:35, 30:50] = 7
    return d, labels


# --------------------------------------------------------------------------------------------
# Quantization and noise


@pytest.mark.parametrize("z0", [1.0, 2.0, 4.0])
def test_quantization_step_matches_literature(z0):
    z = np.linspace(0.95 * z0, 1.05 * z0, 20001, dtype=np.float32)
    levels = np.unique(quantize_depth(z))
    steps = np.diff(levels)
    near = steps[np.argmin(np.abs(levels[:-1] - z0))]
    assert near == pytest.approx(2.9e-3 * z0**2, rel=0.1)
    # Quantization never moves a depth by more than half a step.
    assert np.max(np.abs(quantize_depth(z) - z)) <= 0.55 * 2.9e-3 * (1.05 * z0) ** 2


@pytest.mark.parametrize("z0", [2.0, 4.0])
def test_quantization_through_pipeline_in_mm(z0):
    # A slanted strip of depths around z0; the output levels are spaced by the step (in mm).
    z = np.linspace(0.97 * z0, 1.03 * z0, INTR80.width * INTR80.height, dtype=np.float32)
    out, _ = apply_kinect_noise(
        z.reshape(INTR80.height, INTR80.width),
        None,
        INTR80,
        only(quantize=True),
        np.random.default_rng(0),
    )
    steps = np.diff(np.unique(out)).astype(float)
    assert np.median(steps) == pytest.approx(2.9 * z0**2, rel=0.1)


def test_quantization_uses_native_focal_at_any_resolution():
    z = np.linspace(1.9, 2.1, 5001, dtype=np.float32)
    assert np.array_equal(quantize_depth(z), quantize_depth(z, focal_px=580.0))
    # The step halves with twice the focal length, so the focal really enters.
    a = np.diff(np.unique(quantize_depth(z, focal_px=580.0)))
    b = np.diff(np.unique(quantize_depth(z, focal_px=1160.0)))
    assert np.median(b) == pytest.approx(np.median(a) / 2, rel=0.05)


@pytest.mark.parametrize("z0", [2.0, 4.0])
def test_noise_std_grows_as_z_squared(z0):
    cfg = only(noise=True)
    intr = INTR160
    out, _ = apply_kinect_noise(plane(intr, z0), None, intr, cfg, np.random.default_rng(1))
    err = out.astype(np.float64) / 1000.0 - z0
    assert err.std() == pytest.approx(cfg.noise_k * z0**2, rel=0.2)
    assert abs(err.mean()) < 0.1 * cfg.noise_k * z0**2


def test_correlated_noise_keeps_std_and_correlates_neighbours():
    z0 = 3.0
    cfg0 = only(noise=True, noise_correlated_fraction=0.0)
    cfg1 = only(noise=True, noise_correlated_fraction=0.8)
    rng = np.random.default_rng(2)
    e0 = apply_kinect_noise(plane(INTR160, z0), None, INTR160, cfg0, rng)[0] / 1000.0 - z0
    e1 = apply_kinect_noise(plane(INTR160, z0), None, INTR160, cfg1, rng)[0] / 1000.0 - z0
    assert e1.std() == pytest.approx(e0.std(), rel=0.1)

    def corr(e):  # within the 2x2 blocks: columns 0-1, 2-3, ...
        return np.corrcoef(e[:, 0::2].ravel(), e[:, 1::2].ravel())[0, 1]

    assert abs(corr(e0)) < 0.1 and corr(e1) > 0.6


def test_window_noise_keeps_sigma_and_spreads_over_the_window():
    """Noise drawn before the correlation window: the same sigma_z = k z^2 per pixel (the gain
    makes up for the averaging), alike over a few pixels rather than within 2x2 blocks."""
    z0, intr = 2.8, Intrinsics.kinect_v1(320)
    cfg = only(noise=True)
    e0 = apply_kinect_noise(plane(intr, z0), None, intr, cfg, np.random.default_rng(5))[0]
    cfg = only(noise=True, correlation_smoothing=True)
    e1 = apply_kinect_noise(plane(intr, z0), None, intr, cfg, np.random.default_rng(5))[0]
    e0, e1 = (e[10:-10, 10:-10] / 1000.0 - z0 for e in (e0, e1))
    assert e1.std() == pytest.approx(cfg.noise_k * z0**2, rel=0.1)

    def corr(e, lag):
        return np.corrcoef(e[:, :-lag].ravel(), e[:, lag:].ravel())[0, 1]

    # Alike over the window's width (lag 1: 0.88, lag 2: 0.59), unrelated beyond it.
    assert corr(e1, 1) > 0.8 and corr(e1, 2) > 0.45 and abs(corr(e1, 6)) < 0.1
    assert abs(corr(e0, 2)) < 0.1


# --------------------------------------------------------------------------------------------
# Projector shadows


def test_shadow_band_left_of_foreground_with_formula_width():
    intr = INTR160
    z_box, z_wall = 1.2, 4.0
    d = box_on_wall(intr, z_box, z_wall, rows=(40, 80), cols=(80, 110))
    mask = projector_shadow_mask(d, intr)
    width = intr.fx * 0.075 * (1 / z_box - 1 / z_wall)  # 6.3 px
    assert not mask[:40].any() and not mask[80:].any()  # only rows of the box
    assert not mask[:, 80:].any()  # nothing on the box or right of it (projector side)
    per_row = mask[40:80].sum(axis=1)
    assert np.all(np.abs(per_row - width) <= 1.0)
    # The band touches the box's left edge.
    assert mask[40:80, 79].all()
    # Through the pipeline: exactly those pixels lose their reading.
    out, _ = apply_kinect_noise(d, None, intr, only(shadows=True), np.random.default_rng(0))
    assert np.array_equal(out == 0, mask)


def test_shadow_side_follows_projector_side():
    intr = INTR160
    d = box_on_wall(intr, 1.2, 4.0, rows=(40, 80), cols=(50, 80))
    left = projector_shadow_mask(d, intr, projector_side="left")
    assert left.any() and not left[:, :80].any()  # right of the box now
    assert np.array_equal(left, projector_shadow_mask(d[:, ::-1], intr)[:, ::-1])


def test_thin_object_casts_narrow_shadow():
    # A 2-pixel pole: the shadow is as wide as the pole, shifted left by the band width, and
    # the wall between the shadow and the pole stays lit.
    intr = INTR160
    d = box_on_wall(intr, 1.2, 4.0, rows=(40, 80), cols=(100, 102))
    per_row = projector_shadow_mask(d, intr)[40:80]
    assert np.all(per_row.sum(axis=1) <= 3) and per_row.any()
    assert not per_row[:, 97:100].any()


def test_no_shadow_on_smooth_surfaces():
    intr = INTR80
    assert not projector_shadow_mask(plane(intr, 2.0), intr).any()
    floor, _ = add_floor_and_background(
        np.zeros((60, 80), np.float32), None, intr, 1.0, math.radians(15), scene=BackgroundScene(4)
    )
    assert not projector_shadow_mask(floor, intr).any()


# --------------------------------------------------------------------------------------------
# Grazing angles


def slanted_plane(intr: Intrinsics, angle_deg: float, z0: float = 2.0) -> np.ndarray:
    """Plane through (0, 0, z0) whose normal is ``angle_deg`` from the optical axis (about y)."""
    a = math.radians(angle_deg)
    n = np.array([math.sin(a), 0.0, -math.cos(a)])
    rx = (np.arange(intr.width) - intr.cx) / intr.fx
    ry = (np.arange(intr.height) - intr.cy) / intr.fy
    rx, ry = np.meshgrid(rx, ry)
    return (n[2] * z0 / (n[0] * rx + n[2])).astype(np.float32)  # n . (z r) = n . p0


def test_incidence_angle_of_slanted_plane():
    narrow = Intrinsics(64, 48, 2000.0, 2000.0, 31.5, 23.5)  # +-0.9 deg field of view
    ang = np.degrees(incidence_angle(slanted_plane(narrow, 87.0), narrow))
    assert np.allclose(ang, 87.0, atol=1.0)
    ang = np.degrees(incidence_angle(plane(INTR80, 2.0), INTR80))
    rx = (np.arange(80) - INTR80.cx) / INTR80.fx
    ry = (np.arange(60) - INTR80.cy) / INTR80.fy
    ray = np.degrees(np.arctan(np.hypot(*np.meshgrid(rx, ry))))
    assert np.allclose(ang, ray, atol=0.1)


def test_grazing_dropout_removes_slanted_plane_not_frontal():
    narrow = Intrinsics(64, 48, 2000.0, 2000.0, 31.5, 23.5)
    cfg = only(grazing=True, grazing_start_deg=75.0, grazing_full_deg=85.0)
    rng = np.random.default_rng(3)
    out, _ = apply_kinect_noise(slanted_plane(narrow, 87.0), None, narrow, cfg, rng)
    assert (out == 0).all()
    out, _ = apply_kinect_noise(slanted_plane(narrow, 80.0), None, narrow, cfg, rng)
    assert 0.3 < (out == 0).mean() < 0.7  # half-way up the probability ramp
    out, _ = apply_kinect_noise(slanted_plane(narrow, 60.0), None, narrow, cfg, rng)
    assert (out > 0).all()
    # Fronto-parallel plane and box edges (one-sided gradients): nothing dropped.
    d = box_on_wall(INTR80, 1.5, 3.0, rows=(15, 35), cols=(30, 50))
    out, _ = apply_kinect_noise(d, None, INTR80, only(grazing=True), rng)
    assert (out > 0).all()


def _smooth_reference(z, sigma, gate, fb=580.0 * 0.075):
    """smooth_disparity by its definition, one pixel at a time."""
    out = np.zeros_like(z)
    r = math.ceil(2.5 * sigma)
    for y, x in zip(*np.nonzero(z > 0), strict=True):
        num = den = 0.0
        for v in range(max(0, y - r), min(z.shape[0], y + r + 1)):
            for u in range(max(0, x - r), min(z.shape[1], x + r + 1)):
                if z[v, u] > 0 and abs(z[v, u] - z[y, x]) <= gate:
                    g = math.exp(-((v - y) ** 2 + (u - x) ** 2) / (2 * sigma * sigma))
                    num, den = num + g * fb / z[v, u], den + g
        out[y, x] = fb / (num / den)
    return out


def test_correlation_smoothing_matches_its_definition():
    rng = np.random.default_rng(3)
    z = rng.uniform(1.8, 2.3, (12, 15)).astype(np.float32)
    z[rng.random(z.shape) < 0.2] = 0.0
    got = smooth_disparity(z, 1.1, 0.2)
    np.testing.assert_allclose(got, _smooth_reference(z, 1.1, 0.2), rtol=1e-5)
    assert np.array_equal(got == 0, z == 0)  # no reading stays none, none is averaged in


def test_correlation_smoothing_blends_small_steps_and_keeps_large_ones():
    z = plane(INTR80, 2.0)
    z[:, :10] = 0.0  # no reading: never pulls the body's edge
    z[20:40, 30:45] = 1.92  # a forearm 8 cm in front of the belly
    z[20:40, 60:70] = 1.6  # a hand 40 cm in front
    out = smooth_disparity(z, 1.3, 0.2)
    assert np.array_equal(out == 0, z == 0)
    np.testing.assert_allclose(out[5, 15:25], 2.0, rtol=1e-6)  # a flat surface is unchanged
    row = out[30, 24:36]  # across the 8 cm step: gradual, between the two depths
    assert np.all(np.diff(row) <= 1e-6) and row[0] > 1.999 and row[-1] < 1.921
    assert ((row > 1.925) & (row < 1.995)).sum() >= 3
    # Across the 40 cm step each side keeps its own depth (the body beside it still
    # averages with the body only).
    np.testing.assert_allclose(out[30, 62:68], 1.6, rtol=1e-6)
    np.testing.assert_allclose(out[30, 52:59], 2.0, rtol=1e-6)
    assert np.array_equal(smooth_disparity(z, 0.0, 0.2), z)
    for sigma, gate in ((-1.0, 0.2), (1.3, 0.0), (float("nan"), 0.2)):
        with pytest.raises(ValueError, match="sigma_px"):
            smooth_disparity(z, sigma, gate)


def test_correlation_smoothing_in_the_pipeline_scales_with_width():
    z = plane(INTR160, 2.0)
    z[40:80, 60:90] = 1.92
    cfg = only(correlation_smoothing=True)
    out, _ = apply_kinect_noise(z, None, INTR160, cfg, RNG)
    want = smooth_disparity(z, cfg.correlation_sigma_px * 160 / 320, cfg.correlation_gate_m)
    assert np.array_equal(out, np.rint(want * 1000).astype(np.uint16))
    assert not np.array_equal(out, np.rint(z * 1000).astype(np.uint16))
    with pytest.raises(ValueError, match="correlation"):
        apply_kinect_noise(z, None, INTR160, only(correlation_gate_m=0.0), RNG)


# --------------------------------------------------------------------------------------------
# Switches, determinism, labels


def test_all_off_is_clean_depth_in_mm(scene):
    d, labels = scene
    d = d.copy()
    d[40:45, 5:10] = 0.0
    out, lab = apply_kinect_noise(d, labels, INTR80, KinectNoiseConfig.disabled(), RNG)
    assert out.dtype == np.uint16 and lab.dtype == np.uint8
    assert np.array_equal(out, np.rint(d * 1000).astype(np.uint16))
    assert np.array_equal(lab, np.where(d > 0, labels, 0))


@pytest.mark.parametrize(
    "flag", ["quantize", "noise", "shadows", "grazing", "holes", "edge_erosion", "range_limit"]
)
def test_each_effect_switches_on_alone(scene, flag):
    d, labels = scene
    cfg = only(**{flag: True}, hole_rate=200.0)
    out, _ = apply_kinect_noise(d, labels, INTR80, cfg, np.random.default_rng(4))
    clean = np.rint(d * 1000).astype(np.uint16)
    assert not np.array_equal(out, clean)
    if flag not in ("quantize", "noise"):  # these only remove readings
        assert np.array_equal(out[out > 0], clean[out > 0])


def test_default_model_is_deterministic_per_seed(scene):
    d, labels = scene
    cfg = KinectNoiseConfig()
    a = apply_kinect_noise(d, labels, INTR80, cfg, np.random.default_rng(7))
    b = apply_kinect_noise(d, labels, INTR80, cfg, np.random.default_rng(7))
    c = apply_kinect_noise(d, labels, INTR80, cfg, np.random.default_rng(8))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])


def test_labels_zeroed_exactly_where_depth_lost(scene):
    d, labels = scene
    out, lab = apply_kinect_noise(
        d, labels, INTR80, KinectNoiseConfig(hole_rate=50.0), np.random.default_rng(5)
    )
    assert (out == 0).any()
    assert np.array_equal(lab == 0, out == 0)
    assert np.array_equal(lab[out > 0], labels[out > 0])
    assert (out[:5, :10] == 0).all() and (out[:5, 70:] == 0).all()  # out of range
    assert (
        apply_kinect_noise(d, None, INTR80, KinectNoiseConfig(), np.random.default_rng(5))[1]
        is None
    )


def test_random_holes_are_small_blobs():
    mask = random_holes_mask((240, 320), 20.0, (1.0, 4.0), np.random.default_rng(6))
    # About 15 holes of at most 9x9 pixels.
    assert 0 < mask.sum() < 15 * 3 * 81


def test_input_checks():
    with pytest.raises(ValueError, match="intrinsics"):
        apply_kinect_noise(np.zeros((10, 10)), None, INTR80, KinectNoiseConfig(), RNG)
    with pytest.raises(ValueError, match="labels"):
        apply_kinect_noise(
            plane(INTR80, 2), np.zeros((5, 5), np.uint8), INTR80, KinectNoiseConfig(), RNG
        )
    with pytest.raises(ValueError, match="grazing"):
        apply_kinect_noise(
            plane(INTR80, 2), None, INTR80, KinectNoiseConfig(grazing_start_deg=89.0), RNG
        )


def test_configs_documented_and_round_trip():
    for cls in (KinectNoiseConfig, BackgroundConfig):
        assert all(f.metadata.get("help") for f in dataclasses.fields(cls))
        assert config_from_dict(cls, config_to_dict(cls())) == cls()


# --------------------------------------------------------------------------------------------
# Floor, wall and boxes


def test_floor_depth_matches_analytic_plane():
    intr = Intrinsics(81, 61, 70.0, 70.0, 40.0, 30.0)
    h, pitch = 1.1, math.radians(12.0)
    z = floor_depth(intr, h, pitch)
    assert z[30, 40] == pytest.approx(h / math.sin(pitch))  # optical axis
    # Back-project a few pixels and rotate into the level frame: they lie on y = h.
    c, s = math.cos(pitch), math.sin(pitch)
    rot = np.array([[1, 0, 0], [0, c, s], [0, -s, c]])  # camera -> level (pitched down)
    for v, u in [(60, 0), (45, 70), (35, 40), (31, 80)]:
        p = z[v, u] * np.array([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, 1.0])
        assert (rot @ p)[1] == pytest.approx(h)
    assert np.isinf(z[0]).all()  # above the horizon


def test_background_fills_only_empty_pixels_and_wall_caps_floor():
    intr = INTR80
    body = np.zeros((60, 80), np.float32)
    body[10:50, 35:45] = 2.0
    labels = (body > 0).astype(np.uint8) * 3
    d, lab = add_floor_and_background(
        body, labels, intr, 1.0, math.radians(10), scene=BackgroundScene(4.0)
    )
    assert (d > 0).all()
    assert np.array_equal(d[10:50, 35:45], body[10:50, 35:45])
    assert np.array_equal(lab, labels)
    assert np.all(d <= wall_depth(intr, math.radians(10), 4.0) + 1e-6)  # nearest surface wins
    floor = floor_depth(intr, 1.0, math.radians(10))
    assert d[59, 0] == pytest.approx(floor[59, 0], rel=1e-6)


def test_box_in_front_occludes_body():
    intr = INTR80
    body = plane(intr, 2.5)
    labels = np.full(body.shape, 5, np.uint8)
    # Level camera 2 m above the floor (the floor stays behind the body in this image).
    box = BackgroundBox(-0.3, 0.3, 1.0, 1.4, 1.9)
    behind = BackgroundBox(-0.3, 0.3, 3.0, 3.4, 1.9)  # hidden by the body
    d, lab = add_floor_and_background(
        body, labels, intr, 2.0, 0.0, scene=BackgroundScene(None, (box, behind))
    )
    hit = np.isfinite(box_depth(intr, 2.0, 0.0, box))
    assert 50 < hit.sum() < body.size // 2
    assert (lab[hit] == 0).all() and (lab[~hit] == 5).all()
    assert np.allclose(d[hit], box_depth(intr, 2.0, 0.0, box)[hit])
    assert (d[~hit] == 2.5).all()
    # Pixels through the front face (z = 1.0 plane) read exactly z_min.
    v, u = 59, 40
    assert d[v, u] == pytest.approx(1.0, abs=1e-5)


def test_random_scene_is_drawn_from_rng():
    cfg = BackgroundConfig(wall_prob=1.0, max_boxes=4)
    a = random_background_scene(np.random.default_rng(9), cfg)
    b = random_background_scene(np.random.default_rng(9), cfg)
    assert a == b and 3.0 <= a.wall_distance <= 6.0
    for box in a.boxes:
        assert box.x_min < box.x_max and 1.0 <= box.z_min < box.z_max
    d, _ = add_floor_and_background(
        np.zeros((60, 80), np.float32), None, INTR80, 1.0, 0.2, np.random.default_rng(9), cfg
    )
    assert (d > 0).mean() > 0.5


def test_cylinder_side_and_top_by_ray_geometry():
    """Golden depths of a vertical cylinder against the rays' own geometry: the side at the
    centre column, the top disc seen from above, misses outside it."""
    intr = INTR160
    cam_h = 1.0
    u = 100
    dx = (u - intr.cx) / intr.fx
    # the axis on column u's rays, so they meet the circle at t = 2 - r / sqrt(1 + dx^2)
    cyl = BackgroundCylinder(x=2.0 * dx, z=2.0, radius=0.3, bottom=0.2, top=0.5)
    d = cylinder_depth(intr, cam_h, 0.0, cyl)
    stretch = math.sqrt(1 + dx * dx)
    t_side = 2.0 - 0.3 / stretch
    for v in range(intr.height):
        ry = (v - intr.cy) / intr.fy
        h_side = cam_h - t_side * ry
        t_top = (cam_h - 0.5) / ry if ry > 0 else np.inf
        on_top = ry > 0 and abs(t_top - 2.0) * stretch <= 0.3
        want = min(t_side if 0.2 <= h_side <= 0.5 else np.inf, t_top if on_top else np.inf)
        if np.isinf(want):
            assert np.isinf(d[v, u])
        else:
            assert d[v, u] == pytest.approx(want, rel=1e-9)
    assert np.isinf(d[:, 0]).all()  # nothing far beside it
    assert np.isfinite(d[:, u]).sum() > 3
    # composited: it hides what is behind it, as a box does
    body = plane(intr, 2.5)
    labels = np.full(body.shape, 5, np.uint8)
    out, lab = add_floor_and_background(
        body, labels, intr, cam_h, 0.0, scene=BackgroundScene(None, (), (cyl,))
    )
    hit = np.isfinite(d) & (d < 2.5)
    assert hit.sum() > 50 and (lab[hit] == 0).all()
    np.testing.assert_allclose(out[hit], d[hit], rtol=1e-6)
