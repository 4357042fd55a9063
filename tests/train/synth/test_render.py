"""Headless depth + label rendering (train.synth.render) and viewpoint sampling
(train.synth.viewpoints).

Rendering is checked against a small numpy reference rasterizer that projects with
``shared.camera.points_to_pixels`` and evaluates every triangle at every pixel centre: depth
must match the analytic plane depth, labels must be exactly the nearest covering triangle's
label, and pixels whose centre lies within a hair of a triangle edge may take the label of any
triangle touching them (or background), nothing else. Tests that need EGL skip when it cannot
be initialised.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from depthmocap.shared.camera import Intrinsics, points_to_pixels
from depthmocap.shared.config import config_from_dict
from depthmocap.train.synth import offscreen_gl
from depthmocap.train.synth.render import (
    EGL_HELP,
    DepthLabelRenderer,
    face_labels_from_vertices,
    render_depth_labels,
    split_by_label,
)
from depthmocap.train.synth.viewpoints import (
    ViewpointConfig,
    fits_in_view,
    look_at,
    sample_person_yaw,
    sample_viewpoint_in_view,
    sample_viewpoints,
    transform_points,
)

INTR = Intrinsics.kinect_v1(320)
LABEL_A, LABEL_B = 40, 200  # far apart, so that a blend of the two is a third value


# --------------------------------------------------------------------------------------------
# Fixtures and reference rasterizer
# --------------------------------------------------------------------------------------------


def _make_renderer(**kw) -> DepthLabelRenderer:
    pytest.importorskip("pyrender")
    try:
        return DepthLabelRenderer(INTR, **kw)
    except RuntimeError as err:
        pytest.skip(f"EGL rendering unavailable: {err}")


@pytest.fixture(scope="module")
def renderer():
    r = _make_renderer()
    yield r
    r.close()


def box(center, size, rot=None) -> tuple[np.ndarray, np.ndarray]:
    """Closed box with outward (counter-clockwise seen from outside) faces: (8, 3), (12, 3)."""
    corners = np.array(
        [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
    ) * np.asarray(size)
    if rot is not None:
        corners = corners @ np.asarray(rot).T
    faces = np.array(
        [
            [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5],  # -x, +x
            [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],  # -y, +y
            [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],  # -z, +z
        ]
    )  # fmt: skip
    return corners + np.asarray(center), faces


def rot_xy(ax_deg: float, ay_deg: float) -> np.ndarray:
    ax, ay = math.radians(ax_deg), math.radians(ay_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    return ry @ rx


def two_boxes() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An upright box (label A, front face at z = 2.0) partly hidden by a tilted box (label B)."""
    va, fa = box((-0.15, 0.0, 2.25), (0.5, 0.6, 0.5))
    vb, fb = box((0.12, 0.1, 1.6), (0.3, 0.3, 0.3), rot_xy(25, 35))
    vertices = np.vstack([va, vb]).astype(np.float32)
    faces = np.vstack([fa, fb + len(va)])
    labels = np.repeat(np.array([LABEL_A, LABEL_B], np.uint8), 8)
    return vertices, faces, labels


def reference(vertices, faces, face_labels, intr: Intrinsics = INTR, tol: float = 0.02):
    """Nearest-triangle depth and label at each pixel centre, and the edge-ambiguous pixels.

    Returns:
        depth (H, W) float64 (0 = none), labels (H, W) uint8, ambiguous (H, W) bool (a pixel
        centre within ``tol`` px of some triangle's edge), allowed (H, W, 256) bool (labels a
        pixel may take: those of triangles covering it within ``tol``, and 0 where ambiguous or
        uncovered).
    """
    v64 = np.asarray(vertices, np.float64)
    uv = points_to_pixels(torch.from_numpy(v64), intr).numpy()
    cols, rows = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    rays = np.stack(
        [(cols - intr.cx) / intr.fx, (rows - intr.cy) / intr.fy, np.ones_like(cols, float)], -1
    )
    h, w = rows.shape
    depth = np.full((h, w), np.inf)
    labels = np.zeros((h, w), np.uint8)
    ambiguous = np.zeros((h, w), bool)
    allowed = np.zeros((h, w, 256), bool)
    for face, label in zip(np.asarray(faces), np.asarray(face_labels)):
        p = uv[face]
        area = (p[1, 0] - p[0, 0]) * (p[2, 1] - p[0, 1]) - (p[1, 1] - p[0, 1]) * (p[2, 0] - p[0, 0])
        if abs(area) < 1e-12:
            continue
        dist = []  # signed distance of each pixel centre to each edge, positive inside
        for a, b in ((0, 1), (1, 2), (2, 0)):
            e = p[b] - p[a]
            cross = e[0] * (rows - p[a, 1]) - e[1] * (cols - p[a, 0])
            dist.append(np.sign(area) * cross / np.hypot(*e))
        dmin = np.minimum(np.minimum(dist[0], dist[1]), dist[2])
        strict, loose = dmin >= tol, dmin >= -tol
        normal = np.cross(v64[face[1]] - v64[face[0]], v64[face[2]] - v64[face[0]])
        z = (normal @ v64[face[0]]) / (rays @ normal)
        closer = strict & (z < depth)
        depth[closer], labels[closer] = z[closer], label
        ambiguous |= loose & ~strict
        allowed[loose, label] = True
    allowed[ambiguous | (labels == 0), 0] = True
    depth[np.isinf(depth)] = 0.0
    return depth, labels, ambiguous, allowed


