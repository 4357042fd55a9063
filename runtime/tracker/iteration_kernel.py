"""One Gauss-Newton iteration of :func:`runtime.tracker.tracker.fit_frames` after the forward
kinematics, as one compiled call (numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
``fit_frames`` imports it lazily and keeps its term-by-term code for GPUs, autograd, float64
and installs without numba.

Why: every piece of an iteration was already a compiled loop (the z-buffer, the pixel
classes, the four data terms' rows, the normal equations, the update), but each was its own
call with its tensors turned into arrays and back, its rows built as tensors and
concatenated: about half of a batched refit's time was that glue, and it held the
interpreter lock, so the two halves of a split refit waited for each other
(``docs/experiments.md``, thirty-third session). Here one ``nogil`` call runs the same
kernels on the same arrays in the same order: the ray-cast, the classes, the extra depth
term's correspondences, the depth, silhouette and label rows, their moments and assembly,
the collision term's equations (made by the caller, which has them in torch), and the update.
The same poses, bit for bit (a test compares them with the term-by-term path).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import torch
from depthmocap.shared import skeleton as sk

from ..raycast_kernel import _zbuffer
from .depth_kernel import _depth_rows
from .extra_kernel import _correspondences
from .label_kernel import _label_rows
from .normal_kernel import _CHAINS, _COUNTS, _assemble, _moments
from .regions_kernel import _classify
from .silhouette_kernel import _silhouette
from .step_kernel import _LIMITS, _step

__all__ = ["FitArrays", "fit_arrays", "iteration_cpu"]

_FIRST_LIMB = sk.FIRST_LIMB_SEGMENT


@dataclass
class FitArrays:
    """What an iteration reads that stays the same over a fit: the observation's arrays (the
    views the term-by-term path hands its kernels), the observed candidates of the extra
    depth term, the labelled limb pixels and the settings, made once per
    :func:`~runtime.tracker.tracker.fit_frames` call."""

    shared: bool  # one observed frame under every pose (a batch of starts)
    valid: np.ndarray  # (B or 1, H, W) for the classes
    silhouette1: np.ndarray
    depth1: np.ndarray
    silhouette: np.ndarray  # (B, H, W) views, as the terms read them
    points: np.ndarray  # (B, H, W, 3)
    distance: np.ndarray
    distance_grad: np.ndarray
    labels: np.ndarray
    use: np.ndarray  # labelled limb pixels with depth (B, H, W)
    cand_points: np.ndarray
    cand_batch: np.ndarray
    flags: np.ndarray  # (7,) bool: depth, extra, silhouette, labels, occlusion, prior, collision
    ints: np.ndarray  # (6,) int64: see fit_arrays
    floats: np.ndarray  # (12,) float64: see fit_arrays
    centre: np.ndarray  # (2,) float32 cx, cy
    focal: np.ndarray  # (2,) float32 fx, fy
    intr64: np.ndarray  # (4,) float64 fx, fy, cx, cy: the ray-caster's


def fit_arrays(obs, observed, cfg, labels_on: bool, sampling: dict) -> FitArrays:
    """The :class:`FitArrays` of a fit on ``obs`` (float32, CPU) with the extra depth term's
    ``observed`` candidates (None: the term is off) under ``cfg``; ``labels_on``: the label
    term runs; ``sampling``: the terms' constants by name (their modules hold them)."""
    B, H, W = obs.depth.shape
    views = [obs.valid, obs.silhouette, obs.depth]
    shared = all(t.stride(0) == 0 for t in views)
    valid, silhouette1, depth1 = (
        np.ascontiguousarray((t[:1] if shared else t).numpy()) for t in views
    )
    intr = obs.intr
    labels = obs.labels if obs.labels is not None else torch.full_like(obs.depth, -1).long()
    use = obs.valid & (labels >= sk.FIRST_LIMB_SEGMENT)
    if observed is None:
        cand_points = np.zeros((0, 3), np.float32)
        cand_batch = np.zeros(0, np.int64)
    else:
        cand_points = observed.points.numpy()
        cand_batch = observed.batch.numpy().astype(np.int64, copy=False)
    s = sampling
    flags = np.array(
        [cfg.use_depth, observed is not None, cfg.use_silhouette, labels_on,
         cfg.occlusion_handling, cfg.use_prior, cfg.use_collision], np.bool_,
    )  # fmt: skip
    ints = np.array(
        [s["extra_margin"], s["extra_half"], s["max_candidates"], s["max_depth_pixels"],
         s["max_silhouette_pixels"], s["max_label_pixels"]], np.int64,
    )  # fmt: skip
    floats = np.array(
        [cfg.depth_gate_m, cfg.extra_gate_m, s["extra_max_distance"] ** 2, s["sigma_torso"],
         cfg.sigma_extra_m, s["min_cosine"], cfg.sigma_depth_m, s["deadzone"],
         cfg.sigma_silhouette_px, s["label_gate"], cfg.sigma_label_m, s["near"]], np.float64,
    )  # fmt: skip
    return FitArrays(
        shared, valid, silhouette1, depth1, obs.silhouette.numpy(), obs.points.numpy(),
        obs.distance.numpy(), obs.distance_grad.numpy(), labels.numpy(), use.numpy(),
        cand_points, cand_batch, flags, ints, floats,
        np.array([intr.cx, intr.cy], np.float32), np.array([intr.fx, intr.fy], np.float32),
        np.array([intr.fx, intr.fy, intr.cx, intr.cy], np.float64),
    )  # fmt: skip


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _extra_moments(points, seg, batch, offset, weight, K, stats):  # pragma: no cover
    """The extra depth term's rows (one per camera axis of each correspondence, in the order
    ``runtime.tracker.extra_depth_term._rows`` lays them out) into the moments."""
    n = points.shape[0]
    dt = points.dtype
    p3 = np.empty((3 * n, 3), dt)
    g3 = np.zeros((3 * n, 3), dt)
    r3 = np.empty(3 * n, dt)
    w3 = np.empty(3 * n, dt)
    b3 = np.empty(3 * n, np.int64)
    s3 = np.empty(3 * n, np.int64)
    for i in range(n):
        for a in range(3):
            r = 3 * i + a
            for c in range(3):
                p3[r, c] = points[i, c]
            g3[r, a] = 1.0
            r3[r] = offset[i, a]
            w3[r] = weight[i]
            b3[r] = batch[i]
            s3[r] = seg[i]
    _moments(p3, g3, r3, w3, b3, s3, K, stats)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _iteration(
    rot, origin, basis, scale, span, segment_of, table, hess_c, grad_c, q, q_pred, prior_w2,
    damping, max_angle, valid, silhouette1, depth1, silhouette, points, distance,
    distance_grad, labels, use, cand_points, cand_batch, flags, ints, floats, centre, focal,
    intr64, depth, prim, segment, good, b1, front, behind, b3, diff, q_out, dq_out, decrease,
    extra_stats,
):  # fmt: skip  # pragma: no cover - compiled
    B, P = origin.shape[0], origin.shape[1]
    K = _COUNTS.shape[0]
    fx, fy = focal[0], focal[1]
    near = floats[11]
    # The ray-cast (runtime.raycast.render_body, its compiled z-buffer, in float64).
    _zbuffer(
        rot.astype(np.float64), origin.astype(np.float64), basis.astype(np.float64),
        scale.astype(np.float64), span.astype(np.float64), intr64[0], intr64[1], intr64[2],
        intr64[3], near, prim, segment_of, segment, depth,
    )  # fmt: skip
    rendered = segment >= 0
    # The pixel classes (runtime.tracker.regions.classify).
    gate = np.array([floats[0]], np.float32)
    _classify(rendered, valid, silhouette1, depth1, depth, gate, flags[4], good, b1, front,
              behind, b3, diff)  # fmt: skip
    stats = np.zeros((B * K, 6, 7), np.float64)
    any_rows = False
    dt = depth.dtype
    rot_c = np.ascontiguousarray(rot)
    origin_c = np.ascontiguousarray(origin)
    span_c = np.ascontiguousarray(span)
    scale_c = np.ascontiguousarray(scale)
    # The rows, term by term in fit_frames' order (depth, extra, silhouette, labels): the
    # moments add each row in turn, so term by term is the concatenation's order.
    if flags[0]:
        consts = np.array([floats[5], 1e-9, 1e-12, 0.0], dt)
        d_b, d_p, d_s, d_g, d_r, d_w = _depth_rows(
            good, depth, segment, prim, rot_c, origin_c, basis, span_c, scale_c, diff,
            centre, focal, ints[3], consts, floats[6],
        )  # fmt: skip
        _moments(d_p, d_g, d_r, d_w, d_b, d_s, K, stats)
        any_rows = True
    if flags[1]:
        e_pts, e_seg, e_batch, e_off, e_w, e_err, e_cnt = _correspondences(
            b1, front, behind, b3, good, silhouette, rendered, ints[0], depth, segment,
            centre, focal, points, cand_points, cand_batch, ints[1], ints[2], floats[1],
            floats[2], floats[0], floats[3], floats[4], _FIRST_LIMB, B,
        )  # fmt: skip
        for b in range(B):
            extra_stats[b, 0] = e_err[b]
            extra_stats[b, 1] = e_cnt[b]
        _extra_moments(e_pts, e_seg, e_batch, e_off, e_w, K, stats)
        any_rows = True
    if flags[2]:
        consts = np.array([fx, fy, 1e-6, floats[7]], dt)
        s_b, s_p, s_s, s_g, s_r, s_w = _silhouette(
            rendered, distance, distance_grad, depth, segment, centre, focal, ints[4], consts,
            floats[8],
        )  # fmt: skip
        _moments(s_p, s_g, s_r, s_w, s_b, s_s, K, stats)
        any_rows = True
    if flags[3]:
        consts = np.array([floats[9], 0.0, 0.0, 1.0, 1e-9, 1e-12], dt)
        l_b, l_p, l_s, l_g, l_r, l_w = _label_rows(
            use, labels, points, rot_c, origin_c, basis, span_c, scale_c, ints[5], consts,
            floats[10],
        )  # fmt: skip
        _moments(l_p, l_g, l_r, l_w, l_b, l_s, K, stats)
        any_rows = True
    D = table.shape[2]
    hess = np.zeros((B, D, D), np.float64)
    grad = np.zeros((B, D), np.float64)
    if any_rows:
        _assemble(stats, table, _CHAINS, _COUNTS, hess, grad)
    for b in range(B if flags[6] else 0):  # the collision term's, added as fit_frames does
        for i in range(D):
            grad[b, i] = grad[b, i] + grad_c[b, i]
            for j in range(D):
                hess[b, i, j] = hess[b, i, j] + hess_c[b, i, j]
    q64 = q.astype(np.float64)
    qp64 = q_pred.astype(np.float64)
    q_new = np.empty((B, D), np.float64)
    dq_new = np.empty((B, D), np.float64)
    _step(hess, grad, q64, qp64, prior_w2.astype(np.float64), flags[5], damping, max_angle,
          _LIMITS, q_new, dq_new, decrease)  # fmt: skip
    for b in range(B):
        for i in range(D):
            q_out[b, i] = q_new[b, i]  # rounded to float32, as torch's .to
            dq_out[b, i] = dq_new[b, i]


