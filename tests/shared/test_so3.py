import math

import torch
from depthmocap.shared.so3 import matrix_to_rotvec, rotvec_to_matrix, skew


def test_skew_is_cross_product():
    a, b = torch.randn(5, 3), torch.randn(5, 3)
    assert torch.allclose((skew(a) @ b[..., None])[..., 0], torch.linalg.cross(a, b), atol=1e-6)


def test_rotvec_round_trip_all_angles(dtype):
    g = torch.Generator().manual_seed(0)
    axis = torch.randn(200, 3, generator=g, dtype=dtype)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    angle = torch.linspace(0, math.pi * 0.999, 200, dtype=dtype)
    v = axis * angle[:, None]
    r = rotvec_to_matrix(v)
    eye = torch.eye(3, dtype=dtype)
    tol = 1e-5 if dtype == torch.float32 else 1e-10
    assert torch.allclose(r @ r.transpose(-1, -2), eye.expand_as(r), atol=tol)
    assert torch.allclose(torch.linalg.det(r), torch.ones(200, dtype=dtype), atol=tol)
    assert torch.allclose(matrix_to_rotvec(r), v, atol=50 * tol)


def test_golden_rotation():
    r = rotvec_to_matrix(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64))
    x = r @ torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    assert torch.allclose(x, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64), atol=1e-12)


def test_half_turn_is_stable():
    r = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    v = matrix_to_rotvec(r)
    assert torch.allclose(v.abs(), torch.tensor([math.pi, 0.0, 0.0], dtype=torch.float64))
    assert torch.allclose(rotvec_to_matrix(v), r, atol=1e-12)


def test_gradients_finite_at_zero():
    v = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    (rotvec_to_matrix(v) @ torch.ones(3, dtype=torch.float64)).sum().backward()
    assert torch.isfinite(v.grad).all()
    r = rotvec_to_matrix(torch.zeros(3, dtype=torch.float64)).requires_grad_(True)
    matrix_to_rotvec(r).sum().backward()
    assert torch.isfinite(r.grad).all()


def test_quaternion_route_matches_matrices():
    """rotvec -> quaternion agrees with the matrix exponential, the Hamilton product with the
    matrix product, and compose_rotvec with the matrix route, small angles included."""
    from depthmocap.shared.so3 import (
        compose_rotvec,
        matrix_to_quaternion,
        quaternion_conjugate,
        quaternion_multiply,
        rotvec_to_quaternion,
    )

    g = torch.Generator().manual_seed(1)
    a = torch.randn(100, 3, generator=g, dtype=torch.float64)
    b = torch.randn(100, 3, generator=g, dtype=torch.float64)
    a[:5] *= 1e-6  # the small-angle series
    b[5:10] = 0.0
    qa, qb = rotvec_to_quaternion(a), rotvec_to_quaternion(b)
    # Same rotation up to the quaternion's sign.
    ref = matrix_to_quaternion(rotvec_to_matrix(a))
    assert torch.allclose(qa * torch.sign(qa[:, :1] * ref[:, :1] + 1e-30), ref, atol=1e-12)
    prod = matrix_to_quaternion(rotvec_to_matrix(a) @ rotvec_to_matrix(b))
    got = quaternion_multiply(qa, qb)
    got = torch.where(got[:, :1] < 0, -got, got)
    assert torch.allclose(got, prod, atol=1e-12)
    identity = quaternion_multiply(qa, quaternion_conjugate(qa))
    assert torch.allclose(identity, torch.tensor([1.0, 0, 0, 0], dtype=torch.float64), atol=1e-12)
    composed = compose_rotvec(a, b)
    assert torch.allclose(
        rotvec_to_matrix(composed), rotvec_to_matrix(a) @ rotvec_to_matrix(b), atol=1e-12
    )
    assert (composed.norm(dim=-1) <= math.pi + 1e-12).all()