def check_exact(frame, vertices, faces, face_labels, depth_tol=1e-3) -> dict:
    """Counts of label/depth errors of a rendered frame against :func:`reference`."""
    ref_depth, ref_labels, ambiguous, allowed = reference(vertices, faces, face_labels)
    sure = ~ambiguous
    rows, cols = np.indices(frame.labels.shape)
    return {
        "label_mismatch": int((frame.labels != ref_labels)[sure].sum()),
        "not_allowed": int((~allowed[rows, cols, frame.labels]).sum()),
        "depth_mismatch": int((np.abs(frame.depth - ref_depth) > depth_tol)[sure].sum()),
        "foreground_sure": int((sure & (ref_labels > 0)).sum()),
        "ambiguous": int(ambiguous.sum()),
    }


# --------------------------------------------------------------------------------------------
# Pure helpers
# --------------------------------------------------------------------------------------------


def test_face_labels_majority_and_tie_break():
    faces = np.array([[0, 1, 2], [0, 1, 3], [3, 1, 1], [1, 3, 3], [0, 3, 4]])
    vertex_labels = np.array([5, 5, 5, 7, 9], np.uint8)
    np.testing.assert_array_equal(face_labels_from_vertices(faces, vertex_labels), [5, 5, 5, 7, 5])


def test_split_by_label_duplicates_only_boundary_vertices():
    # Two triangles sharing the edge 1-2, with different labels: 1 and 2 are duplicated.
    faces = np.array([[0, 1, 2], [2, 1, 3], [1, 4, 2]])
    face_labels = np.array([3, 8, 3], np.uint8)
    split = split_by_label(faces, face_labels)
    np.testing.assert_array_equal(split.source[split.faces], faces)
    np.testing.assert_array_equal(split.labels[split.faces], np.repeat(face_labels[:, None], 3, 1))
    assert len(split.source) == 5 + 2
    assert split.faces.dtype == np.uint32 and split.labels.dtype == np.uint8


