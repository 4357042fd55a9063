"""The compiled z-buffer (numba) against the torch ray-caster it replaces on the CPU."""

from __future__ import annotations

import pytest
import torch
from depthmocap.runtime import raycast
from depthmocap.runtime.capsule_pixels import NEAR
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import forward_kinematics

kernel = pytest.importorskip("depthmocap.runtime.raycast_kernel")

SMALL = Intrinsics(160, 120, 143.95, 143.95, 80.0, 60.0)


def _random_poses(n: int, seed: int = 0) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    lim = torch.as_tensor(sk.DOF_LIMITS, dtype=torch.float32).clamp(-3.0, 3.0)
    q = lim[:, 0] + torch.rand(n, sk.NUM_DOFS, generator=gen) * (lim[:, 1] - lim[:, 0])
    q[:, 3:6] = 0.5 * torch.randn(n, 3, generator=gen)
    q[:, :3] = torch.tensor([0.0, 0.0, 2.5]) + 0.3 * torch.randn(n, 3, generator=gen)
    return q


def _both(q: torch.Tensor, body: BodyShape, intr: Intrinsics):
    kin = forward_kinematics(q, body)
    geom = raycast.segment_geometry(body, q)
    rot, origin = geom.frames(kin)
    ref = raycast._zbuffer_torch(rot, origin, geom, intr, box=False)  # every pixel, every capsule
    got = kernel.zbuffer_cpu(rot, origin, geom.basis, geom.scale, geom.span, intr, NEAR)
    return ref, got


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-9), (torch.float32, 1e-3)])
def test_matches_torch_raycaster(dtype, tol):
    """The same primitive at all but rounding ties (coincident caps at a joint, grazing rays)
    and, where the primitive is the same, the same depth: to 1e-9 m against the torch caster
    in float64; to 1 mm against it in float32, whose closed form cancels digits at 2.5 m (the
    kernel computes in float64 whatever the dtype)."""
    q = _random_poses(12).to(dtype)
    body = BodyShape.default(dtype)
    (d_ref, p_ref), (d, p) = _both(q, body, SMALL)
    assert d.shape == d_ref.shape and d.dtype == dtype and p.dtype == torch.int64
    assert (p_ref >= 0).sum() > 10_000  # the poses are in view
    assert ((p >= 0) != (p_ref >= 0)).float().mean() < 1e-3
    assert (p != p_ref).float().mean() < 5e-3
    same = (p == p_ref) & (p >= 0)
    torch.testing.assert_close(d[same], d_ref[same], atol=tol, rtol=0)
    assert (d[p < 0] == 0).all() and (p[d == 0] == -1).all()


def test_batched_bodies_and_near_plane():
    """A batch of bodies, one pose straddling the camera plane (its hits behind NEAR dropped),
    one wholly behind the camera (nothing rendered)."""
    base = BodyShape.default()
    body = base.scaled(torch.tensor([0.8, 1.0, 1.2]))
    q = _random_poses(3, seed=3)
    q[1, 2] = 0.2
    q[2, 2] = -3.0
    (d_ref, p_ref), (d, p) = _both(q, body, SMALL)
    assert (p[2] == -1).all() and (d[2] == 0).all()
    assert (p != p_ref).float().mean() < 5e-3
    assert (d[d > 0] > NEAR).all()


def test_render_body_dispatch(monkeypatch):
    """render_body takes the compiled z-buffer on the CPU and gives what the torch one gives."""
    q = _random_poses(2, seed=5)
    body = BodyShape.default()
    fast = raycast.render_body(q, body, SMALL)
    monkeypatch.setattr(raycast, "_compiled_kernel", lambda: None)
    slow = raycast.render_body(q, body, SMALL)
    assert (fast.segment != slow.segment).float().mean() < 5e-3
    same = fast.segment == slow.segment
    torch.testing.assert_close(fast.depth[same], slow.depth[same], atol=1e-3, rtol=0)
    torch.testing.assert_close(fast.normals[same], slow.normals[same], atol=1e-2, rtol=0)


def test_segment_distances_match_torch(monkeypatch):
    """The compiled distances equal the torch expression (float64), batched bodies included,
    and autograd still reaches the points through the torch code."""
    base = BodyShape.default(torch.float64)
    body = base.scaled(torch.tensor([0.9, 1.1], dtype=torch.float64))
    q = _random_poses(2, seed=7).double()
    kin = forward_kinematics(q, body)
    gen = torch.Generator().manual_seed(8)
    points = q[:, None, :3] + 0.6 * torch.randn(2, 200, 3, generator=gen, dtype=torch.float64)
    fast = raycast.segment_distances(points, kin, body)
    monkeypatch.setattr(raycast, "_compiled_kernel", lambda: None)
    slow = raycast.segment_distances(points, kin, body)
    assert fast.shape == slow.shape == (2, 200, 17)
    torch.testing.assert_close(fast, slow, atol=1e-12, rtol=0)
    assert (slow < 0).any() and (slow > 0).any()  # points inside and outside
    monkeypatch.undo()
    grad_points = points.clone().requires_grad_(True)
    raycast.surface_distance(grad_points, kin, body).sum().backward()
    assert grad_points.grad is not None and grad_points.grad.abs().sum() > 0


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_poses_that_are_not_numbers_render_as_the_torch_caster_does(bad, monkeypatch):
    """A NaN or infinite angle or position: no crash and no stray writes; what is rendered is
    what the torch caster renders (the good parts of the body, nothing for a NaN root)."""
    q = _random_poses(3, seed=11)
    q[0, 12] = bad  # one joint angle
    q[1, 2] = bad  # the root's depth
    body = BodyShape.default()
    fast = raycast.render_body(q, body, SMALL, details=False)
    monkeypatch.setattr(raycast, "_compiled_kernel", lambda: None)
    slow = raycast.render_body(q, body, SMALL, details=False)
    assert torch.isfinite(fast.depth).all()
    assert ((fast.segment >= 0) != (slow.segment >= 0)).float().mean() < 1e-3
    torch.testing.assert_close(fast.depth[2], slow.depth[2], atol=1e-3, rtol=0)


def test_segments_and_depth_rounding_in_the_same_loop():
    """With the primitives' segment table the kernel also writes each pixel's segment (-1 on
    background), the same as looking the primitive up afterwards; the depth is rounded to
    float32 as torch's ``.to`` rounds the float64 buffer."""
    q = _random_poses(4, seed=5)
    body = BodyShape.default()
    kin = forward_kinematics(q, body)
    geom = raycast.segment_geometry(body, q)
    rot, origin = geom.frames(kin)
    depth, prim, segment = kernel.zbuffer_cpu(
        rot, origin, geom.basis, geom.scale, geom.span, SMALL, NEAR, geom.segment
    )
    want = torch.where(prim >= 0, geom.segment[prim.clamp_min(0)], prim)
    assert torch.equal(segment, want) and (segment >= 0).sum() > 1000
    d64, p64 = kernel.zbuffer_cpu(
        rot.double(), origin.double(), geom.basis.double(), geom.scale.double(),
        geom.span.double(), SMALL, NEAR,
    )  # fmt: skip
    assert torch.equal(prim, p64) and torch.equal(depth, d64.float())