def iteration_cpu(
    arrays: FitArrays,
    rot: torch.Tensor,
    origin: torch.Tensor,
    geom,
    table: torch.Tensor,
    collision: tuple[torch.Tensor, torch.Tensor],
    q: torch.Tensor,
    q_pred: torch.Tensor | None,
    prior_w2: torch.Tensor,
    damping: float,
    max_angle: float,
    H: int,
    W: int,
):
    """One iteration at poses ``q`` (B, 34) float32 whose primitives' frames are ``rot`` (B,
    P, 3, 3), ``origin`` (B, P, 3) and lever tables ``table`` (B, 6, 34) float64;
    ``collision``: the collision term's (hess, grad) float64. Returns the new poses and steps
    (B, 34) float32, the predicted decreases (B,) float64, and the last rendering's depth,
    primitive and segment images, the pixel classes (good, b1, front, behind, b3, depth
    difference) and the extra depth term's (error sum, count) per pose, as tensors."""
    B, P = origin.shape[:2]
    shape = (B, H, W)
    depth = np.empty(shape, np.float32)
    prim = np.empty(shape, np.int64)
    segment = np.empty(shape, np.int64)
    masks = [np.empty(shape, np.bool_) for _ in range(5)]
    diff = np.empty(shape, np.float32)
    q_out = np.empty((B, sk.NUM_DOFS), np.float32)
    dq_out = np.empty((B, sk.NUM_DOFS), np.float32)
    decrease = np.empty(B, np.float64)
    extra_stats = np.zeros((B, 2), np.float32)
    a = arrays
    q_np = q.numpy()
    _iteration(
        rot.numpy(), origin.numpy(), geom.basis.numpy(), geom.scale.expand(B, P, 3).numpy(),
        geom.span.expand(B, P, 2).numpy(), geom.segment.numpy(), table.numpy(),
        collision[0].numpy(), collision[1].numpy(), q_np,
        q_np if q_pred is None else q_pred.numpy(), prior_w2.numpy(), float(damping),
        float(max_angle), a.valid, a.silhouette1, a.depth1, a.silhouette, a.points, a.distance,
        a.distance_grad, a.labels, a.use, a.cand_points, a.cand_batch, a.flags, a.ints,
        a.floats, a.centre, a.focal, a.intr64, depth, prim, segment, *masks, diff, q_out, dq_out,
        decrease, extra_stats,
    )  # fmt: skip
    t = torch.from_numpy
    return (
        t(q_out), t(dq_out), t(decrease), t(depth), t(prim), t(segment),
        tuple(t(m) for m in masks), t(diff), t(extra_stats[:, 0].copy()),
        t(extra_stats[:, 1].copy()),
    )  # fmt: skip