def test_import_is_cheap_and_sets_egl_platform():
    import os
    import subprocess
    import sys

    code = (
        "import os, sys; os.environ.pop('PYOPENGL_PLATFORM', None); import train.synth.render; "
        "print(os.environ['PYOPENGL_PLATFORM'], 'pyrender' in sys.modules, "
        "'OpenGL' in sys.modules)"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    assert out.stdout.split() == ["egl", "False", "False"]


def test_missing_egl_gives_actionable_error(monkeypatch):
    pyrender = pytest.importorskip("pyrender")

    def no_egl(*args, **kwargs):
        raise AssertionError()  # what pyrender's EGL platform raises when eglInitialize fails

    monkeypatch.setattr(pyrender, "OffscreenRenderer", no_egl)
    with pytest.raises(RuntimeError) as info:
        DepthLabelRenderer(INTR)
    message = str(info.value)
    assert "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri" in message
    assert "PYOPENGL_PLATFORM=egl" in message and EGL_HELP in message


# --------------------------------------------------------------------------------------------
# Rendering (EGL)
# --------------------------------------------------------------------------------------------


def test_multisampling_is_off(renderer):
    assert renderer.samples == 0


def test_two_boxes_depth_and_exact_labels(renderer):
    vertices, faces, vertex_labels = two_boxes()
    frame = renderer.render(vertices, faces, vertex_labels)
    assert frame.depth.shape == frame.labels.shape == (INTR.height, INTR.width)
    assert frame.depth.dtype == np.float32 and frame.labels.dtype == np.uint8
    assert set(np.unique(frame.labels)) == {0, LABEL_A, LABEL_B}  # no blended third values

    face_labels = face_labels_from_vertices(faces, vertex_labels)
    errors = check_exact(frame, vertices, faces, face_labels)
    assert errors["label_mismatch"] == 0 and errors["not_allowed"] == 0, errors
    assert errors["depth_mismatch"] == 0, errors
    assert errors["foreground_sure"] > 20 * errors["ambiguous"], errors  # a meaningful check

    # The upright box's front face is the plane z = 2.0; sample it beside the tilted box.
    corner = points_to_pixels(torch.tensor([-0.35, -0.25, 2.0], dtype=torch.float64), INTR)
    u, v = (int(round(float(c))) + 3 for c in corner)
    assert frame.labels[v, u] == LABEL_A
    assert abs(float(frame.depth[v, u]) - 2.0) < 1e-3
    # Background is 0 in both, and depth > 0 exactly where a label is.
    assert frame.labels[0, 0] == 0 and frame.depth[0, 0] == 0.0
    np.testing.assert_array_equal(frame.depth > 0, frame.labels > 0)


def test_checker_detects_multisampling(monkeypatch):
    """With pyrender's 4x MSAA left on, the same check finds blended labels at edges."""

    def keep_msaa(offscreen):
        offscreen._platform.make_current()
        offscreen._renderer._configure_main_framebuffer()
        return int(offscreen._renderer._main_cb_ms), int(offscreen._renderer._main_db_ms)

    monkeypatch.setattr(offscreen_gl, "disable_multisampling", keep_msaa)
    with _make_renderer() as msaa_renderer:
        assert msaa_renderer.samples > 0
        vertices, faces, vertex_labels = two_boxes()
        frame = msaa_renderer.render(vertices, faces, vertex_labels)
    errors = check_exact(frame, vertices, faces, face_labels_from_vertices(faces, vertex_labels))
    assert errors["not_allowed"] > 0


def test_label_boundary_inside_one_mesh(renderer):
    """A tilted grid whose vertex labels change along a diagonal: per-face majority, exact."""
    n = 8
    gx, gy = np.meshgrid(np.linspace(-0.5, 0.5, n + 1), np.linspace(-0.4, 0.4, n + 1))
    flat = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], -1)
    vertices = (flat @ rot_xy(20, -30).T + [0.05, 0.0, 1.8]).astype(np.float32)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = (
        idx[:-1, :-1].ravel(),
        idx[:-1, 1:].ravel(),
        idx[1:, :-1].ravel(),
        idx[1:, 1:].ravel(),
    )
    faces = np.concatenate([np.stack([a, b, d], -1), np.stack([a, d, c], -1)])
    vertex_labels = np.where(gx.ravel() + 0.7 * gy.ravel() > 0.05, LABEL_B, LABEL_A).astype(
        np.uint8
    )

    frame = renderer.render(vertices, faces, vertex_labels)
    face_labels = face_labels_from_vertices(faces, vertex_labels)
    errors = check_exact(frame, vertices, faces, face_labels)
    assert errors["label_mismatch"] == 0 and errors["not_allowed"] == 0, errors
    assert errors["depth_mismatch"] == 0, errors
    assert set(np.unique(frame.labels)) == {0, LABEL_A, LABEL_B}


@pytest.mark.parametrize("u0,v0", [(37, 81), (160, 120), (301, 7)])
def test_projection_matches_points_to_pixels(renderer, u0, v0):
    """A triangle 0.6 px wide around one pixel centre lights exactly that pixel."""
    z = 2.5
    offsets = np.array([[-0.3, -0.3], [0.3, -0.3], [0.0, 0.3]])
    uv = np.array([u0, v0]) + offsets
    points = np.stack(
        [(uv[:, 0] - INTR.cx) / INTR.fx * z, (uv[:, 1] - INTR.cy) / INTR.fy * z, np.full(3, z)], -1
    )
    projected = points_to_pixels(torch.from_numpy(points), INTR).numpy()
    np.testing.assert_allclose(projected, uv, atol=1e-9)
    frame = renderer.render(points.astype(np.float32), np.array([[0, 1, 2]]), np.full(3, 7))
    lit = np.argwhere(frame.labels > 0)
    np.testing.assert_array_equal(lit, [[v0, u0]])
    assert abs(float(frame.depth[v0, u0]) - z) < 1e-3


