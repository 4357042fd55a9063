"""The observed-joint support (:func:`runtime.tracker.joint_support.joint_support_cm2`) as one
compiled loop (numba): the CPU float32 path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:mod:`runtime.tracker.joint_support` imports it lazily and keeps its torch code for autograd,
GPUs, float64 and installs without numba.

Why: every fit ends with its failure signals, and the support's dozen torch ops over the
frame's matched pixels cost about a millisecond per fit on the CPU (the arm search and the
detector fit several times a frame). The arithmetic is torch's, to the bit: float32 offsets
to the joints with the fused norm (:func:`runtime.tracker.extra_kernel.norm3_float32`), the
float64 footprint ``z^2 / (fx fy) 1e4`` and the per-joint sums in the order of the pixels.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from .extra_kernel import norm3_float32
from .sampling_kernel import rendered_points_cpu

__all__ = ["joint_support_cpu"]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _support(idx, points, segment, labels, has_labels, group, joints, slots, radius, fxfy,
             area):  # fmt: skip  # pragma: no cover - compiled
    """Add each pixel's footprint (cm^2) to the (at most two) joints its segment meets that
    lie within their radius of it: ``area`` (B, J + 1), the last column the padding."""
    for n in range(idx.shape[0]):
        s = segment[n]
        counts = s >= 0
        sc = max(s, 0)
        if has_labels:
            said = labels[idx[n, 0], idx[n, 1], idx[n, 2]]
            counts = counts and said >= 0 and group[max(said, 0)] == group[sc]
        b = idx[n, 0]
        z = np.float64(points[n, 2])
        footprint = z * z / fxfy * 1e4
        for k in range(2):
            j = slots[sc, k]
            d = norm3_float32(
                points[n, 0] - joints[b, j, 0],
                points[n, 1] - joints[b, j, 1],
                points[n, 2] - joints[b, j, 2],
            )
            if counts and d < radius[j]:  # torch adds 0.0 otherwise: no change
                area[b, j] += footprint


def joint_support_cpu(
    depth: torch.Tensor,
    segment_map: torch.Tensor,
    idx: torch.Tensor,
    intr,
    labels: torch.Tensor | None,
    group: torch.Tensor,
    joints: torch.Tensor,
    slots: torch.Tensor,
    radius: torch.Tensor,
) -> torch.Tensor:
    """``joint_support_cm2`` on CPU float32 tensors: the rendered ``depth`` and
    ``segment_map`` (B, H, W), the G pixels ``idx`` (N, 3), the forest's segment ``labels``
    (B, H, W) or None, the body ``group`` of each segment (S,), the named ``joints`` padded
    with one zero joint (B, J + 1, 3), each segment's two joint ``slots`` (S, 2) and the
    padded ``radius`` (J + 1,). Returns (B, J) float64 cm^2."""
    rows = np.ascontiguousarray(idx.numpy())
    points, segment = (t.numpy() for t in rendered_points_cpu(depth, segment_map, idx, intr))
    has_labels = labels is not None
    lab = labels.numpy() if has_labels else np.zeros((1, 1, 1), np.int64)
    B, J1 = joints.shape[0], joints.shape[1]
    area = np.zeros((B, J1), np.float64)
    _support(
        rows, points, segment, lab, has_labels, group.numpy(), np.ascontiguousarray(joints.numpy()),
        slots.numpy(), radius.numpy(), float(intr.fx * intr.fy), area,
    )  # fmt: skip
    return torch.from_numpy(area[:, : J1 - 1])
