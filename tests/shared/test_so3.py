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