def test_reused_renderer_matches_fresh_context(renderer):
    vertices, faces, vertex_labels = two_boxes()
    renderer.set_mesh(faces, vertex_labels)
    renderer.render(vertices)
    moved = vertices + np.array([0.05, -0.03, 0.2], np.float32)
    reused = renderer.render(moved)  # in-place vertex upload
    assert renderer._vbo is not None  # the fast path was taken
    fresh = render_depth_labels(moved, faces, vertex_labels, INTR)
    np.testing.assert_array_equal(reused.labels, fresh.labels)
    np.testing.assert_array_equal(reused.depth, fresh.depth)
    # A different topology replaces the mesh.
    vs, fs = box((0.0, 0.0, 3.0), (0.4, 0.4, 0.4))
    other = renderer.render(vs.astype(np.float32), fs, np.full(8, 3))
    assert set(np.unique(other.labels)) == {0, 3}


def test_back_face_culling_same_image_for_closed_mesh(renderer):
    vertices, faces, vertex_labels = two_boxes()
    both = renderer.render(vertices, faces, vertex_labels)
    with _make_renderer(cull_back_faces=True) as culling:
        culled = culling.render(vertices, faces, vertex_labels)
    np.testing.assert_array_equal(both.labels, culled.labels)
    np.testing.assert_array_equal(both.depth, culled.depth)


def test_clipping_planes_and_empty_mesh(renderer):
    vs, fs = box((0.0, 0.0, 12.0), (1.0, 1.0, 1.0))  # beyond zfar = 10
    frame = renderer.render(vs.astype(np.float32), fs, np.full(8, 5))
    assert not frame.labels.any() and not frame.depth.any()
    empty = renderer.render(np.zeros((0, 3), np.float32), np.zeros((0, 3), int), np.zeros(0))
    assert not empty.labels.any() and not empty.depth.any()


def test_input_validation_and_close():
    r = _make_renderer()
    vertices, faces, vertex_labels = two_boxes()
    with pytest.raises(ValueError):
        r.render(vertices)  # no mesh yet
    with pytest.raises(ValueError):
        r.render(vertices[:5], faces, vertex_labels)
    with pytest.raises(ValueError):
        r.render(vertices, faces, vertex_labels.astype(int) + 300)
    with pytest.raises(ValueError):
        r.set_mesh(faces, vertex_labels, face_labels=np.zeros(len(faces)))
    with r:
        pass
    assert r.closed
    r.close()  # idempotent
    with pytest.raises(RuntimeError):
        r.render(vertices, faces, vertex_labels)


# --------------------------------------------------------------------------------------------
# Viewpoints
# --------------------------------------------------------------------------------------------


def test_viewpoint_config_fields_documented_and_loadable():
    for f in dataclasses.fields(ViewpointConfig):
        assert f.metadata.get("help"), f.name
    cfg = config_from_dict(ViewpointConfig, {"distance_max": 3.5, "front_weight": 0.8})
    assert cfg.distance_max == 3.5
    cfg.validate()
    with pytest.raises(ValueError):
        ViewpointConfig(distance_min=5.0).validate()


