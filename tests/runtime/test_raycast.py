"""Body ray-caster: golden depths, segment ids, local-point round trip, normals, batching."""

from __future__ import annotations

import math

import pytest
import torch
from depthmocap.runtime.raycast import (
    render_body,
    render_body_depth,
    segment_geometry,
    surface_distance,
    surface_normals,
)
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics, depth_to_points
from depthmocap.shared.kinematics import forward_kinematics, rest_pose, segment_points_to_world

# Principal point on a pixel centre so the centre pixel's ray is the optical axis.
INTR = Intrinsics(320, 240, 287.9, 287.9, 160.0, 120.0)
SMALL = Intrinsics(160, 120, 143.95, 143.95, 80.0, 60.0)


def _project(point: torch.Tensor, intr: Intrinsics) -> tuple[int, int]:
    u = intr.fx * point[0] / point[2] + intr.cx
    v = intr.fy * point[1] / point[2] + intr.cy
    return int(round(float(u))), int(round(float(v)))


def _posed(dtype=torch.float64, device="cpu") -> torch.Tensor:
    q = rest_pose(2, dtype=dtype, device=device)
    names = {n: i for i, n in enumerate(sk.DOF_NAMES)}
    q[1, 0:3] = torch.tensor([0.1, -0.05, 2.8], dtype=dtype)
    q[1, names["l_humerus_abd"]] = 1.2
    q[1, names["l_radius_flex"]] = 1.0
    q[1, names["r_femur_flex"]] = 0.6
    q[1, names["r_tibia_flex"]] = 0.9
    q[1, names["lower_back_y"]] = 0.3
    q[1, names["head_y"]] = 0.4
    return q


def test_pelvis_depth_golden_value():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, root_position=(0.0, 0.0, 2.5), dtype=torch.float64)
    r = render_body(q, body, INTR)
    # The optical axis meets the pelvis's front: root z minus the torso's depth semi-axis.
    assert int(r.segment[0, 120, 160]) == 0
    assert float(r.depth[0, 120, 160]) == pytest.approx(2.5 - float(body.radii[0, 1]), abs=1e-3)
    assert bool(r.mask[0, 120, 160])


def test_segment_ids_at_projected_centres():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, dtype=torch.float64)
    r = render_body(q, body, INTR)
    kin = r.kin
    for seg, frac in ((4, 0.5), (2, 0.5), (9, 0.5), (10, 0.5), (13, 0.5), (14, 0.5)):
        local = (
            torch.as_tensor(sk.SEGMENT_AXIS[seg], dtype=torch.float64) * body.lengths[seg] * frac
        )
        p = segment_points_to_world(kin, local[None, None], torch.tensor([seg]))[0, 0]
        u, v = _project(p, INTR)
        assert int(r.segment[0, v, u]) == seg, sk.SEGMENT_NAMES[seg]
    # Facing the camera, the person's left (body +x) is on the image's right.
    u_left, _ = _project(kin.origins[0, 9], INTR)
    assert u_left > INTR.cx
    assert int(r.segment[0, 0, 0]) == -1 and float(r.depth[0, 0, 0]) == 0.0


def _offset_body() -> BodyShape:
    """The default body with its sections moved off the joint axes (as measured on meshes)."""
    body = BodyShape.default(torch.float64)
    g = torch.Generator().manual_seed(3)
    body.offsets = 0.03 * (2 * torch.rand(15, 2, generator=g, dtype=torch.float64) - 1)
    return body


BODIES = {"default": lambda: BodyShape.default(torch.float64), "offsets": _offset_body}


def test_section_offset_moves_the_surface():
    body = BodyShape.default(torch.float64)
    body.offsets[0, 1] = 0.02  # pelvis centre 2 cm forward, towards the camera
    q = rest_pose(1, root_position=(0.0, 0.0, 2.5), dtype=torch.float64)
    r = render_body(q, body, INTR)
    assert int(r.segment[0, 120, 160]) == 0
    expected = 2.5 - float(body.radii[0, 1]) - 0.02
    assert float(r.depth[0, 120, 160]) == pytest.approx(expected, abs=1e-3)


