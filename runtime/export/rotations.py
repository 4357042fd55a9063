"""Rotation conversions in numpy for the per-frame exporters (one pose per frame: torch's
per-call overhead would cost more than the arithmetic).

Quaternions are stored ``(x, y, z, w)`` (Unity's and the VMC protocol's order) with the usual
Hamilton product, so ``quat_to_matrix(q) @ v`` rotates ``v`` the way ``q v q*`` does. Rotation
vectors are ``axis * angle`` (radians), the root-orientation layout of :mod:`shared.skeleton`.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "rotvec_to_matrix",
    "matrix_to_quat",
    "quat_to_matrix",
    "quat_to_rotvec",
    "matrix_to_rotvec",
]


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: (..., 3) rotation vectors -> (..., 3, 3) matrices."""
    v = np.asarray(rotvec, dtype=np.float64)
    angle = np.linalg.norm(v, axis=-1)
    axis = v / np.where(angle > 0, angle, 1.0)[..., None]
    k = np.zeros(v.shape + (3,))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def matrix_to_quat(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions ``(x, y, z, w)``, ``w >= 0``.

    Shepperd's method: the quaternion is read off the largest of ``w, |x|, |y|, |z|``, which
    keeps it accurate at every angle (180-degree turns included).
    """
    m = np.asarray(rot, dtype=np.float64)
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    t = m00 + m11 + m22
    # Each candidate is 4 * (one component) * (x, y, z, w).
    cand = np.stack(
        [
            np.stack([1 + 2 * m00 - t, m01 + m10, m02 + m20, m21 - m12], -1),
            np.stack([m01 + m10, 1 + 2 * m11 - t, m12 + m21, m02 - m20], -1),
            np.stack([m02 + m20, m12 + m21, 1 + 2 * m22 - t, m10 - m01], -1),
            np.stack([m21 - m12, m02 - m20, m10 - m01, 1 + t], -1),
        ],
        -2,
    )
    best = np.argmax(np.stack([m00, m11, m22, t], -1), -1)
    q = np.take_along_axis(cand, best[..., None, None], -2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions ``(x, y, z, w)`` (normalized here) -> (..., 3, 3)."""
    q = np.asarray(quat, dtype=np.float64)
    x, y, z, w = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def quat_to_rotvec(quat: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions ``(x, y, z, w)`` -> (..., 3) rotation vectors, angle in
    [0, pi]."""
    q = np.asarray(quat, dtype=np.float64)
    q = np.where(q[..., 3:4] < 0, -q, q)
    v = q[..., :3]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 3])
    # angle / sin(angle / 2), with its limit 2 at zero.
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return v * scale[..., None]


def matrix_to_rotvec(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (..., 3) rotation vectors (the matrix logarithm)."""
    return quat_to_rotvec(matrix_to_quat(rot))
