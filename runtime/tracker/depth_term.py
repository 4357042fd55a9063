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
from depthmocap.shared import skeleton as sk
from depthmocap.shared.compiled import compiled_float32

from .config import TrackerConfig
from .gauss_newton import Rows
from .observation import Observation
from .regions import Regions, rendered_points, sample_pixels

__all__ = [
    "HIDDEN_BY_LABEL_M",
    "MAX_DEPTH_PIXELS",
    "MIN_COSINE",
    "TORSO_LABEL_SEGMENTS",
    "depth_rows",
    "depth_error_sum",
]

# At most this many G pixels per iteration (a strided subsample), for speed: the rows' cost
# grows with their number. Each kept pixel is weighed for the ones it stands for, so the cap
# does not shift the balance between the terms.
MAX_DEPTH_PIXELS = 1200
# Pixels seen at grazing angles (|cos| of the viewing angle below this) are skipped: there a
# small lateral error makes a large depth difference and the sensor's depth is least reliable.
MIN_COSINE = 0.2
# A limb rendered on a pixel the forest labels as the torso or head is pushed this far behind
# the observed surface there (m; 0: off), instead of onto it: a hidden arm or leg laid flush on
# the torso fits the depth exactly, and only the labels say it is not there. Behind the
# surface it is hidden, where the camera cannot see it either.
HIDDEN_BY_LABEL_M = 0.05
# The labels (segments) that hide a limb: abdomen, chest and head. Not the pelvis, neck or
# clavicles, where the thighs and upper arms attach and their pixels meet.
TORSO_LABEL_SEGMENTS = (1, 2, 4)
# ... and only where no pixel within this many working pixels is labelled as any limb: at a
# limb's border with the torso (an elbow touching the knee in front of the belly) the labels
# blur, and the limb's own pixels there must not push it away.
HIDDEN_CLEAR_PX = 2


def depth_rows(render: BodyRender, obs: Observation, regions: Regions, cfg: TrackerConfig) -> Rows:
    """Linearized depth-term rows for (a strided subsample of) the pixels in G."""
    kernel = compiled_float32("depthmocap.runtime.tracker.depth_kernel", render.depth)
    if render.normals is None and kernel is not None:  # one compiled call, the same rows
        return Rows(
            *kernel.depth_rows_cpu(
                render, obs, regions, MAX_DEPTH_PIXELS, MIN_COSINE, cfg.sigma_depth_m,
                HIDDEN_BY_LABEL_M, TORSO_LABEL_SEGMENTS, HIDDEN_CLEAR_PX,
            )
        )  # fmt: skip
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
    diff = regions.depth_diff[b, v, u]
    if HIDDEN_BY_LABEL_M > 0 and obs.labels is not None:
        torso = torch.as_tensor(TORSO_LABEL_SEGMENTS, device=segment.device)
        hidden = (segment >= sk.FIRST_LIMB_SEGMENT) & torch.isin(obs.labels[b, v, u], torso)
        if HIDDEN_CLEAR_PX > 0:
            r = HIDDEN_CLEAR_PX
            limb = (obs.labels >= sk.FIRST_LIMB_SEGMENT).to(diff.dtype)[:, None]
            near = torch.nn.functional.max_pool2d(limb, 2 * r + 1, stride=1, padding=r)[:, 0]
            hidden = hidden & (near[b, v, u] == 0)
        diff = torch.where(hidden, diff + HIDDEN_BY_LABEL_M, diff)
    residual = diff * cosine.abs()
    return Rows(idx[:, 0], points, segment, direction, residual, weight)


def depth_error_sum(regions: Regions) -> tuple[torch.Tensor, torch.Tensor]:
    """Sum of |observed - rendered depth| over G (metres) and the pixel count, per batch."""
    err = (regions.depth_diff.abs() * regions.good).sum((1, 2))
    return err, regions.good.sum((1, 2))
