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
from depthmocap.shared import kinematics_kernel as kk
from depthmocap.shared import skeleton as sk

from ..raycast_kernel import _zbuffer
from .closest_kernel import candidate_grid
from .collision_kernel import _collision
from .depth_kernel import _depth_rows
from .extra_kernel import _correspondences_in
from .label_kernel import label_rows_at
from .normal_kernel import _AFFECTS, _CHAINS, _COUNTS, _assemble, _column_rows, _moments
from .observation import label_term_pixels
from .regions_kernel import _classify
from .sampling_kernel import sampled
from .silhouette_kernel import _silhouette
from .step_kernel import _LIMITS, _step

__all__ = ["FitArrays", "fit_arrays", "iteration_cpu"]

_FIRST_LIMB = sk.FIRST_LIMB_SEGMENT


@dataclass
class FitArrays:
    """What an iteration reads that stays the same over a fit: the body's parameters and
    capsules, the observation's arrays (the views the term-by-term path hands its kernels),
    the observed candidates of the extra depth term, the labelled limb pixels and the
    settings, made once per :func:`~runtime.tracker.tracker.fit_frames` call."""

    body: tuple  # lengths (B, K), hip (B,), clavicle rest (B, 2), chest tilt (B,), float64
    capsules: tuple  # segment_of (P,), centre (B, P, 3), basis (P, 3, 3), span, scale
    arms: tuple  # the collision term's samples, their target capsules, tolerances, constants
    observed: tuple  # valid, silhouette, depth (B or 1, H, W) for the classes, then the views
    candidates: tuple  # the extra depth term's observed candidates and their grid
    labelled: tuple  # the label term's sampled pixels (N, 3) and their ratios (N,)
    flags: np.ndarray  # (7,) bool: depth, extra, silhouette, labels, occlusion, prior, collision
    ints: np.ndarray  # (6,) int64: see fit_arrays
    floats: np.ndarray  # (12,) float64: see fit_arrays
    centre: np.ndarray  # (2,) float32 cx, cy
    focal: np.ndarray  # (2,) float32 fx, fy
    intr64: np.ndarray  # (4,) float64 fx, fy, cx, cy: the ray-caster's