def test_feet_ride_on_the_shanks():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, root_position=(0.0, -0.5, 2.5), dtype=torch.float64)  # feet in view
    r = render_body(q, body, INTR)
    for side, seg in enumerate((13, 14)):
        toe, radius = (float(x) for x in body.feet[side])
        sole = float(body.lengths[seg] + body.extents[seg, 1])
        # Front of the toe cap, in the shank's frame (its axis points down, z forward).
        local = torch.tensor([0.0, -(sole - radius), toe], dtype=torch.float64)
        p = segment_points_to_world(r.kin, local[None, None], torch.tensor([seg]))[0, 0]
        u, v = _project(p, INTR)
        assert int(r.segment[0, v, u]) == seg, sk.SEGMENT_NAMES[seg]
        assert float(r.depth[0, v, u]) == pytest.approx(float(p[2]), abs=3e-3)
    no_feet = BodyShape.default(torch.float64)
    no_feet.feet = torch.full((2, 2), 1e-3, dtype=torch.float64)
    assert int(render_body(q, no_feet, INTR).mask.sum()) < int(r.mask.sum())


@pytest.mark.parametrize("make_body", BODIES.values(), ids=BODIES.keys())
def test_local_points_round_trip_to_depth_points(make_body):
    body = make_body()
    q = _posed()
    r = render_body(q, body, SMALL)
    world = depth_to_points(r.depth, SMALL)  # (B, H, W, 3)
    for b in range(2):
        hit = r.mask[b]
        seg = r.segment[b][hit]
        back = segment_points_to_world(
            forward_kinematics(q[b : b + 1], body), r.local_points[b][hit][None], seg
        )[0]
        assert torch.allclose(back, world[b][hit], atol=1e-9)
    assert torch.equal(r.mask, r.depth > 0)
    assert torch.equal(r.mask, r.segment >= 0)


@pytest.mark.parametrize("make_body", BODIES.values(), ids=BODIES.keys())
def test_rendered_points_lie_on_the_surface_and_normals_face_the_camera(make_body):
    body = make_body()
    q = _posed()
    r = render_body(q, body, SMALL)
    pts = depth_to_points(r.depth, SMALL)[r.mask].reshape(1, -1, 3)
    b = torch.nonzero(r.mask)[:, 0]
    for i in range(2):
        mine = pts[:, b == i]
        dist = surface_distance(mine, forward_kinematics(q[i : i + 1], body), body)
        assert float(dist.max()) < 1e-6
    n = r.normals[r.mask]
    assert torch.allclose(n.norm(dim=-1), torch.ones(n.shape[0], dtype=n.dtype), atol=1e-9)
    assert bool(((n * pts[0]).sum(-1) < 0).all())  # towards the camera
    # Points off the surface: a point 5 cm in front of the pelvis is 5 cm away.
    body = BodyShape.default(torch.float64)
    front = torch.tensor([[[0.0, 0.0, 2.5 - 0.11 - 0.05]]], dtype=torch.float64)
    kin = forward_kinematics(rest_pose(1, dtype=torch.float64), body)
    assert float(surface_distance(front, kin, body)[0, 0]) == pytest.approx(0.05, abs=1e-6)


@pytest.mark.parametrize("make_body", BODIES.values(), ids=BODIES.keys())
def test_normals_at_chosen_pixels_are_the_rendered_surface_s(make_body):
    # Independent reference: the normal of the rendered point cloud itself, from central
    # differences of neighbouring pixels on the same primitive, at 640x480 (4.5 mm pixels).
    fine = Intrinsics(640, 480, 575.8, 575.8, 320.0, 240.0)
    body = make_body()
    q = _posed()
    full = render_body(q, body, fine)
    lean = render_body(q, body, fine, details=False)
    assert lean.normals is None and lean.local_points is None
    assert torch.equal(lean.depth, full.depth) and torch.equal(lean.segment, full.segment)
    pts = depth_to_points(full.depth, fine)
    prim = full.primitive
    inner = prim[:, 1:-1, 1:-1]
    same = inner >= 0
    for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        same &= prim[:, 1 + dv : prim.shape[1] - 1 + dv, 1 + du : prim.shape[2] - 1 + du] == inner
    tu = pts[:, 1:-1, 2:] - pts[:, 1:-1, :-2]
    tv = pts[:, 2:, 1:-1] - pts[:, :-2, 1:-1]
    ref = torch.nn.functional.normalize(torch.linalg.cross(tv, tu, dim=-1), dim=-1)
    idx = same.nonzero()[::3]
    b, v, u = idx.unbind(1)
    idx = torch.stack([b, v + 1, u + 1], 1)  # back to full-image pixels
    got = surface_normals(lean, idx, pts[b, v + 1, u + 1])
    cos = (got * ref[b, v, u]).sum(-1)
    assert float(cos.median()) > 0.9999 and float(torch.quantile(cos, 0.05)) > 0.999
    assert torch.allclose(got, full.normals[b, v + 1, u + 1], atol=1e-9)


