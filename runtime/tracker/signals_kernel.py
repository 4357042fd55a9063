"""A fit's surface-error quantile, limb visibility and joint support as one compiled call
(numba): the CPU path of :func:`runtime.tracker.signals.frame_signals` after a compiled fit.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:func:`~runtime.tracker.tracker.fit_frames` imports it lazily and keeps
:func:`~runtime.tracker.signals.frame_signals` for GPUs, float64 and batches of different
frames.

Why: after the iterations became one compiled call, a fit's final signals were a fifth of
its time (~1.5 ms a track fit), most of it the torch glue around two kernels
(``docs/experiments.md``, thirty-third session). Here the same arithmetic in the same order:
float32 products where torch multiplies float32 tensors by Python numbers (the number
rounded to float32 first), sequential sums for 3 x 3 products, the distances' float32
minimum: the same signals, bit for bit. The quantile itself, the depth error and the overlap
stay torch's (its vectorized ``lerp`` uses fused multiply-adds in float64, its float32 sum
its own order).
"""

from __future__ import annotations

import numba
import numpy as np
from depthmocap.shared import skeleton as sk

from ..raycast_kernel import _segment_distances
from .iteration_kernel import _rotate_f32, axis_point_f32
from .sampling_kernel import points_at, sampled
from .support_kernel import _support

__all__ = ["fit_signals"]

_LIMBS = np.array(
    [
        (sk.SEGMENT_NAMES.index(f"{side}_{upper}"), sk.SEGMENT_NAMES.index(f"{side}_{lower}"))
        for upper, lower in (("upper_arm", "forearm"), ("thigh", "shank"))
        for side in "lr"
    ],
    np.int64,
)
_JOINT_SEGMENT = np.asarray(sk.JOINT_SEGMENT, np.int64)
_JOINT_FRACTION = np.asarray(sk.JOINT_FRACTION, np.float32)
_SEGMENT_AXIS = np.asarray(sk.SEGMENT_AXIS, np.float32)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _surface_distances(valid1, obs_points, max_points, rot, origin, basis, span,
                       scale):  # fmt: skip  # pragma: no cover - compiled
    """``surface_error_quantile``'s distances for B poses on one observed frame (``valid1``
    (1, H, W)): (B, N) float64, each sampled point's distance to each pose's surface (the
    float32 minimum over the capsules, as torch's ``min`` of the distances it rounded)."""
    B, P = rot.shape[0], rot.shape[1]
    idx, _, _ = sampled(valid1, max_points)
    N = idx.shape[0]
    pts = np.empty((B, N, 3))
    for n in range(N):
        for i in range(3):
            x = np.float64(obs_points[0, idx[n, 1], idx[n, 2], i])
            for b in range(B):
                pts[b, n, i] = x
    signed = np.empty((B, N, P))
    _segment_distances(
        pts, rot.astype(np.float64), origin.astype(np.float64), basis.astype(np.float64),
        span.astype(np.float64), scale.astype(np.float64), signed,
    )  # fmt: skip
    dist = np.empty((B, N))
    for b in range(B):
        for n in range(N):
            best = np.float32(signed[b, n, 0])
            for p in range(1, P):
                best = min(best, np.float32(signed[b, n, p]))
            dist[b, n] = np.float64(abs(best))
    return dist


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _limb_visibility(segment, rotations, origins, lengths, radii, fx, fy, out):  # pragma: no cover
    """``limb_visibility``: each limb's rendered pixels over its side-on area, (B, 4)."""
    B, K = rotations.shape[0], rotations.shape[1]
    H, W = segment.shape[1], segment.shape[2]
    counts = np.zeros(K, np.int64)
    area = np.empty(K, np.float64)
    for b in range(B):
        counts[:] = 0
        for v in range(H):
            for u in range(W):
                s = segment[b, v, u]
                if s >= 0:
                    counts[s] += 1
        for k in range(K):
            axis = _SEGMENT_AXIS[k]
            h = lengths[b, k] / np.float32(2.0)
            half_z = _rotate_f32(rotations[b, k], axis[0], axis[1], axis[2], 2) * h
            z = max(origins[b, k, 2] + half_z, np.float32(0.1))
            rb = radii[b, k]
            radius = (rb[0] + rb[1]) / np.float32(2.0)
            value = np.float32(2.0) * radius * lengths[b, k] * fx * fy / (z * z)
            area[k] = np.float64(value)
        for m in range(_LIMBS.shape[0]):
            i, j = _LIMBS[m, 0], _LIMBS[m, 1]
            seen = np.float64(counts[i]) + np.float64(counts[j])
            out[b, m] = seen / max(area[i] + area[j], 1e-9)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _joint_support(
    depth, segment, good, labels, has_labels, group, rotations, origins, lengths, slots,
    radius, centre, focal, fxfy, area,
):  # fmt: skip  # pragma: no cover - compiled
    """``joint_support_cm2`` (with the padding column) into ``area`` (B, J + 1)."""
    B, H, W = good.shape
    J = _JOINT_SEGMENT.shape[0]
    joints = np.zeros((B, J + 1, 3), np.float32)
    for b in range(B):
        for j in range(J):
            k = _JOINT_SEGMENT[j]
            f = _JOINT_FRACTION[j] * lengths[b, k]
            axis_point_f32(rotations[b, k], origins[b, k], f, _SEGMENT_AXIS[k], joints[b, j])
    n = 0
    for b in range(B):
        for v in range(H):
            for u in range(W):
                n += good[b, v, u]
    rows = np.empty((n, 3), np.int64)
    n = 0
    for b in range(B):
        for v in range(H):
            for u in range(W):
                if good[b, v, u]:
                    rows[n, 0], rows[n, 1], rows[n, 2] = b, v, u
                    n += 1
    points, seg = points_at(depth, segment, rows, centre, focal)
    _support(rows, points, seg, labels, has_labels, group, joints, slots, radius, fxfy, area)