def fit_arrays(obs, observed, body, geom, B: int, cfg, labels_on: bool, consts: dict) -> FitArrays:
    """The :class:`FitArrays` of a fit of B poses of ``body`` (capsules ``geom``) on ``obs``
    (float32, CPU) with the extra depth term's ``observed`` candidates (None: the term is
    off) under ``cfg``; ``labels_on``: the label term runs; ``consts``: the terms' constants
    by name (their modules hold them)."""
    from .collision_term import collision_samples

    K, P = sk.NUM_SEGMENTS, geom.segment.shape[0]
    views = [obs.valid, obs.silhouette, obs.depth]
    shared = all(t.stride(0) == 0 for t in views)
    classes = tuple(np.ascontiguousarray((t[:1] if shared else t).numpy()) for t in views)
    intr = obs.intr
    labels = obs.labels if obs.labels is not None else torch.full_like(obs.depth, -1).long()
    use = label_term_pixels(obs)
    if observed is None:
        cand_points = np.zeros((0, 3), np.float32)
        cand_batch = np.zeros(0, np.int64)
    else:
        cand_points = observed.points.numpy()
        cand_batch = observed.batch.numpy().astype(np.int64, copy=False)
    candidates = candidate_grid(cand_points, cand_batch, B)
    c = consts
    labelled = sampled(use.numpy(), int(c["max_label_pixels"]))[::2]  # (idx, ratio)
    flags = np.array(
        [cfg.use_depth, observed is not None, cfg.use_silhouette, labels_on,
         cfg.occlusion_handling, cfg.use_prior, cfg.use_collision], np.bool_,
    )  # fmt: skip
    ints = np.array(
        [c["extra_margin"], c["extra_half"], c["max_candidates"], c["max_depth_pixels"],
         c["max_silhouette_pixels"], c["max_label_pixels"]], np.int64,
    )  # fmt: skip
    floats = np.array(
        [cfg.depth_gate_m, cfg.extra_gate_m, c["extra_max_distance"] ** 2, c["sigma_torso"],
         cfg.sigma_extra_m, c["min_cosine"], cfg.sigma_depth_m, c["deadzone"],
         cfg.sigma_silhouette_px, c["label_gate"], cfg.sigma_label_m, c["near"]], np.float64,
    )  # fmt: skip
    per_pose = kk._per_pose
    body_arrays = (
        per_pose(body.lengths, B, K), per_pose(body.hip_half_width, B),
        per_pose(body.clavicle_rest, B, 2), per_pose(body.chest_tilt, B),
    )  # fmt: skip
    capsules = (
        geom.segment.numpy(), geom.centre.expand(B, P, 3).numpy(),
        np.ascontiguousarray(geom.basis.numpy()),
        np.ascontiguousarray(geom.span.expand(B, P, 2).numpy()),
        np.ascontiguousarray(geom.scale.expand(B, P, 3).numpy()),
    )  # fmt: skip
    samples = collision_samples(cfg.leg_collision)
    arms = (
        np.array(samples.segment, np.int64), np.array(samples.fraction, np.float32),
        np.asarray(sk.SEGMENT_AXIS, np.float32), np.array(samples.targets, np.int64),
        np.array(c["collision"][0], np.float32),
        np.array([c["collision"][1], 0.0, 0.0, 1.0, 1e-9, 1e-12], np.float32),
    )  # fmt: skip
    observed_arrays = (
        *classes, obs.silhouette.numpy(), obs.points.numpy(), obs.distance.numpy(),
        obs.distance_grad.numpy(), labels.numpy(), use.numpy(),
    )  # fmt: skip
    return FitArrays(
        body_arrays, capsules, arms, observed_arrays, candidates, labelled, flags, ints,
        floats, np.array([intr.cx, intr.cy], np.float32),
        np.array([intr.fx, intr.fy], np.float32),
        np.array([intr.fx, intr.fy, intr.cx, intr.cy], np.float64),
    )  # fmt: skip


@numba.njit(inline="always")
def _cross_f32(a0, a1, a2, b0, b1, b2):  # pragma: no cover - compiled
    """torch's float32 cross product on the CPU: each component ``fma(a_i, b_j, -(a_j b_i))``
    (the second product rounded, the first exact in float64)."""
    x = np.float32(np.float64(a1) * np.float64(b2) - np.float64(np.float32(np.float64(a2) * b1)))
    y = np.float32(np.float64(a2) * np.float64(b0) - np.float64(np.float32(np.float64(a0) * b2)))
    z = np.float32(np.float64(a0) * np.float64(b1) - np.float64(np.float32(np.float64(a1) * b0)))
    return x, y, z


@numba.njit(inline="always")
def _rotate_f32(r, x0, x1, x2, i):  # pragma: no cover - compiled
    """Row ``i`` of the float32 3 x 3 ``r`` times (x0, x1, x2), summed in order as torch's
    CPU matmul of one 3-vector."""
    return (r[i, 0] * x0 + r[i, 1] * x1) + r[i, 2] * x2


