"""Correspondences of the shape fit (:mod:`.fit`): the model vertices the camera sees, closest
pairs both ways between them and the observed points, and the residuals of the pairs
(point-to-plane within tau, point-to-point beyond) with their Jacobian."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from depthmocap.shared.camera import Intrinsics

__all__ = ["Pairs", "closest_pairs", "residual_jacobian", "residuals", "visible_vertices"]


def visible_vertices(
    verts: torch.Tensor, normals: torch.Tensor, intr: Intrinsics | None, margin: float
) -> torch.Tensor:
    """(V,) vertices facing the camera and not behind nearer vertices of the same mesh."""
    facing = (normals * verts).sum(-1) < 0.0
    if intr is None:
        return facing
    # Z-buffer at half resolution: model vertices are about 1-2 cm apart, so the splat is dense.
    w, h = max(intr.width // 2, 1), max(intr.height // 2, 1)
    z = verts[:, 2].clamp_min(1e-6)
    u = ((intr.fx * verts[:, 0] / z + intr.cx) * w / intr.width).round().long()
    v = ((intr.fy * verts[:, 1] / z + intr.cy) * h / intr.height).round().long()
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    pix = v.clamp(0, h - 1) * w + u.clamp(0, w - 1)
    zbuf = torch.full((w * h,), math.inf, dtype=z.dtype).scatter_reduce(
        0, pix[inside], z[inside], "amin"
    )
    return facing & (~inside | (z <= zbuf[pix] + margin))


@dataclass
class Pairs:
    """Correspondences of one view: model vertex, observed point, normal, plane/point, weight."""

    vertex: torch.Tensor  # (P,) index into the view's active vertex list
    target: torch.Tensor  # (P, 3)
    normal: torch.Tensor  # (P, 3)
    plane: torch.Tensor  # (P,) bool
    weight: torch.Tensor  # (P,)


def closest_pairs(
    posed: torch.Tensor,
    normals: torch.Tensor,
    visible: torch.Tensor,
    cloud: torch.Tensor,
    count: int,
    gate: float,
    tau: float,
    gen: torch.Generator,
    observable: torch.Tensor,
) -> tuple[torch.Tensor, Pairs]:
    """Closest-point pairs both ways; returns the active vertex ids (A,) and the pairs.

    Model-to-data pairs start only at ``observable`` visible vertices (not in the floor band
    that segmentation removed from the data); data-to-model pairs may end at any visible one.
    """
    vis = visible.nonzero()[:, 0]
    sources = (visible & observable).nonzero()[:, 0]
    m_pick = sources[torch.randperm(len(sources), generator=gen)[:count]]
    d_pick = torch.randperm(len(cloud), generator=gen)[:count]
    # model -> data
    # (float32 distances: twice as fast, and mm-accurate is all the search needs)
    p32, c32 = posed.float(), cloud.float()
    _, j1 = torch.cdist(p32[m_pick], c32).min(1)
    # data -> model (nearest visible vertex)
    _, j2 = torch.cdist(c32[d_pick], p32[vis]).min(1)
    d1 = (posed[m_pick] - cloud[j1]).norm(dim=-1)
    d2 = (cloud[d_pick] - posed[vis[j2]]).norm(dim=-1)
    verts = torch.cat([m_pick, vis[j2]])
    targets = torch.cat([cloud[j1], cloud[d_pick]])
    dist = torch.cat([d1, d2])
    keep = dist < gate
    n1, n2 = int((keep[: len(m_pick)]).sum()), int((keep[len(m_pick) :]).sum())
    weight = torch.cat(
        [torch.full_like(d1, 1.0 / max(n1, 1)), torch.full_like(d2, 1.0 / max(n2, 1))]
    )
    verts, targets, dist, weight = verts[keep], targets[keep], dist[keep], weight[keep]
    active, local = torch.unique(verts, return_inverse=True)
    return active, Pairs(local, targets, normals[verts], dist <= tau, weight)


def residuals(posed: torch.Tensor, p: Pairs) -> torch.Tensor:
    """(P, 3) residual vectors: normal component within tau, full difference beyond."""
    d = posed[p.vertex] - p.target
    along = (d * p.normal).sum(-1, keepdim=True) * p.normal
    return torch.where(p.plane[:, None], along, d)


def residual_jacobian(jac: torch.Tensor, p: Pairs) -> torch.Tensor:
    """d residual / d params: (P, 3, X) from d posed / d params (A, 3, X)."""
    j = jac[p.vertex]
    along = p.normal[:, :, None] * torch.einsum("pi,pix->px", p.normal, j)[:, None]
    return torch.where(p.plane[:, None, None], along, j)
