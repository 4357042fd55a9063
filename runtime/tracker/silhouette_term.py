"""Silhouette image term (Wei eq. 6, 11 and its linearization eq. 16).

Wei evaluates ``S - S_render`` where the rendered silhouette's image gradient is non-zero,
i.e. on the rendered silhouette's boundary. With binary images that residual carries no
information about *how far* the boundary is off; here the observed silhouette's distance
transform takes the place of S: each rendered boundary pixel x whose surface point lies
outside the observed silhouette has residual ``-dist_O(x)`` (working pixels), and moves by
``grad dist_O . dx/dp . dp/dq``. Boundary pixels inside O have zero residual and zero gradient,
so, like Wei's term, it only pulls the rendered silhouette in where it spills over the
observed one; the opposite case (observed foreground the rendering misses) is the extra
depth term's type 2.
"""

from __future__ import annotations

import torch
from depthmocap.runtime.raycast import BodyRender
from depthmocap.shared.compiled import compiled_float32

from .config import TrackerConfig
from .gauss_newton import Rows
from .observation import Observation
from .regions import rendered_points, sample_pixels

__all__ = [
    "MAX_SILHOUETTE_PIXELS",
    "SILHOUETTE_DEADZONE_PX",
    "silhouette_boundary",
    "silhouette_rows",
]

# At most this many rendered boundary pixels per iteration (a strided subsample), for speed;
# each kept pixel is weighed for the ones it stands for, so the cap does not shift the
# balance between the terms.
MAX_SILHOUETTE_PIXELS = 600
# The residual is the distance to the observed silhouette minus this (working pixels, >= 0):
# pixel-centre distances overstate the distance to the boundary, which runs between pixels,
# and an edge within half a pixel is as aligned as the image can tell.
SILHOUETTE_DEADZONE_PX = 0.5


def silhouette_boundary(mask: torch.Tensor) -> torch.Tensor:
    """Foreground pixels with a background 4-neighbour (image borders count as background)."""
    p = torch.nn.functional.pad(mask, (1, 1, 1, 1))
    inner = p[:, :-2, 1:-1] & p[:, 2:, 1:-1] & p[:, 1:-1, :-2] & p[:, 1:-1, 2:]
    return mask & ~inner


def silhouette_rows(render: BodyRender, obs: Observation, cfg: TrackerConfig) -> Rows:
    """Rows for the rendered boundary pixels that lie outside the observed silhouette."""
    kernel = compiled_float32("depthmocap.runtime.tracker.silhouette_kernel", render.depth)
    if kernel is not None:  # one compiled call, the same rows
        return Rows(
                *kernel.silhouette_rows_cpu(
                    render, obs, MAX_SILHOUETTE_PIXELS, SILHOUETTE_DEADZONE_PX,
                    cfg.sigma_silhouette_px,
                )
            )  # fmt: skip
    outside = silhouette_boundary(render.mask) & (obs.distance > 0)
    idx, _, ratio = sample_pixels(outside, MAX_SILHOUETTE_PIXELS)
    points, segment = rendered_points(render, idx, obs.intr)
    b, v, u = idx.unbind(1)
    dist = obs.distance[b, v, u]
    grad = obs.distance_grad[b, v, u]  # (N, 2) per pixel along (u, v)
    x, y, z = points.unbind(-1)
    inv_z = 1.0 / z.clamp_min(1e-6)
    fx, fy = obs.intr.fx, obs.intr.fy
    # d(dist)/dp = grad_u * du/dp + grad_v * dv/dp with the pinhole projection's derivatives.
    gu, gv = grad[:, 0] * fx * inv_z, grad[:, 1] * fy * inv_z
    direction = torch.stack([gu, gv, -(gu * x + gv * y) * inv_z], -1)
    weight = (ratio**0.5 / cfg.sigma_silhouette_px).to(dist.dtype)
    residual = -(dist - SILHOUETTE_DEADZONE_PX).clamp_min(0)
    return Rows(b, points, segment, direction, residual, weight)