@numba.njit(inline="always")
def axis_point_f32(rotation, origin, f, axis, out):  # pragma: no cover - compiled
    """A point ``f`` along a segment's ``axis`` (3,) in camera frame into ``out`` (3,), as
    ``shared.kinematics.segment_axis_points`` makes it in float32: ``f`` times the axis,
    rotated by the segment's ``rotation``, plus its ``origin``."""
    x0, x1, x2 = f * axis[0], f * axis[1], f * axis[2]
    for i in range(3):
        out[i] = _rotate_f32(rotation, x0, x1, x2, i) + origin[i]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _pose_terms(
    q, lengths, hip, clavicle, tilt, segment_of, centre, arm_seg, arm_frac, seg_axis, targets,
    allowed, basis, span, scale, coll_consts, use_collision, rotations, origins, dof_axes,
    dof_origins, rot, origin, table, hess_c, grad_c,
):  # fmt: skip  # pragma: no cover - compiled
    """What an iteration needs of the poses alone, as the term-by-term path makes it: the
    forward kinematics (:func:`shared.kinematics.forward_kinematics`, float64 rounded to
    float32), the primitives' frames (``SegmentGeometry.frames``), the lever tables
    (``gauss_newton.lever_table``, float64) and the collision term's equations
    (``collision_rows`` through ``normal_equations`` with its columns)."""
    B, K, D = q.shape[0], rotations.shape[1], q.shape[1]
    P = segment_of.shape[0]
    r64 = np.empty((B, K, 3, 3))
    o64 = np.empty((B, K, 3))
    a64 = np.empty((B, D, 3))
    d64 = np.empty((B, D, 3))
    kk._fk(
        q.astype(np.float64), lengths, hip, clavicle, tilt, kk._PARENT, kk._ORDER, kk._AXIS,
        kk._ATTACH, kk._LATERAL, kk._SLOTS, kk._DOF_AXIS, kk._DOF_SEGMENT, kk._DOF_SLOT,
        kk._CLAVICLE, kk._CHEST, kk._ARMS, kk._MIRROR, r64, o64, a64, d64,
    )  # fmt: skip
    for b in range(B):
        for k in range(K):
            for i in range(3):
                origins[b, k, i] = o64[b, k, i]
                for j in range(3):
                    rotations[b, k, i, j] = r64[b, k, i, j]
        for d in range(D):
            for i in range(3):
                dof_axes[b, d, i] = a64[b, d, i]
                dof_origins[b, d, i] = d64[b, d, i]
        for p in range(P):
            k = segment_of[p]
            r = rotations[b, k]
            c0, c1, c2 = centre[b, p, 0], centre[b, p, 1], centre[b, p, 2]
            for i in range(3):
                for j in range(3):
                    rot[b, p, i, j] = r[i, j]
                origin[b, p, i] = origins[b, k, i] + _rotate_f32(r, c0, c1, c2, i)
        for c in range(6):  # the root translations' columns: (0, e_i)
            for j in range(3):
                table[b, c, j] = 1.0 if c == j + 3 else 0.0
        for j in range(3, D):  # the rotational DoFs': (a, o x a)
            ax, ay, az = dof_axes[b, j, 0], dof_axes[b, j, 1], dof_axes[b, j, 2]
            m0, m1, m2 = _cross_f32(
                dof_origins[b, j, 0], dof_origins[b, j, 1], dof_origins[b, j, 2], ax, ay, az
            )
            table[b, 0, j], table[b, 1, j], table[b, 2, j] = ax, ay, az
            table[b, 3, j], table[b, 4, j], table[b, 5, j] = m0, m1, m2
    if not use_collision:
        return
    M = arm_seg.shape[0]
    points = np.empty((B, M, 3), np.float32)
    for b in range(B):
        for m in range(M):
            k = arm_seg[m]
            f = arm_frac[m] * np.float32(lengths[b, k])
            axis_point_f32(rotations[b, k], origins[b, k], f, seg_axis[k], points[b, m])
    affects = _AFFECTS.astype(np.float32)
    c_b, c_p, c_s, c_g, c_r, c_w, c_col = _collision(
        points, arm_seg, targets, allowed, rot, origin, basis, span, scale, affects, coll_consts
    )
    n = c_p.shape[0]
    lever = np.empty((n, 6))
    for i in range(n):
        g0, g1, g2 = c_g[i, 0], c_g[i, 1], c_g[i, 2]
        x, y, z = _cross_f32(c_p[i, 0], c_p[i, 1], c_p[i, 2], g0, g1, g2)
        lever[i, 0], lever[i, 1], lever[i, 2] = x, y, z
        lever[i, 3], lever[i, 4], lever[i, 5] = g0, g1, g2
    _column_rows(
        lever, c_r.astype(np.float64), c_w.astype(np.float64), c_b, c_s,
        c_col.astype(np.float64), table, _AFFECTS, hess_c, grad_c,
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
    q, q_pred, prior_w2, damping, max_angle, lengths, hip, clavicle, tilt, segment_of, centre,
    basis, span, scale, arm_seg, arm_frac, seg_axis, targets, allowed, coll_consts, valid,
    silhouette1, depth1, silhouette, points, distance, distance_grad, labels, use,
    candidates, labelled, flags, ints, floats, centre_px, focal, intr64, rotations,
    origins, dof_axes, dof_origins, rot, origin, depth, prim, segment, good, b1, front,
    behind, b3, diff, q_out, dq_out, decrease, extra_stats, use_pose_prior, hess_p, grad_p,
):  # fmt: skip  # pragma: no cover - compiled
    """One iteration of ``fit_frames`` at poses ``q`` (B, 34) float32 into ``q_out``,
    ``dq_out`` and ``decrease``; the kinematics, frames, rendering, classes and the extra
    term's (error sum, count) it was linearized with into the other output arrays
    (:func:`iteration_cpu` names them all)."""
    D = q.shape[1]
    table = np.empty((q.shape[0], 6, D))
    hess_c = np.zeros((q.shape[0], D, D))
    grad_c = np.zeros((q.shape[0], D))
    _pose_terms(
        q, lengths, hip, clavicle, tilt, segment_of, centre, arm_seg, arm_frac, seg_axis, targets,
        allowed, basis, span, scale, coll_consts, flags[6], rotations, origins, dof_axes,
        dof_origins, rot, origin, table, hess_c, grad_c,
    )  # fmt: skip
    B = origin.shape[0]
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
    # The rows, term by term in fit_frames' order (depth, extra, silhouette, labels): the
    # moments add each row in turn, so term by term is the concatenation's order.
    if flags[0]:
        consts = np.array([floats[5], 1e-9, 1e-12, 0.0], dt)
        d_b, d_p, d_s, d_g, d_r, d_w = _depth_rows(
            good, depth, segment, prim, rot, origin, basis, span, scale, diff,
            centre_px, focal, ints[3], consts, floats[6],
        )  # fmt: skip
        _moments(d_p, d_g, d_r, d_w, d_b, d_s, K, stats)
        any_rows = True
    if flags[1]:
        e_pts, e_seg, e_batch, e_off, e_w, e_err, e_cnt = _correspondences_in(
            b1, front, behind, b3, good, silhouette, rendered, ints[0], depth, segment,
            centre_px, focal, points, candidates, ints[1], ints[2], floats[1], floats[2],
            floats[0], floats[3], floats[4], _FIRST_LIMB, B,
        )  # fmt: skip
        for b in range(B):
            extra_stats[b, 0] = e_err[b]
            extra_stats[b, 1] = e_cnt[b]
        _extra_moments(e_pts, e_seg, e_batch, e_off, e_w, K, stats)
        any_rows = True
    if flags[2]:
        consts = np.array([fx, fy, 1e-6, floats[7]], dt)
        s_b, s_p, s_s, s_g, s_r, s_w = _silhouette(
            rendered, distance, distance_grad, depth, segment, centre_px, focal, ints[4], consts,
            floats[8],
        )  # fmt: skip
        _moments(s_p, s_g, s_r, s_w, s_b, s_s, K, stats)
        any_rows = True
    if flags[3]:
        consts = np.array([floats[9], 0.0, 0.0, 1.0, 1e-9, 1e-12], dt)
        l_b, l_p, l_s, l_g, l_r, l_w = label_rows_at(
            labelled[0], labelled[1], labels, points, rot, origin, basis, span, scale, consts,
            floats[10],
        )  # fmt: skip
        _moments(l_p, l_g, l_r, l_w, l_b, l_s, K, stats)
        any_rows = True
    hess = np.zeros((B, D, D), np.float64)
    grad = np.zeros((B, D), np.float64)
    if any_rows:
        _assemble(stats, table, _CHAINS, _COUNTS, hess, grad)
    for b in range(B if flags[6] else 0):  # the collision term's, added as fit_frames does
        for i in range(D):
            grad[b, i] = grad[b, i] + grad_c[b, i]
            for j in range(D):
                hess[b, i, j] = hess[b, i, j] + hess_c[b, i, j]
    for b in range(B if use_pose_prior else 0):  # the learned pose prior's, after them
        for i in range(D):
            grad[b, i] = grad[b, i] + grad_p[b, i]
            for j in range(D):
                hess[b, i, j] = hess[b, i, j] + hess_p[b, i, j]
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
    q: torch.Tensor,
    q_pred: torch.Tensor | None,
    prior_w2: torch.Tensor,
    damping: float,
    max_angle: float,
    H: int,
    W: int,
    pose_prior: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> dict:
    """One iteration at poses ``q`` (B, 34) float32 (``q_pred``: the prior's prediction, None:
    no prior; ``prior_w2`` (34,) its weights squared; ``pose_prior``: the learned pose
    prior's normal equations (B, 34, 34) and (B, 34) float64 at ``q``, None: none).
    Returns, as tensors: ``q`` and ``dq`` (B, 34) float32 the new poses and steps,
    ``decrease`` (B,) float64, and what the iteration was linearized with: the kinematics'
    fields (``rotations``, ``origins``, ``dof_axes``, ``dof_origins``), the primitives'
    frames (``rot``, ``origin``), the rendering (``depth``, ``primitive``, ``segment``), the
    pixel classes (``classes``: good, b1, b2 front, b2 behind, b3, the depth difference) and
    the extra depth term's ``error_sum`` and ``count`` per pose."""
    a = arrays
    B, D = q.shape
    K, P = sk.NUM_SEGMENTS, a.capsules[0].shape[0]
    shape = (B, H, W)
    out = {
        "rotations": np.empty((B, K, 3, 3), np.float32),
        "origins": np.empty((B, K, 3), np.float32),
        "dof_axes": np.empty((B, D, 3), np.float32),
        "dof_origins": np.empty((B, D, 3), np.float32),
        "rot": np.empty((B, P, 3, 3), np.float32),
        "origin": np.empty((B, P, 3), np.float32),
        "depth": np.empty(shape, np.float32),
        "primitive": np.empty(shape, np.int64),
        "segment": np.empty(shape, np.int64),
    }
    classes = [np.empty(shape, np.bool_) for _ in range(5)] + [np.empty(shape, np.float32)]
    q_out = np.empty((B, D), np.float32)
    dq_out = np.empty((B, D), np.float32)
    decrease = np.empty(B, np.float64)
    extra = np.zeros((B, 2), np.float32)
    q_np = q.numpy()
    if pose_prior is None:
        hess_p, grad_p = np.zeros((1, D, D)), np.zeros((1, D))
    else:
        hess_p, grad_p = (np.ascontiguousarray(t.numpy()) for t in pose_prior)
    _iteration(
        q_np, q_np if q_pred is None else q_pred.numpy(), prior_w2.numpy(), float(damping),
        float(max_angle), *a.body, *a.capsules, *a.arms, *a.observed, a.candidates,
        a.labelled, a.flags, a.ints, a.floats, a.centre, a.focal, a.intr64, *out.values(),
        *classes, q_out, dq_out, decrease, extra, pose_prior is not None, hess_p, grad_p,
    )  # fmt: skip
    t = torch.from_numpy
    result = {name: t(value) for name, value in out.items()}
    result.update(
        q=t(q_out),
        dq=t(dq_out),
        decrease=t(decrease),
        classes=tuple(t(c) for c in classes),
        error_sum=t(extra[:, 0].copy()),
        count=t(extra[:, 1].copy()),
    )
    return result
