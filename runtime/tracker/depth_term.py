"""Depth image term (Wei eq. 4, 9 and its linearization eq. 15) over G = R - B1 - B2.

At a fixed pixel the rendered depth changes with q both because the surface point moves in
depth and because the surface slides across the pixel (Wei's ``grad D_render dx/dp`` part).
Both are captured exactly by the rendered surface's tangent plane: a rigid displacement dp
of the point with unit normal n changes the depth along the pixel's ray d (d_z = 1) by
``n . dp / n . d``. The image gradient of Wei's formula is thus replaced by its analytic
value from the ray-caster's normal, which is noise-free and defined up to the silhouette.

The residual is measured along the normal (depth difference times the cosine of the viewing
angle, as in point-to-plane ICP): at grazing angles, where a small lateral error makes a
large depth difference and sensor depth is least reliable, pixels weigh less; pixels beyond
``MIN_COSINE`` are skipped.
"""

from __future__ import annotations

import torch
from depthmocap.runtime.raycast import BodyRender, surface_normals
from depthmocap.shared.compiled import compiled_float32

from .config import TrackerConfig
from .gauss_newton import Rows
from .observation import Observation
from .regions import Regions, rendered_points, sample_pixels

__all__ = ["MAX_DEPTH_PIXELS", "MIN_COSINE", "depth_rows", "depth_error_sum"]

# At most this many G pixels per iteration (a strided subsample), for speed: the rows' cost
# grows with their number. Each kept pixel is weighed for the ones it stands for, so the cap
# does not shift the balance between the terms.
MAX_DEPTH_PIXELS = 1200
# Pixels seen at grazing angles (|cos| of the viewing angle below this) are skipped: there a
# small lateral error makes a large depth difference and the sensor's depth is least reliable.
MIN_COSINE = 0.2


def depth_rows(render: BodyRender, obs: Observation, regions: Regions, cfg: TrackerConfig) -> Rows:
    """Linearized depth-term rows for (a strided subsample of) the pixels in G."""
    kernel = compiled_float32("depthmocap.runtime.tracker.depth_kernel", render.depth)
    if render.normals is None and kernel is not None:  # one compiled call, the same rows
        return Rows(
            *kernel.depth_rows_cpu(
                render, obs, regions, MAX_DEPTH_PIXELS, MIN_COSINE, cfg.sigma_depth_m
            )
        )
    idx, _, ratio = sample_pixels(regions.good, MAX_DEPTH_PIXELS)
    points, segment = rendered_points(render, idx, obs.intr)
    b, v, u = idx.unbind(1)
    normal = (
        render.normals[b, v, u]
        if render.normals is not None
        else surface_normals(render, idx, points)
    )
    ray_len = points.norm(dim=-1) / points[:, 2].clamp_min(1e-9)  # |d| with d_z = 1
    cosine = (normal * points).sum(-1) / points.norm(dim=-1).clamp_min(1e-9)  # < 0: facing
    keep = cosine.abs() >= MIN_COSINE
    weight = keep.to(points.dtype) * (ratio**0.5 / cfg.sigma_depth_m).to(points.dtype)
    # d(depth)/dp = n / (n . d); scaled by |cos| = -(n . d) / |d|: g = -n / |d|.
    direction = -normal / ray_len[:, None]
    residual = regions.depth_diff[b, v, u] * cosine.abs()
    return Rows(idx[:, 0], points, segment, direction, residual, weight)


def depth_error_sum(regions: Regions) -> tuple[torch.Tensor, torch.Tensor]:
    """Sum of |observed - rendered depth| over G (metres) and the pixel count, per batch."""
    err = (regions.depth_diff.abs() * regions.good).sum((1, 2))
    return err, regions.good.sum((1, 2))
