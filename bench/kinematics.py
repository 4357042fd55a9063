"""Speed of forward kinematics and its analytic Jacobian (:mod:`shared.kinematics`).

The analytic Jacobian is compared with reverse-mode autograd through FK, what a naive
implementation would use, timed in the same run so that the ratio survives a noisy host.
"""

from __future__ import annotations

import torch
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import (
    forward_kinematics,
    named_joint_positions,
    point_jacobian,
    pose_update,
    rest_pose,
)
from depthmocap.shared.skeleton import DOF_LIMITS, JOINT_SEGMENT

from .timing import median_ms

__all__ = ["random_poses", "kinematics_rows"]


def random_poses(batch: int, dtype: torch.dtype, device: str | torch.device) -> torch.Tensor:
    """(batch, 34) seeded poses: each joint angle uniform in half its limits, ``[lo/2, hi/2]``
    (away from the limits, where the Jacobian is typical)."""
    g = torch.Generator().manual_seed(0)
    q = rest_pose(batch, dtype=dtype)
    lim = torch.as_tensor(DOF_LIMITS[6:], dtype=dtype)
    q[:, 6:] = 0.5 * (
        lim[:, 0] + torch.rand(batch, 28, generator=g, dtype=dtype) * (lim[:, 1] - lim[:, 0])
    )
    return q.to(device)


def kinematics_rows(
    batch: int, device: str, dtype: torch.dtype = torch.float32
) -> list[tuple[str, float, str]]:
    """FK and Jacobian timings for ``batch`` poses; rows of (what, ms, note)."""
    body = BodyShape.default(dtype, device)
    q = random_poses(batch, dtype, device)
    seg = torch.as_tensor(JOINT_SEGMENT, device=device)

    def fk():
        return forward_kinematics(q, body)

    def fk_jac():
        kin = forward_kinematics(q, body)
        p = named_joint_positions(kin)
        return point_jacobian(kin, p, seg)

    # Baseline: the same Jacobian by reverse-mode autograd through FK, on a smaller batch and
    # scaled up.
    small = max(1, batch // 10)
    qs = q[:small]

    def autograd_jac():
        def f(dq):
            return named_joint_positions(forward_kinematics(pose_update(qs, dq), body)).sum(0)

        return torch.autograd.functional.jacobian(f, torch.zeros_like(qs), vectorize=True)

    t_fk = median_ms(fk, device=device)
    t_jac = median_ms(fk_jac, device=device)
    t_auto = median_ms(autograd_jac, repeats=5, device=device) * batch / small
    # One tracker-sized call: a single pose and 5,000 surface points.
    kin1 = forward_kinematics(q[:1], body)
    pts = torch.randn(1, 5000, 3, dtype=dtype, device=device) * 0.1 + q[:1, None, :3]
    pseg = torch.randint(0, 15, (5000,), device=device)
    t_track = median_ms(lambda: point_jacobian(kin1, pts, pseg), device=device)
    return [
        (f"FK, {batch} poses", t_fk, "target < 5 ms on 2 CPU cores"),
        (f"FK + 16-joint Jacobian, {batch} poses", t_jac, ""),
        (
            f"autograd Jacobian baseline, {batch} poses",
            t_auto,
            f"analytic is {t_auto / t_jac:.1f}x faster",
        ),
        ("Jacobian of 5,000 surface points, 1 pose", t_track, "per tracker iteration"),
    ]
