"""Inverse kinematics in joint-angle space: fit q to 3D marker positions.

Used by retargeting (mocap joints -> q for ground truth) and by the detector (class
centroids -> q, Wei section 4.2). A marker is a point on a segment's axis at a fraction of
the segment's length (the named joints are markers). The solver is Levenberg-Marquardt with
the analytic Jacobians of :mod:`shared.kinematics` and the damped solve of
:mod:`shared.least_squares`, batched over poses, with joint limits enforced by projection
after every step and a weak prior towards a reference pose that settles what the markers
leave free (e.g. the twist of a straight arm). On the CPU without autograd the same loop runs
compiled, in float64 (:mod:`shared.ik_kernel`; torch's loop stays for GPUs and gradients).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from . import skeleton as sk
from .body import BodyShape
from .compiled import compiled_module
from .kinematics import (
    Kinematics,
    clamp_to_limits,
    forward_kinematics,
    point_jacobian,
    pose_update,
    segment_points_to_world,
)
from .least_squares import damped_solve

__all__ = ["Markers", "NAMED_JOINT_MARKERS", "marker_positions", "IKResult", "fit_pose"]


@dataclass(frozen=True)
class Markers:
    """Points on segment axes.

    Attributes:
        segment: (M,) segment index of each marker.
        fraction: (M,) position along the segment axis as a fraction of its length.
    """

    segment: tuple[int, ...]
    fraction: tuple[float, ...]

    def __len__(self) -> int:
        return len(self.segment)


NAMED_JOINT_MARKERS = Markers(
    tuple(int(s) for s in sk.JOINT_SEGMENT), tuple(float(f) for f in sk.JOINT_FRACTION)
)


def marker_positions(kin: Kinematics, markers: Markers) -> torch.Tensor:
    """Camera-frame marker positions: (B, M, 3)."""
    like = kin.origins
    seg = torch.as_tensor(markers.segment, dtype=torch.long, device=like.device)
    frac = torch.as_tensor(markers.fraction, dtype=like.dtype, device=like.device)
    axis = torch.as_tensor(sk.SEGMENT_AXIS, dtype=like.dtype, device=like.device)[seg]
    local = (frac * kin.lengths[:, seg])[..., None] * axis
    return segment_points_to_world(kin, local, seg)


@dataclass
class IKResult:
    """Output of :func:`fit_pose`.

    Attributes:
        q: (B, 34) fitted poses.
        rms: (B,) weighted RMS marker error in metres.
        iterations: iterations run.
    """

    q: torch.Tensor
    rms: torch.Tensor
    iterations: int


def _cost(q, targets, weights, body, markers, q_ref, prior):
    kin = forward_kinematics(q, body)
    p = marker_positions(kin, markers)
    r = targets - p
    data = (weights[..., None] * r * r).sum((1, 2))
    reg = prior * ((q[:, 6:] - q_ref[:, 6:]) ** 2).sum(1)
    return data + reg, kin, p, r


def _compiled_kernel(*tensors: torch.Tensor):
    """:mod:`shared.ik_kernel` where every tensor is on the CPU without autograd and numba is
    installed, else None (the torch loop below)."""
    if any(t.device.type != "cpu" or t.requires_grad for t in tensors):
        return None
    return compiled_module("depthmocap.shared.ik_kernel")


def fit_pose(
    targets: torch.Tensor,
    q_init: torch.Tensor,
    body: BodyShape,
    weights: torch.Tensor | None = None,
    markers: Markers = NAMED_JOINT_MARKERS,
    q_ref: torch.Tensor | None = None,
    prior: float = 1e-5,
    iterations: int = 30,
    tolerance: float = 1e-7,
) -> IKResult:
    """Levenberg-Marquardt fit of poses to marker targets.

    Args:
        targets: (B, M, 3) camera-frame target positions (metres).
        q_init: (B, 34) starting poses.
        body: body parameters (unbatched or batch B).
        weights: (B, M) per-marker weights; 0 drops a marker (missing or occluded).
        markers: which segment point each target is.
        q_ref: (B, 34) pose the prior pulls joint angles towards (default ``q_init``).
        prior: weight of the prior per squared radian, relative to squared metres.
        iterations: maximum iterations.
        tolerance: stop once every pose's update is below this (max |dq|).
    Returns:
        :class:`IKResult`.
    """
    B, M = targets.shape[:2]
    if M != len(markers):
        raise ValueError(f"targets have {M} markers, marker set has {len(markers)}")
    weights = targets.new_ones(B, M) if weights is None else weights.to(targets)
    weights = torch.where(torch.isfinite(targets).all(-1), weights, torch.zeros_like(weights))
    targets = torch.nan_to_num(targets)
    q = clamp_to_limits(q_init.clone())
    q_ref = q if q_ref is None else q_ref
    seg = torch.as_tensor(markers.segment, dtype=torch.long, device=targets.device)
    kernel = _compiled_kernel(targets, weights, q, q_ref, body.lengths)
    if kernel is not None:
        frac = torch.as_tensor(markers.fraction, dtype=torch.float64)
        q, rms, its = kernel.fit_pose_cpu(
            targets, weights, q, q_ref.to(q), body, seg, frac, prior, iterations, tolerance
        )
        return IKResult(q, rms, its)
    lam = targets.new_full((B,), 1e-3)
    prior_diag = torch.cat([targets.new_zeros(6), targets.new_full((28,), prior)])
    cost, kin, p, r = _cost(q, targets, weights, body, markers, q_ref, prior)
    it = 0
    for it in range(1, iterations + 1):  # noqa: B007
        jac = point_jacobian(kin, p, seg).flatten(1, 2)  # (B, 3M, 34)
        w = weights.repeat_interleave(3, 1)
        jtw = jac.transpose(1, 2) * w[:, None, :]
        hess = jtw @ jac + torch.diag(prior_diag)
        grad = jtw @ r.flatten(1)[..., None]
        grad = grad[..., 0] - prior_diag * torch.cat(
            [q.new_zeros(B, 6), q[:, 6:] - q_ref[:, 6:]], 1
        )
        # Marquardt scaling: damping proportional to the curvature of each DoF.
        damping = lam[:, None] * (torch.diagonal(hess, dim1=1, dim2=2) + 1e-9)
        dq = damped_solve(hess, grad, damping)
        q_new = clamp_to_limits(pose_update(q, dq))
        cost_new, kin_new, p_new, r_new = _cost(
            q_new, targets, weights, body, markers, q_ref, prior
        )
        better = cost_new <= cost
        # Accept per pose where the cost went down; adapt the damping the other way.
        q = torch.where(better[:, None], q_new, q)
        cost = torch.where(better, cost_new, cost)
        lam = torch.where(better, lam * 0.3, lam * 10.0).clamp(1e-7, 1e7)
        sel = better[:, None, None]
        kin = Kinematics(
            torch.where(sel[..., None], kin_new.rotations, kin.rotations),
            torch.where(sel, kin_new.origins, kin.origins),
            torch.where(sel, kin_new.dof_axes, kin.dof_axes),
            torch.where(sel, kin_new.dof_origins, kin.dof_origins),
            kin.lengths,
        )
        p = torch.where(sel, p_new, p)
        r = torch.where(sel, r_new, r)
        step = torch.where(better, dq.abs().amax(1), torch.zeros_like(lam))
        if bool((step < tolerance).all()) and bool(better.all()):
            break
    err = (weights[..., None] * r * r).sum((1, 2)) / weights.sum(1).clamp_min(1e-12)
    return IKResult(q, err.sqrt(), it)
