"""Posing an :class:`~train.bodies.anny_body.AnnyBody` by linear blend skinning (LBS).

Our own LBS gives identical results to anny's forward pass ('world-orient' parameterization,
tested to 1e-9 m) in about 1 ms per pose instead of about 55 ms on a 2-core CPU, and it takes
the per-bone global rotations that retargeting by bone directions produces (see
``/work/shared/data/mocap/README.md``).

Posing convention (``pose_body``): bone b gets a global rotation ``G_b`` relative to its rest
orientation, ``G_b = R_out_bone_posed @ R_body_bone_rest^T``: it maps a direction fixed on the
bone in the rest body frame to the same direction in the output frame. A point x fixed on bone
b goes to ``G_b (x - h_b) + p_b``, where h_b is the rest head and the posed heads follow the
tree, ``p_b = p_parent + G_parent (h_b - h_parent)``. The body-frame origin (hip centre) rides
on the root bone (Hips) and goes to ``root_position``. All rotations identity and root 0 give
the rest mesh. The output frame is whatever the rotations map into: to pose directly in camera
coordinates, left-multiply every ``G_b`` by the root orientation and pass the camera-frame root
position.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
from depthmocap.shared.skeleton import NUM_SEGMENTS
from depthmocap.train.bodies.anny_body import AnnyBody, bone_segments

__all__ = ["PosedBody", "pose_body", "segment_to_bone_rotations"]


@dataclasses.dataclass(frozen=True)
class PosedBody:
    """Output of ``pose_body``; ``...`` are the broadcast batch dimensions of its inputs.

    Attributes:
        vertices: (..., V, 3) posed vertices.
        bone_heads: (..., n_bones, 3) posed bone heads.
        bone_tails: (..., n_bones, 3) posed bone tails.
    """

    vertices: np.ndarray
    bone_heads: np.ndarray
    bone_tails: np.ndarray


@functools.lru_cache(maxsize=8)
def _chain_matrices(parents: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Tree structure for the closed-form posed heads.

    Returns:
        lever_bone (n,): the bone whose rotation carries each bone's head offset (its parent;
            the root's own for the root, whose offset is measured from the origin), and
        path (n, n): path[b, a] = 1 when a is b or one of its ancestors.
    """
    n = len(parents)
    lever_bone = np.array([0] + list(parents[1:]), dtype=np.int64)
    path = np.zeros((n, n))
    for b in range(n):
        a = b
        while a >= 0:
            path[b, a] = 1.0
            a = parents[a]
    return lever_bone, path


def _pose_arrays(body: AnnyBody, dtype: np.dtype) -> tuple[np.ndarray, ...]:
    """Rest arrays in ``dtype`` (cached on the body, conversions would cost per call)."""
    key = ("pose", np.dtype(dtype).str)
    if key not in body._cache:
        lever_bone, path = _chain_matrices(tuple(int(p) for p in body.bone_parents))
        offsets = body.bone_heads - np.where(
            body.bone_parents[:, None] >= 0, body.bone_heads[body.bone_parents], 0.0
        )
        body._cache[key] = tuple(
            np.ascontiguousarray(a, dtype=dtype)
            for a in (body.skin_weights, body.vertices, body.bone_heads,
                      body.bone_tails - body.bone_heads, offsets, path)
        ) + (lever_bone,)  # fmt: skip
    return body._cache[key]


def pose_body(body: AnnyBody, global_rotations: np.ndarray, root_position: np.ndarray) -> PosedBody:
    """Pose the body by linear blend skinning with per-bone global rotations.

    Convention (module docstring): ``global_rotations[..., b]`` = G_b = R_out_bone_posed @
    R_body_bone_rest^T; a point x on bone b maps to G_b (x - h_b) + p_b; the body-frame origin
    (hip centre) rides on the root bone and maps to ``root_position``. Computation follows the
    rotations' floating dtype (float32 is about twice as fast as float64).

    Args:
        body: the rest body.
        global_rotations: (..., n_bones, 3, 3) rotation matrices.
        root_position: (..., 3) where the hip centre goes.
    Returns:
        ``PosedBody`` with (..., V, 3) vertices and (..., n_bones, 3) bone heads/tails.
    """
    rot = np.asarray(global_rotations)
    n = body.num_bones
    if rot.shape[-3:] != (n, 3, 3):
        raise ValueError(f"global_rotations must be (..., {n}, 3, 3), got {rot.shape}")
    dtype = np.result_type(rot.dtype, np.float32)
    root = np.asarray(root_position, dtype=dtype)
    if root.shape[-1:] != (3,):
        raise ValueError(f"root_position must be (..., 3), got {root.shape}")
    batch = np.broadcast_shapes(rot.shape[:-3], root.shape[:-1])
    rot = np.broadcast_to(rot.astype(dtype, copy=False), batch + (n, 3, 3))
    root = np.broadcast_to(root, batch + (3,))
    weights, rest, heads, bone_vec, offsets, path, lever_bone = _pose_arrays(body, dtype)

    # p_b = root + sum over the path root..b of G_lever(a) offset_a (closed-form chain).
    levers = np.einsum("...bij,bj->...bi", rot[..., lever_bone, :, :], offsets)
    posed_heads = root[..., None, :] + path @ levers
    posed_tails = posed_heads + np.einsum("...bij,bj->...bi", rot, bone_vec)
    # Per-bone affine maps x -> G_b x + t_b, t_b = p_b - G_b h_b, stored as the three columns
    # of G_b followed by t_b so that one matrix product blends them all.
    trans = posed_heads - np.einsum("...bij,bj->...bi", rot, heads)
    affine = np.concatenate([np.swapaxes(rot, -1, -2).reshape(batch + (n, 9)), trans], -1)
    blended = weights @ affine  # (..., V, 12)
    verts = (
        blended[..., 0:3] * rest[:, 0:1]
        + blended[..., 3:6] * rest[:, 1:2]
        + blended[..., 6:9] * rest[:, 2:3]
        + blended[..., 9:12]
    )
    return PosedBody(vertices=verts, bone_heads=posed_heads, bone_tails=posed_tails)


def segment_to_bone_rotations(body: AnnyBody, segment_rotations: np.ndarray) -> np.ndarray:
    """Give every bone the global rotation of the segment it belongs to (``BONE_SEGMENT``).

    Args:
        body: the body (for its bone names).
        segment_rotations: (..., 15, 3, 3) per-segment rotations in SEGMENT_NAMES order.
    Returns:
        (..., n_bones, 3, 3) rotations for ``pose_body``.
    """
    rot = np.asarray(segment_rotations)
    if rot.shape[-3:] != (NUM_SEGMENTS, 3, 3):
        raise ValueError(f"segment_rotations must be (..., {NUM_SEGMENTS}, 3, 3)")
    return rot[..., bone_segments(body.bone_names), :, :]
