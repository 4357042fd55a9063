"""The inverse kinematics' Levenberg-Marquardt loop as one compiled call (numba): the CPU
path of :func:`shared.ik.fit_pose`.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:func:`shared.ik.fit_pose` imports it lazily and keeps its torch code for autograd, GPUs and
where numba is missing.

Why: the detector runs the IK from 8-9 starts for 15 iterations on every frame it sees, and
in torch each iteration is ~70 small tensor ops (kinematics, point Jacobian, normal
equations, solve, the SO(3) update, the acceptance test): 15 ms a detection on the CPU,
about a fifth of a detector frame (issue 38). Here the same steps run in float64 in one
call; the results agree with torch's to its rounding (float32 inputs are computed in
float32 there), so a detection can differ where the LM path sits on a knife edge.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch

from . import kinematics_kernel as kk
from . import skeleton as sk

__all__ = ["fit_pose_cpu", "cholesky_solve"]

_SMALL = kk._SMALL  # shared.so3's switch to Taylor series
_AFFECTS = sk.DOF_AFFECTS_SEGMENT.astype(np.float64)  # (K, 34)
_LIMITS = np.ascontiguousarray(sk.DOF_LIMITS, dtype=np.float64)  # (34, 2)


@numba.njit(inline="always")
def _quaternion(x, y, z):  # pragma: no cover - compiled
    """shared.so3.rotvec_to_quaternion of one rotation vector: (w, x, y, z)."""
    th2 = x * x + y * y + z * z
    if th2 < _SMALL * _SMALL:
        w, s = 1.0 - th2 / 8.0, 0.5 - th2 / 48.0
    else:
        th = math.sqrt(th2)
        w, s = math.cos(0.5 * th), math.sin(0.5 * th) / th
    return w, x * s, y * s, z * s


@numba.njit(inline="always")
def _compose(a0, a1, a2, b0, b1, b2):  # pragma: no cover - compiled
    """shared.so3.compose_rotvec: the rotation vector of exp(a) exp(b)."""
    aw, ax, ay, az = _quaternion(a0, a1, a2)
    bw, bx, by, bz = _quaternion(b0, b1, b2)
    w = aw * bw - (ax * bx + ay * by + az * bz)
    x = aw * bx + bw * ax + (ay * bz - az * by)
    y = aw * by + bw * ay + (az * bx - ax * bz)
    z = aw * bz + bw * az + (ax * by - ay * bx)
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    s2 = x * x + y * y + z * z
    if s2 < _SMALL * _SMALL:
        f = 2.0 / max(w, 1e-12)
    else:
        s = math.sqrt(s2)
        f = 2.0 * math.atan2(s, w) / s
    return x * f, y * f, z * f


@numba.njit(inline="always")
def cholesky_solve(matrix, rhs, out):  # pragma: no cover - compiled
    """``out = matrix^-1 rhs`` for a symmetric positive definite (n, n) ``matrix`` given by
    its lower triangle, which is overwritten by the Cholesky factor."""
    n = rhs.shape[0]
    for j in range(n):
        s = matrix[j, j]
        for k in range(j):
            s -= matrix[j, k] * matrix[j, k]
        s = math.sqrt(max(s, 1e-300))
        matrix[j, j] = s
        for i in range(j + 1, n):
            t = matrix[i, j]
            for k in range(j):
                t -= matrix[i, k] * matrix[j, k]
            matrix[i, j] = t / s
    for i in range(n):  # L y = b
        t = rhs[i]
        for k in range(i):
            t -= matrix[i, k] * out[k]
        out[i] = t / matrix[i, i]
    for i in range(n - 1, -1, -1):  # L^T x = y
        t = out[i]
        for k in range(i + 1, n):
            t -= matrix[k, i] * out[k]
        out[i] = t / matrix[i, i]


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _markers(rotations, origins, local, segment, out):  # pragma: no cover - compiled
    """Camera-frame marker positions (B, M, 3) of markers ``local`` (B, M, 3) on ``segment``."""
    for b in range(out.shape[0]):
        for m in range(out.shape[1]):
            k = segment[m]
            for i in range(3):
                out[b, m, i] = origins[b, k, i] + (
                    rotations[b, k, i, 0] * local[b, m, 0]
                    + rotations[b, k, i, 1] * local[b, m, 1]
                    + rotations[b, k, i, 2] * local[b, m, 2]
                )


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _cost(q, q_ref, targets, weights, points, prior, residual, cost):  # pragma: no cover
    """Residuals ``targets - points`` and each pose's cost (weighted squares + prior)."""
    B, M = points.shape[0], points.shape[1]
    for b in range(B):
        c = 0.0
        for m in range(M):
            for i in range(3):
                r = targets[b, m, i] - points[b, m, i]
                residual[b, m, i] = r
                c += weights[b, m] * r * r
        reg = 0.0
        for d in range(6, q.shape[1]):
            e = q[b, d] - q_ref[b, d]
            reg += e * e
        cost[b] = c + prior * reg


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _lm_step(b, q, q_ref, points, residual, weights, segment, dof_axes, dof_origins, affects,
             prior_diag, lam, hess, grad, col, dq):  # fmt: skip  # pragma: no cover - compiled
    """Pose b's damped step ``dq`` (34,): the normal equations of its markers' point
    Jacobian (translations: the camera axes; rotations: ``a x (p - o)``, on the chain of
    the marker's segment), the prior, Marquardt damping, a Cholesky solve; ``hess``,
    ``grad`` and ``col`` (34, 3) are scratch space."""
    D = q.shape[1]
    hess[:] = 0.0
    grad[:] = 0.0
    for m in range(points.shape[1]):
        w = weights[b, m]
        if w == 0.0:
            continue
        k = segment[m]
        for d in range(D):
            if affects[k, d] == 0.0 or d < 3:
                for i in range(3):
                    col[d, i] = 1.0 if (d == i and affects[k, d] != 0.0) else 0.0
            else:
                ax, ay, az = dof_axes[b, d, 0], dof_axes[b, d, 1], dof_axes[b, d, 2]
                px = points[b, m, 0] - dof_origins[b, d, 0]
                py = points[b, m, 1] - dof_origins[b, d, 1]
                pz = points[b, m, 2] - dof_origins[b, d, 2]
                col[d, 0] = ay * pz - az * py
                col[d, 1] = az * px - ax * pz
                col[d, 2] = ax * py - ay * px
        for d in range(D):
            if affects[k, d] == 0.0:
                continue
            grad[d] += w * (
                col[d, 0] * residual[b, m, 0]
                + col[d, 1] * residual[b, m, 1]
                + col[d, 2] * residual[b, m, 2]
            )
            for e in range(d + 1):
                if affects[k, e] != 0.0:
                    hess[d, e] += w * (
                        col[d, 0] * col[e, 0] + col[d, 1] * col[e, 1] + col[d, 2] * col[e, 2]
                    )
    for d in range(D):
        hess[d, d] += prior_diag[d]
        grad[d] -= prior_diag[d] * (q[b, d] - q_ref[b, d]) if d >= 6 else 0.0
        for e in range(d):
            hess[e, d] = hess[d, e]
    # Cholesky of H + lam (diag(H) + 1e-9), in place in the lower triangle.
    for d in range(D):
        hess[d, d] += lam * (hess[d, d] + 1e-9)
    cholesky_solve(hess, grad, dq)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _fit(targets, weights, q, q_ref, local, segment, prior, iterations, tolerance, limits,
         affects, lengths, hip, clavicle, tilt, parent, order, seg_axis, attach, lateral,
         slots, dof_axis, dof_segment, dof_slot, clav_dofs, chest, arms,
         mirror):  # fmt: skip  # pragma: no cover - compiled
    B, M = targets.shape[0], targets.shape[1]
    K, D = parent.shape[0], q.shape[1]
    rot, org = np.empty((B, K, 3, 3)), np.empty((B, K, 3))
    axes, dorg = np.empty((B, D, 3)), np.empty((B, D, 3))
    rot_n, org_n = np.empty((B, K, 3, 3)), np.empty((B, K, 3))
    axes_n, dorg_n = np.empty((B, D, 3)), np.empty((B, D, 3))
    pts, res, cost = np.empty((B, M, 3)), np.empty((B, M, 3)), np.empty(B)
    pts_n, res_n, cost_n = np.empty((B, M, 3)), np.empty((B, M, 3)), np.empty(B)
    q_new, dq = np.empty((B, D)), np.empty((B, D))
    prior_diag = np.zeros(D)
    for d in range(6, D):
        prior_diag[d] = prior
    lam = np.full(B, 1e-3)
    hess, grad, col = np.empty((D, D)), np.empty(D), np.empty((D, 3))
    kk._fk(q, lengths, hip, clavicle, tilt, parent, order, seg_axis, attach, lateral, slots,
           dof_axis, dof_segment, dof_slot, clav_dofs, chest, arms, mirror, rot, org, axes,
           dorg)  # fmt: skip
    _markers(rot, org, local, segment, pts)
    _cost(q, q_ref, targets, weights, pts, prior, res, cost)
    it = 0
    for it in range(1, iterations + 1):  # noqa: B007 (returned)
        for b in range(B):
            _lm_step(b, q, q_ref, pts, res, weights, segment, axes, dorg, affects, prior_diag,
                     lam[b], hess, grad, col, dq[b])  # fmt: skip
            for d in range(D):
                q_new[b, d] = q[b, d] + dq[b, d]
            q_new[b, 3], q_new[b, 4], q_new[b, 5] = _compose(
                dq[b, 3], dq[b, 4], dq[b, 5], q[b, 3], q[b, 4], q[b, 5]
            )
            for d in range(6, D):
                q_new[b, d] = min(max(q_new[b, d], limits[d, 0]), limits[d, 1])
        kk._fk(q_new, lengths, hip, clavicle, tilt, parent, order, seg_axis, attach, lateral,
               slots, dof_axis, dof_segment, dof_slot, clav_dofs, chest, arms, mirror, rot_n,
               org_n, axes_n, dorg_n)  # fmt: skip
        _markers(rot_n, org_n, local, segment, pts_n)
        _cost(q_new, q_ref, targets, weights, pts_n, prior, res_n, cost_n)
        done = True
        for b in range(B):
            better = cost_n[b] <= cost[b]
            step = 0.0
            if better:
                for d in range(D):
                    step = max(step, abs(dq[b, d]))
                q[b, :] = q_new[b, :]
                cost[b] = cost_n[b]
                rot[b] = rot_n[b]
                org[b] = org_n[b]
                axes[b] = axes_n[b]
                dorg[b] = dorg_n[b]
                pts[b] = pts_n[b]
                res[b] = res_n[b]
                lam[b] = max(lam[b] * 0.3, 1e-7)
            else:
                lam[b] = min(lam[b] * 10.0, 1e7)
                done = False
            if not step < tolerance:
                done = False
        if done:
            break
    rms = np.empty(B)
    for b in range(B):
        num, den = 0.0, 0.0
        for m in range(M):
            den += weights[b, m]
            for i in range(3):
                num += weights[b, m] * res[b, m, i] * res[b, m, i]
        rms[b] = math.sqrt(num / max(den, 1e-12))
    return it, rms


