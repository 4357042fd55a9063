"""Rotation helpers on SO(3), batched over any leading shape, differentiable everywhere.

Rotation vectors (axis * angle, radians) parameterize the root orientation; fixed-axis
rotations build the joint-angle part of the skeleton. Small angles use Taylor series through
``torch.where`` so that values *and* gradients stay finite at zero rotation.
"""

from __future__ import annotations

import torch

__all__ = [
    "skew",
    "axis_angle_to_matrix",
    "rotvec_to_matrix",
    "matrix_to_quaternion",
    "rotvec_to_quaternion",
    "quaternion_multiply",
    "quaternion_conjugate",
    "quaternion_to_rotvec",
    "matrix_to_rotvec",
    "compose_rotvec",
]

_SMALL = 1e-4


def skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrix ``[v]_x`` with ``[v]_x w = v x w``.

    Args:
        v: (..., 3).
    Returns:
        (..., 3, 3).
    """
    z = torch.zeros_like(v[..., 0])
    x, y, w = v.unbind(-1)
    return torch.stack(
        [torch.stack([z, -w, y], -1), torch.stack([w, z, -x], -1), torch.stack([-y, x, z], -1)],
        -2,
    )


def axis_angle_to_matrix(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotation about unit ``axis`` by ``angle`` (Rodrigues).

    Args:
        axis: (..., 3) unit vectors, broadcastable against ``angle[..., None]``.
        angle: (...) radians.
    Returns:
        (..., 3, 3).
    """
    axis = axis.to(angle.dtype).expand(*angle.shape, 3)
    k = skew(axis)
    s = torch.sin(angle)[..., None, None]
    c = torch.cos(angle)[..., None, None]
    eye = torch.eye(3, dtype=angle.dtype, device=angle.device)
    return eye + s * k + (1.0 - c) * (k @ k)


def rotvec_to_matrix(rotvec: torch.Tensor) -> torch.Tensor:
    """Exponential map: rotation vector (..., 3) -> rotation matrix (..., 3, 3)."""
    theta2 = (rotvec * rotvec).sum(-1)
    small = theta2 < _SMALL**2
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = theta2_safe.sqrt()
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2_safe)
    k = skew(rotvec)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def matrix_to_quaternion(rot: torch.Tensor) -> torch.Tensor:
    """Rotation matrix (..., 3, 3) -> unit quaternion (..., 4) as (w, x, y, z), w >= 0.

    Shepperd's method: of the four algebraically equal formulas, each element uses the one
    with the largest denominator, chosen by a mask rather than branching on data.
    """
    m = rot
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    cands = torch.stack(
        [
            torch.stack(
                [
                    1 + trace,
                    m[..., 2, 1] - m[..., 1, 2],
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 1, 0] - m[..., 0, 1],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + m00 - m11 - m22,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m00 + m11 - m22,
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m00 - m11 + m22,
                ],
                -1,
            ),
        ],
        -2,
    )  # (..., 4, 4): row i is 2*sqrt(denominator_i) * q
    diag = torch.stack(
        [1 + trace, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1
    )
    best = diag.argmax(-1, keepdim=True)
    q = torch.gather(cands, -2, best[..., None].expand(*best.shape, 4)).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def rotvec_to_quaternion(rotvec: torch.Tensor) -> torch.Tensor:
    """Rotation vector (..., 3) -> unit quaternion (..., 4) as (w, x, y, z), w >= 0 for
    angles up to pi."""
    theta2 = (rotvec * rotvec).sum(-1, keepdim=True)
    small = theta2 < _SMALL**2
    theta = torch.where(small, torch.ones_like(theta2), theta2).sqrt()
    w = torch.where(small, 1.0 - theta2 / 8.0, torch.cos(0.5 * theta))
    s = torch.where(small, 0.5 - theta2 / 48.0, torch.sin(0.5 * theta) / theta)
    return torch.cat([w, rotvec * s], -1)


def quaternion_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a b`` of (..., 4) quaternions (w, x, y, z): the rotation
    ``R(a) @ R(b)``."""
    aw, av = a[..., :1], a[..., 1:]
    bw, bv = b[..., :1], b[..., 1:]
    w = aw * bw - (av * bv).sum(-1, keepdim=True)
    v = aw * bv + bw * av + torch.linalg.cross(av, bv, dim=-1)
    return torch.cat([w, v], -1)


def quaternion_conjugate(quat: torch.Tensor) -> torch.Tensor:
    """The inverse rotation of unit quaternions (..., 4) as (w, x, y, z)."""
    return torch.cat([quat[..., :1], -quat[..., 1:]], -1)


def quaternion_to_rotvec(quat: torch.Tensor) -> torch.Tensor:
    """Unit quaternion (..., 4) as (w, x, y, z) -> rotation vector (..., 3), angle in [0, pi]."""
    quat = torch.where(quat[..., :1] < 0, -quat, quat)
    w, v = quat[..., 0], quat[..., 1:]
    s2 = (v * v).sum(-1)
    small = s2 < _SMALL**2
    s = torch.where(small, torch.ones_like(s2), s2).sqrt()
    angle_over_s = torch.where(small, 2.0 / w.clamp_min(1e-12), 2.0 * torch.atan2(s, w) / s)
    return v * angle_over_s[..., None]


def matrix_to_rotvec(rot: torch.Tensor) -> torch.Tensor:
    """Logarithm map: rotation matrix (..., 3, 3) -> rotation vector (..., 3)."""
    return quaternion_to_rotvec(matrix_to_quaternion(rot))


def compose_rotvec(left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
    """Rotation vector of ``exp(left) @ exp(right)``; both (..., 3). Through quaternions: a
    third of the small ops of the matrix route, which the tracker pays every iteration."""
    product = quaternion_multiply(rotvec_to_quaternion(left), rotvec_to_quaternion(right))
    return quaternion_to_rotvec(product)