def fit_signals(render, regions, obs, radii) -> tuple:
    """The surface-error quantile (B,) float64 mm, limb visibility (B, 4) float64 and joint
    support (B, J) float64 cm^2 of a fit's last rendering on one observed frame (``obs`` a
    batch of views of it, or of one pose), CPU float32; ``radii`` the body's (B, K, 2)
    cross-section radii. The same values as :func:`runtime.tracker.signals.frame_signals`."""
    import torch

    from . import joint_support
    from .signals import MAX_SURFACE_POINTS, SURFACE_LEVEL

    max_points, level = MAX_SURFACE_POINTS, SURFACE_LEVEL
    tables = (joint_support._GROUP, joint_support._SEGMENT_JOINTS, joint_support._RADIUS)

    kin = render.kin
    B = kin.origins.shape[0]
    geom = render.geom
    P = geom.segment.shape[0]
    dist = _surface_distances(
        np.ascontiguousarray(obs.valid[:1].numpy()), obs.points.numpy(), int(max_points),
        render.rot.numpy(), render.origin.numpy(), geom.basis.numpy(),
        geom.span.expand(B, P, 2).numpy(), geom.scale.expand(B, P, 3).numpy(),
    )  # fmt: skip
    if dist.shape[1] == 0:
        surface = torch.zeros(B, dtype=torch.float64)
    else:  # torch's quantile itself: its vectorized lerp rounds as numba cannot
        quantile = torch.nanquantile(torch.from_numpy(dist), level, dim=1) * 1e3
        surface = torch.nan_to_num(quantile, nan=0.0)
    intr = obs.intr
    fx, fy = np.float32(intr.fx), np.float32(intr.fy)
    rotations, origins = kin.rotations.numpy(), kin.origins.numpy()
    lengths = kin.lengths.numpy()
    visibility = np.empty((B, _LIMBS.shape[0]), np.float64)
    segment = render.segment.numpy()
    _limb_visibility(segment, rotations, origins, lengths, radii.numpy(), fx, fy, visibility)
    group, slots, radius = tables
    J = _JOINT_SEGMENT.shape[0]
    area = np.zeros((B, J + 1), np.float64)
    has_labels = obs.labels is not None
    labels = obs.labels.numpy() if has_labels else np.zeros((1, 1, 1), np.int64)
    _joint_support(
        render.depth.numpy(), segment, regions.good.numpy(), labels, has_labels, group.numpy(),
        rotations, origins, lengths, slots.numpy(), radius.numpy(),
        np.array([intr.cx, intr.cy], np.float32), np.array([intr.fx, intr.fy], np.float32),
        float(intr.fx * intr.fy), area,
    )  # fmt: skip
    t = torch.from_numpy
    return surface, t(visibility), t(area[:, :J].copy())