def fit_pose_cpu(
    targets: torch.Tensor,
    weights: torch.Tensor,
    q: torch.Tensor,
    q_ref: torch.Tensor,
    body,
    segment: torch.Tensor,
    fraction: torch.Tensor,
    prior: float,
    iterations: int,
    tolerance: float,
) -> tuple[torch.Tensor, torch.Tensor, int]:
    """:func:`shared.ik.fit_pose`'s loop on CPU tensors: finite ``targets`` (B, M, 3),
    ``weights`` (B, M), start poses ``q`` (B, 34) inside the limits, ``q_ref`` (B, 34),
    markers ``segment`` (M,) at ``fraction`` (M,) of their segment's length. Returns the
    fitted poses (B, 34) and weighted RMS errors (B,) in ``targets``' dtype, and the
    iterations run."""
    B, M = targets.shape[:2]
    K = sk.NUM_SEGMENTS
    lengths = kk._per_pose(body.lengths, B, K)
    seg = segment.detach().cpu().numpy().astype(np.int64)
    frac = fraction.detach().cpu().numpy().astype(np.float64)
    local = (frac * lengths[:, seg])[..., None] * kk._AXIS[seg]  # (B, M, 3)
    q64 = kk._per_pose(q, B, sk.NUM_DOFS).copy()
    its, rms = _fit(
        kk._per_pose(targets, B, M, 3), kk._per_pose(weights, B, M), q64,
        kk._per_pose(q_ref, B, sk.NUM_DOFS),
        np.ascontiguousarray(local), seg, float(prior), int(iterations), float(tolerance),
        _LIMITS, _AFFECTS, lengths, kk._per_pose(body.hip_half_width, B),
        kk._per_pose(body.clavicle_rest, B, 2), kk._per_pose(body.chest_tilt, B), kk._PARENT,
        kk._ORDER, kk._AXIS, kk._ATTACH, kk._LATERAL, kk._SLOTS, kk._DOF_AXIS, kk._DOF_SEGMENT,
        kk._DOF_SLOT, kk._CLAVICLE, kk._CHEST, kk._ARMS, kk._MIRROR,
    )  # fmt: skip
    dt = targets.dtype
    return torch.from_numpy(q64).to(dt), torch.from_numpy(rms).to(dt), int(its)
