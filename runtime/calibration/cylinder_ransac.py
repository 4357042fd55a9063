"""RANSAC cylinder fit of one bone in a labelled depth frame (Wei section 6).

A sample is a radius r (uniform in a range around the template's) and a pair of the bone's
pixels. Each pixel is pushed back along its viewing ray by r, onto the cylinder's axis, so the
pair gives the axis end points a, b; the cylinder (a, b, r) projects to a 2D band: pixels whose
projection onto the image segment a'b' falls between the ends, within ``r * f / z`` pixels
of it. Its score is Wei's eq. 14,

    Q = N_in - N_out,

N_in the bone's pixels inside the band and N_out every other pixel inside it (pixels of other
classes, misclassified ones and background). The best sample spans the bone's silhouette
exactly: a longer or wider band takes in background, a shorter one leaves bone pixels out. So
``|b - a|`` is the visible axial extent of the bone and r its radius as seen from the camera.

The winner then fixes which pixels belong to the bone (its inliers: the bone's pixels inside
its band); the cylinder is refitted on them for precision that random pairs cannot reach: the
axis is their principal direction (or a given one), the length the axial extent between two
quantiles, the radius from the spread across the axis in the image plane, and the axis lies
that radius behind the surface.

Vectorized over samples x pixels of the bone's image region (strided to a pixel budget).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from depthmocap.shared.camera import Intrinsics, depth_to_points

__all__ = ["CylinderFit", "fit_cylinder"]


@dataclass
class CylinderFit:
    """Best cylinder of one bone.

    Attributes:
        found: enough pixels for a fit.
        start, end: (3,) axis end points, camera metres.
        radius: metres.
        length: ``|end - start|``, metres.
        score: Q of the winner (in strided pixels).
    """

    found: bool
    start: torch.Tensor
    end: torch.Tensor
    radius: float
    length: float
    score: float


def fit_cylinder(
    depth_m: torch.Tensor,
    bone_px: torch.Tensor,
    intr: Intrinsics,
    radius_range: tuple[float, float],
    samples: int = 1024,
    max_pixels: int = 4000,
    min_pixels: int = 20,
    generator: torch.Generator | None = None,
    axis: torch.Tensor | None = None,
    extent_quantile: float = 0.01,
    radius_quantile: float = 0.9,
) -> CylinderFit:
    """Fit one bone's cylinder (module docstring).

    Args:
        depth_m: (H, W) metres, 0 = no reading.
        bone_px: (H, W) bool, pixels labelled as this bone (any of its classes).
        intr: intrinsics.
        radius_range: (low, high) radii sampled, metres.
        samples: RANSAC samples.
        max_pixels: pixels of the region scored at most (the region is strided to fit).
        min_pixels: fewer bone pixels with depth: not found.
        generator: random source (CPU).
        axis: (3,) known axis direction (torso segments: the trunk's up direction); else the
            principal axis of the inliers.
        extent_quantile: the axial extent runs between this quantile and its complement.
        radius_quantile: radius = this quantile of |lateral offset| / itself (pixels are
            uniform across a cylinder's image width, so the q-quantile of |offset| is q r).
    """
    dev, dt = depth_m.device, depth_m.dtype
    valid = bone_px & (depth_m > 0)
    n = int(valid.sum())
    nothing = CylinderFit(False, depth_m.new_zeros(3), depth_m.new_zeros(3), 0.0, 0.0, 0.0)
    if n < min_pixels:
        return nothing
    pts_img = depth_to_points(depth_m[None], intr)[0]
    vv, uu = valid.nonzero(as_tuple=True)
    pts = pts_img[vv, uu]
    z_mean = float(pts[:, 2].mean())

    # Region scored: the bone's bounding box grown by the largest band radius.
    grow = int(radius_range[1] * intr.fx / max(z_mean, 0.1)) + 2
    H, W = depth_m.shape
    r0, r1 = max(int(vv.min()) - grow, 0), min(int(vv.max()) + grow + 1, H)
    c0, c1 = max(int(uu.min()) - grow, 0), min(int(uu.max()) + grow + 1, W)
    area = (r1 - r0) * (c1 - c0)
    stride = max(1, int((area / max_pixels) ** 0.5 + 0.999))
    gv, gu = torch.meshgrid(
        torch.arange(r0, r1, stride, device=dev), torch.arange(c0, c1, stride, device=dev),
        indexing="ij",
    )  # fmt: skip
    gv, gu = gv.reshape(-1), gu.reshape(-1)
    is_bone = valid[gv, gu]
    grid = torch.stack([gu, gv], -1).to(dt)  # (P, 2) pixel coordinates (u, v)

    def rand(*shape):
        return torch.rand(*shape, generator=generator).to(device=dev, dtype=dt)

    ij = (rand(samples, 2) * n).long().clamp(max=n - 1)
    radius = radius_range[0] + rand(samples) * (radius_range[1] - radius_range[0])
    p, q = pts[ij[:, 0]], pts[ij[:, 1]]
    a = p + radius[:, None] * p / p.norm(dim=-1, keepdim=True)
    b = q + radius[:, None] * q / q.norm(dim=-1, keepdim=True)

    def project(x):
        return torch.stack(
            [intr.fx * x[:, 0] / x[:, 2] + intr.cx, intr.fy * x[:, 1] / x[:, 2] + intr.cy], -1
        )

    a2, b2 = project(a), project(b)  # (S, 2)
    r_px = radius * intr.fx / (0.5 * (a[:, 2] + b[:, 2]))
    seg = b2 - a2
    len2 = (seg * seg).sum(-1).clamp_min(1e-9)
    rel = grid[None] - a2[:, None]  # (S, P, 2)
    t = (rel * seg[:, None]).sum(-1) / len2[:, None]
    perp = (rel[..., 0] * seg[:, None, 1] - rel[..., 1] * seg[:, None, 0]).abs() / len2[
        :, None
    ].sqrt()
    inside = (t >= 0) & (t <= 1) & (perp <= r_px[:, None])
    n_in = (inside & is_bone[None]).sum(-1)
    n_out = (inside & ~is_bone[None]).sum(-1)
    score = (n_in - n_out).to(dt)
    score = torch.where(len2 > 4.0, score, torch.full_like(score, -1e9))  # degenerate pairs
    best = int(score.argmax())

    # Refit on the winner's inliers: bone pixels in its band (grown a little for the caps).
    rel = project(pts) - a2[best]
    tb = (rel * seg[best]).sum(-1) / len2[best]
    pb = (rel[:, 0] * seg[best, 1] - rel[:, 1] * seg[best, 0]).abs() / len2[best].sqrt()
    inl = (tb >= -0.25) & (tb <= 1.25) & (pb <= 1.5 * r_px[best])
    x = pts[inl] if int(inl.sum()) >= min_pixels else pts
    centre = x.mean(0)
    if axis is None:
        cov = (x - centre).T @ (x - centre)
        axis_dir = torch.linalg.eigh(cov)[1][:, -1]
    else:
        axis_dir = axis.to(x) / axis.to(x).norm()
    view = centre / centre.norm()
    lateral = torch.linalg.cross(axis_dir, view)
    lateral = lateral / lateral.norm().clamp_min(1e-9)
    s_ax = (x - centre) @ axis_dir
    lat = (x - centre) @ lateral
    lo, hi = torch.quantile(s_ax, extent_quantile), torch.quantile(s_ax, 1.0 - extent_quantile)
    spread = (lat - lat.median()).abs()
    radius_fit = float(torch.quantile(spread, radius_quantile) / radius_quantile)
    push = radius_fit * view
    start, end = centre + lo * axis_dir + push, centre + hi * axis_dir + push
    return CylinderFit(True, start, end, radius_fit, float(hi - lo), float(score[best]))