def test_viewpoint_ranges_and_rigidity():
    cfg = ViewpointConfig()
    views = sample_viewpoints(np.random.default_rng(0), 4000, cfg)
    assert views.cam_from_world.shape == (4000, 4, 4)
    assert (views.distance >= cfg.distance_min).all() and (views.distance <= cfg.distance_max).all()
    assert (views.height >= cfg.height_min).all() and (views.height <= cfg.height_max).all()
    assert np.abs(views.roll).max() <= math.radians(cfg.roll_max_deg)
    rot = views.cam_from_world[:, :3, :3]
    np.testing.assert_allclose(
        rot @ rot.transpose(0, 2, 1), np.broadcast_to(np.eye(3), rot.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-12)
    # The camera centre maps to the camera origin; horizontal distance and height as sampled.
    origin = transform_points(views.cam_from_world, views.position[:, None])[:, 0]
    np.testing.assert_allclose(origin, 0.0, atol=1e-12)
    np.testing.assert_allclose(np.hypot(views.position[:, 0], views.position[:, 2]), views.distance)
    np.testing.assert_allclose(views.position[:, 1], views.height)
    # The aim point is near the optical axis (jitter only) and in front of the camera.
    target = transform_points(views.cam_from_world, np.array([[0.0, cfg.target_height, 0.0]]))[:, 0]
    off_axis = np.degrees(np.arctan2(np.hypot(target[:, 0], target[:, 1]), target[:, 2]))
    assert (target[:, 2] > 0).all() and off_axis.max() < 1.5 * cfg.aim_jitter_deg


def test_yaw_mixture_favours_front():
    cfg = ViewpointConfig()
    yaw = np.degrees(np.abs(sample_person_yaw(np.random.default_rng(1), 20000, cfg)))
    front = (yaw <= cfg.front_half_angle_deg).mean()
    back = (yaw >= 180 - cfg.back_half_angle_deg).mean()
    side = 1.0 - front - back
    assert abs(front - cfg.front_weight) < 0.02
    assert abs(side - cfg.side_weight) < 0.02
    assert abs(back - cfg.back_weight) < 0.02
    assert front > side > back
    hist, _ = np.histogram(yaw, bins=[0, 45, 90, 135, 180])
    assert hist[0] == hist.max()


def test_yaw_zero_sees_the_front_and_left_is_image_right():
    """Camera in front (yaw 0): the person's left (+x world) appears on the image's right."""
    cam = look_at(np.array([[0.0, 1.0, 3.0]]), np.array([0.0, 1.0, 0.0]))
    pts = transform_points(cam, np.array([[[0.3, 1.0, 0.0], [0.0, 1.5, 0.0]]]))[0]
    uv = points_to_pixels(torch.from_numpy(pts), INTR).numpy()
    assert uv[0, 0] > INTR.cx  # left hand on the right of the image
    assert uv[1, 1] < INTR.cy  # higher in the world is higher in the image (smaller row)


def test_viewpoints_deterministic_per_seed():
    a = sample_viewpoints(np.random.default_rng(7), 50)
    b = sample_viewpoints(np.random.default_rng(7), 50)
    c = sample_viewpoints(np.random.default_rng(8), 50)
    np.testing.assert_array_equal(a.cam_from_world, b.cam_from_world)
    assert not np.allclose(a.cam_from_world, c.cam_from_world)


def test_fits_in_view_and_rejection_sampling():
    pts = np.array([[0.0, 0.0, 2.0], [0.5, 0.3, 2.0]])
    assert fits_in_view(pts, INTR)
    assert not fits_in_view(pts * [1, 1, -1], INTR)  # behind the camera
    u_edge = (INTR.width - 0.5 - 1.0 - INTR.cx) / INTR.fx * 2.0  # exactly 1 px from the border
    edge = np.array([[u_edge, 0.0, 2.0]])
    assert fits_in_view(edge, INTR, margin_px=1.0 - 1e-6)
    assert not fits_in_view(edge, INTR, margin_px=1.0 + 1e-6)
    assert fits_in_view(torch.tensor(np.stack([pts, pts])), INTR).shape == (2,)
    assert fits_in_view(edge, INTR, max_depth=2.0 + 1e-6)
    assert not fits_in_view(edge, INTR, max_depth=2.0 - 1e-6)  # beyond the sensor's range

    # A 1.8 m tall, 0.5 m wide "person" standing at the origin.
    body = np.array([[x, y, z] for x in (-0.25, 0.25) for y in (0.0, 1.8) for z in (-0.15, 0.15)])
    views = sample_viewpoints(np.random.default_rng(3), 500)
    fits = fits_in_view(transform_points(views.cam_from_world, body[None]), INTR)
    assert 0 < fits.mean() < 1  # near views crop a tall person; far ones do not
    view = sample_viewpoint_in_view(np.random.default_rng(3), body, INTR, margin_px=2.0)
    assert view is not None and view.cam_from_world.shape == (1, 4, 4)
    assert fits_in_view(transform_points(view.cam_from_world[0], body), INTR, margin_px=2.0)
    near = ViewpointConfig(distance_min=0.6, distance_max=0.7)
    assert sample_viewpoint_in_view(np.random.default_rng(3), body, INTR, near) is None
    in_range = sample_viewpoint_in_view(np.random.default_rng(3), body, INTR, max_depth=3.5)
    assert in_range is not None
    assert transform_points(in_range.cam_from_world[0], body)[:, 2].max() < 3.5