def test_box_culling_batching_and_dtypes_agree():
    body = BodyShape.default(torch.float64)
    q = _posed()
    full = render_body(q, body, SMALL, box=False)
    boxed = render_body(q, body, SMALL)
    assert torch.equal(full.segment, boxed.segment)
    assert torch.allclose(full.depth, boxed.depth)
    single = render_body(q[1:], body, SMALL)
    assert torch.equal(single.segment[0], boxed.segment[1])
    f32 = render_body_depth(q.float(), BodyShape.default(), SMALL)
    assert f32.dtype == torch.float32 and f32.shape == (2, 120, 160)
    both = full.mask & (f32 > 0)
    err = (f32.double() - full.depth)[both].abs()
    # float32 loses a little at grazing hits (the quadratic's discriminant nears zero).
    assert float(err.max()) < 1e-3 and float(err.median()) < 1e-5


def test_caps_keep_the_stature():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, root_position=(0.0, 0.0, 3.0), dtype=torch.float64)
    side = Intrinsics(200, 400, 300.0, 300.0, 100.0, 200.0)
    r = render_body(q, body, side)
    kin = r.kin
    # Sole (below the shank and the foot) and top of the head in metres: camera y of the hits.
    v = torch.arange(side.height, dtype=torch.float64)[:, None].expand(-1, side.width)
    y = ((v - side.cy) / side.fy * r.depth[0])[r.mask[0]]
    # Pixels are 1 cm apart at 3 m; the outermost hits graze the caps within a pixel or two.
    assert float(y.max() - y.min()) == pytest.approx(float(body.stature()), abs=0.03)
    assert kin.origins.shape == (1, 15, 3)


def test_empty_when_the_body_is_behind_the_camera():
    body = BodyShape.default()
    q = rest_pose(1, root_position=(0.0, 0.0, -3.0))
    r = render_body(q, body, INTR)
    assert not bool(r.mask.any()) and float(r.depth.abs().sum()) == 0.0


def test_geometry_spans():
    body = BodyShape.default(torch.float64)
    geom = segment_geometry(body, torch.zeros(1, dtype=torch.float64))
    # The forearm's cap ends at the hand's end, the upper arm's cap bulges past the elbow.
    cap = geom.scale[9, 2]
    assert float(geom.span[9, 1] + cap) == pytest.approx(0.26 + 0.10)
    assert float(geom.span[7, 1]) == pytest.approx(0.29)
    assert math.isclose(float(geom.span[0, 0] - geom.scale[0, 2]), -0.08)


@pytest.mark.gpu
def test_cuda_matches_cpu():
    body = BodyShape.default()
    q = _posed(torch.float32)
    cpu = render_body(q, body, INTR)
    gpu = render_body(q.cuda(), body.to(device="cuda"), INTR)
    assert (gpu.segment.cpu() != cpu.segment).float().mean() < 1e-3
    both = cpu.mask & gpu.mask.cpu()
    # float32 at 2-4 m: the GPU contracts multiply-adds the CPU does not, 0.2 mm seen on an
    # H200; a sub-millimetre bound still catches any wrong surface or index.
    assert float((gpu.depth.cpu() - cpu.depth)[both].abs().max()) < 1e-3


def test_frames_are_kept_per_pose_batch_and_geometry_can_be_passed():
    """A geometry answers the same kinematics' frames once (the tracker asks three times an
    iteration) and new poses afresh; distances with the caller's geometry are the same."""
    body = BodyShape.default()
    q = rest_pose(2)
    q[1, 0] += 0.3
    geom = segment_geometry(body, q)
    kin = forward_kinematics(q, body)
    first = geom.frames(kin)
    assert geom.frames(kin) is first
    moved = forward_kinematics(q + 0.1, body)
    rot, origin = geom.frames(moved)
    assert not torch.equal(origin, first[1])
    assert geom.frames(moved)[1] is origin
    points = torch.randn(2, 50, 3) * 0.3 + torch.tensor([0.0, 0.0, 2.5])
    assert torch.equal(
        surface_distance(points, kin, body, geom), surface_distance(points, kin, body)
    )
