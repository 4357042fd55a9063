"""Body ray-caster: depth, silhouette, segment index and surface coordinates of the cylinder model.

The tracker (Wei section 3, step 1-2 of the optimization) renders the body at the current pose
and needs, per pixel, which segment it sees and where on that segment (``p0`` of
``p = f(q; k, p0)``), so that the analytic point Jacobian applies. Wei reads these from
OpenGL's selection buffer; here every pixel's ray is intersected analytically with every
segment's quadric, batched over poses x segments x pixels.

Geometry of segment k (see :mod:`shared.body`): an elliptic cylinder with semi-axes
``radii[k]`` along ``cross_section_axes()[k]``, spanning ``-extents[k, 0]`` to
``lengths[k] + extents[k, 1]`` along ``SEGMENT_AXIS[k]``, closed by half-ellipsoid caps with
the same cross-section and axial semi-axis ``cap = CAP_FRACTION[k] * min(radii[k])``, its axis
moved off the joint axis by ``offsets[k]`` (local coordinates of hits stay joint-relative):

- at a *joint end* (where another segment attaches: every lower end except the root's, and
  upper ends with children) the cap is centred on the end of the cylinder and bulges
  ``cap`` beyond it, so consecutive segments overlap and joints bend without gaps;
- at a *free end* (pelvis bottom, top of the head, hands, feet) the cap is inset so the
  geometry ends exactly at the body's stated extent and the stature stays as documented.

Limbs use hemispherical caps (``CAP_FRACTION = 1``): capsules. The torso's elliptic segments use
shallow caps (0.3) so the chest stays roughly flat at the shoulder line. In coordinates scaled
by ``1 / (r1, r2, cap)`` each segment is a unit-radius capsule along z, and since that scaling is
affine, the ray parameter t of a hit is the same in both spaces: one closed-form capsule
intersection per ray and segment (Inigo Quilez's formulation). Rays have ``d_z = 1`` so t is
the metric depth z directly.

Only the pixels each capsule can cover are cast (:mod:`runtime.capsule_pixels`: a
conservative span per row, one host sync); the rest of the image is background. Everything
follows q's device and dtype.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from depthmocap.runtime.capsule_pixels import NEAR as _NEAR
from depthmocap.runtime.capsule_pixels import (
    capsule_ends,
    segment_boxes,
    segment_row_spans,
    span_pairs,
)
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import FOOT_SEGMENTS, BodyShape, cross_section_axes
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.compiled import compiled_module
from depthmocap.shared.kinematics import Kinematics, forward_kinematics
from depthmocap.shared.labels import segment_to_part

__all__ = [
    "CAP_FRACTION",
    "SegmentGeometry",
    "BodyRender",
    "segment_geometry",
    "render_body",
    "render_body_depth",
    "part_labels",
    "surface_normals",
    "surface_local_points",
    "surface_distance",
    "capsule_signed_distance",
]

# Axial semi-axis of each segment's end caps, as a fraction of its smaller cross-section radius.
CAP_FRACTION = np.array([0.3, 0.3, 0.3] + [1.0] * 12)

# Upper end has a child attached (a joint end); lower ends are joint ends except the root's.
_HAS_CHILD_AT_END = np.zeros(sk.NUM_SEGMENTS, dtype=bool)
for _k, _p in enumerate(sk.SEGMENT_PARENT):
    if _p >= 0 and sk.SEGMENT_ATTACH_END[_k] > 0.5:
        _HAS_CHILD_AT_END[_p] = True
_LOWER_IS_FREE = sk.SEGMENT_PARENT < 0


@dataclass
class SegmentGeometry:
    """Capsule parameters of the body's P primitives (15 segments, then the 2 feet) in the local
    frames of the segments they ride on.

    Attributes:
        basis: (P, 3, 3) rows: first and second cross-section axis, capsule axis (local frame).
        scale: (..., P, 3) semi-axes (r1, r2, cap), metres.
        span: (..., P, 2) axial positions of the two cap centres (metres along the axis).
        centre: (..., P, 3) the capsule axis's offset from the segment origin, local frame.
        segment: (P,) int64 segment each primitive is rigid with.
    """

    basis: torch.Tensor
    scale: torch.Tensor
    span: torch.Tensor
    centre: torch.Tensor
    segment: torch.Tensor

    def frames(self, kin: Kinematics) -> tuple[torch.Tensor, torch.Tensor]:
        """Rotation (B, P, 3, 3) and camera-frame axis point at span 0 (B, P, 3) per primitive.

        The last answer is kept for its ``kin``: a tracker iteration asks for the frames of
        one pose batch in the ray-caster and again in two of its terms."""
        last = self.__dict__.get("_frames_of")
        if last is not None and last[0] is kin:
            return last[1]
        B = kin.origins.shape[0]
        rot = kin.rotations[:, self.segment]
        origin = kin.origins[:, self.segment]
        frames = rot, origin + (rot @ self.centre.expand(B, -1, -1)[..., None])[..., 0]
        self.__dict__["_frames_of"] = (kin, frames)
        return frames


@dataclass
class BodyRender:
    """What the ray-caster sees for B poses on an H x W image.

    Attributes:
        depth: (B, H, W) metric z of the nearest hit, 0 where the ray misses the body.
        mask: (B, H, W) bool, the rendered silhouette.
        segment: (B, H, W) int64 segment hit, -1 on background.
        local_points: (B, H, W, 3) hit point in the hit segment's frame (0 on background);
            None when rendered without details (see :func:`surface_normals` instead).
        normals: (B, H, W, 3) unit outward surface normal in camera frame (0 on background);
            None when rendered without details.
        kin: forward kinematics of the poses (reused by the tracker for Jacobians).
        primitive: (B, H, W) int64 primitive hit (segments, then feet), -1 on background.
        geom: the primitives' geometry; rot, origin: their frames
            (:meth:`SegmentGeometry.frames`), for details at chosen pixels.
    """

    depth: torch.Tensor
    mask: torch.Tensor
    segment: torch.Tensor
    local_points: torch.Tensor | None
    normals: torch.Tensor | None
    kin: Kinematics
    primitive: torch.Tensor
    geom: SegmentGeometry
    rot: torch.Tensor
    origin: torch.Tensor


def segment_geometry(body: BodyShape, like: torch.Tensor) -> SegmentGeometry:
    """Capsule parameters of ``body`` (unbatched or batched) in ``like``'s dtype/device."""
    dtype, device = like.dtype, like.device
    axes = torch.as_tensor(cross_section_axes(), dtype=dtype, device=device)  # (15, 2, 3)
    seg_axis = torch.as_tensor(sk.SEGMENT_AXIS, dtype=dtype, device=device)
    radii = body.radii.to(dtype=dtype, device=device)
    lengths = body.lengths.to(dtype=dtype, device=device)
    ext = body.extents.to(dtype=dtype, device=device)
    frac = torch.as_tensor(CAP_FRACTION, dtype=dtype, device=device)
    cap = frac * radii.min(-1).values
    lower_free = torch.as_tensor(_LOWER_IS_FREE, device=device)
    upper_free = torch.as_tensor(~_HAS_CHILD_AT_END, device=device)
    lo = -ext[..., 0] + torch.where(lower_free, cap, torch.zeros_like(cap))
    hi = lengths + ext[..., 1] - torch.where(upper_free, cap, torch.zeros_like(cap))
    hi = torch.maximum(hi, lo)
    centre = torch.einsum("...ki,kij->...kj", body.offsets.to(dtype=dtype, device=device), axes)
    # Feet: capsules along the shank frame's forward axis (local z), lying on the sole (the
    # shank's end) from the shank axis to the toe tip; cross-sections along local x and y.
    feet = body.feet.to(dtype=dtype, device=device)  # (..., 2, 2)
    fs = torch.as_tensor(FOOT_SEGMENTS, device=device)
    r_f = feet[..., 1]
    sole = lengths[..., fs] + ext[..., fs, 1] - r_f  # along the shank axis
    foot_centre = sole[..., None] * seg_axis[fs] + centre[..., fs, :]
    foot_span = torch.stack([torch.zeros_like(r_f), (feet[..., 0] - r_f).clamp_min(0)], -1)
    eye = torch.eye(3, dtype=dtype, device=device)
    basis = torch.cat([torch.cat([axes, seg_axis[:, None]], 1), eye.expand(2, 3, 3)], 0)
    scale = torch.cat(
        [torch.cat([radii, cap[..., None]], -1), r_f[..., None].expand(*r_f.shape, 3)], -2
    )
    span = torch.cat([torch.stack([lo, hi], -1), foot_span], -2)
    segment = torch.cat([torch.arange(sk.NUM_SEGMENTS, device=device), fs])
    return SegmentGeometry(basis, scale, span, torch.cat([centre, foot_centre], -2), segment)


def _cast(
    rays: torch.Tensor,
    seg: torch.Tensor,
    rot: torch.Tensor,
    origin: torch.Tensor,
    geom: SegmentGeometry,
) -> torch.Tensor:
    """Ray parameter (= depth) of each ray's hit with one segment's capsule.

    Args:
        rays: (P, 3) ray directions with z = 1 (from the camera centre).
        seg: (P,) segment to intersect.
        rot, origin: the primitives' frames, :meth:`SegmentGeometry.frames`.
    Returns:
        (B, P) depth, inf where the ray misses.
    """
    B, K = origin.shape[:2]
    # World -> scaled local: xi = diag(1/scale) @ basis @ R^T @ (x - o). One table row per
    # (pose, segment), gathered once per pair: 9 matrix entries, camera centre, cap centres.
    m = (geom.basis @ rot.transpose(-1, -2)) / geom.scale.expand(B, -1, -1)[..., None]
    o = -(m @ origin[..., None])[..., 0]  # (B, K, 3): camera centre in scaled space
    zab = (geom.span / geom.scale[..., 2:]).expand(B, -1, -1)
    table = torch.cat([m.reshape(B, K, 9), o, zab], -1)  # (B, K, 14)
    # Channel-first gather: every component below is a contiguous (B, P) tensor. Transposing
    # the small table first makes the gather write channel-first rows directly; on CPU
    # ``gather`` with an expanded index is 5x faster here than ``index_select`` on dim 2.
    chan = table.permute(2, 0, 1).contiguous()
    row = torch.gather(chan, 2, seg.expand(chan.shape[0], B, -1))  # (14, B, P)
    rx, ry, rz = rays.unbind(-1)
    dx = row[0] * rx + row[1] * ry + row[2] * rz
    dy = row[3] * rx + row[4] * ry + row[5] * rz
    dz = row[6] * rx + row[7] * ry + row[8] * rz
    ox, oy, oz, za, zb = row[9:].unbind(0)

    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    c = ox * ox + oy * oy - 1.0
    h = b * b - a * c
    t_cyl = (-b - h.clamp_min(0).sqrt()) / a.clamp_min(1e-12)
    z = oz + t_cyl * dz
    on_body = (z >= za) & (z <= zb)
    # Otherwise the ray enters through the cap on the side where it met the infinite cylinder.
    oc_z = oz - torch.where(z < za, za, zb)
    a_s = a + dz * dz
    b_s = b + oc_z * dz
    c_s = c + oc_z * oc_z
    h_s = b_s * b_s - a_s * c_s
    t_cap = (-b_s - h_s.clamp_min(0).sqrt()) / a_s
    t = torch.where(on_body, t_cyl, t_cap)
    hit = (h >= 0) & (on_body | (h_s >= 0)) & (t > _NEAR)
    return torch.where(hit, t, torch.full_like(t, float("inf")))


def _primitive_frames(
    render: BodyRender, idx: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pose index, primitive, rotation (N, 3, 3) and axis point (N, 3) at pixels (b, v, u)."""
    b, v, u = idx.unbind(1)
    prim = render.primitive[b, v, u].clamp_min(0)
    return b, prim, render.rot[b, prim], render.origin[b, prim]


def surface_normals(render: BodyRender, idx: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Camera-frame unit outward normals (N, 3) of rendered surface points at chosen pixels.

    Args:
        idx: (N, 3) int64 pixels (b, v, u) on the rendered silhouette.
        points: (N, 3) their camera-frame surface points (depth times the pixel's ray).
    """
    b, prim, rot, origin = _primitive_frames(render, idx)
    geom = render.geom
    B = render.rot.shape[0]
    # Camera -> section coordinates (r1-direction, r2-direction, axial), metres: c = A (p - o).
    a_mat = geom.basis[prim] @ rot.transpose(-1, -2)
    coords = (a_mat @ (points - origin)[..., None])[..., 0]
    span = geom.span.expand(B, -1, -1)[b, prim]
    scale = geom.scale.expand(B, -1, -1)[b, prim]
    axial = coords[:, 2] - torch.minimum(torch.maximum(coords[:, 2], span[:, 0]), span[:, 1])
    grad = torch.stack([coords[:, 0], coords[:, 1], axial], -1) / (scale * scale)
    normals = (a_mat.transpose(-1, -2) @ grad[..., None])[..., 0]
    return normals / normals.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def surface_local_points(
    render: BodyRender, idx: torch.Tensor, points: torch.Tensor
) -> torch.Tensor:
    """Rendered surface points (N, 3) at pixels ``idx`` in their segment's frame (a foot's in
    its shank's): ``R^T (p - o)`` plus the primitive's offset from the segment origin."""
    b, prim, rot, origin = _primitive_frames(render, idx)
    centre = render.geom.centre.expand(render.rot.shape[0], -1, -1)[b, prim]
    return ((points - origin)[:, None, :] @ rot)[:, 0] + centre


def _compiled_kernel():
    """:mod:`runtime.raycast_kernel` (numba's compiled z-buffer and capsule distances), or
    None without numba."""
    return compiled_module("depthmocap.runtime.raycast_kernel")


def _zbuffer_torch(
    rot: torch.Tensor, origin: torch.Tensor, geom: SegmentGeometry, intr: Intrinsics, box: bool
) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth (B, H, W) (0: background) and primitive (B, H, W) int64 (-1: background): every
    candidate (pixel, primitive) pair cast, the nearest hit kept by two scatters."""
    B, H, W = origin.shape[0], intr.height, intr.width
    dtype, device = origin.dtype, origin.device
    if box:
        ends = capsule_ends(rot, origin, geom.basis[:, 2], geom.span, geom.scale)
        first, count = segment_row_spans(*ends, intr, segment_boxes(*ends, intr))
    else:
        first = torch.zeros(geom.segment.shape[0], H, dtype=torch.long, device=device)
        count = torch.full_like(first, W)
    pix, pseg, col, row = span_pairs(first, count, W)  # pseg: primitive of each pair
    rays = torch.stack(
        [
            (col.to(dtype) - intr.cx) / intr.fx,
            (row.to(dtype) - intr.cy) / intr.fy,
            torch.ones(col.shape, dtype=dtype, device=device),
        ],
        -1,
    )
    t = _cast(rays, pseg, rot, origin, geom)  # (B, P)
    inf = torch.full((B, H * W), float("inf"), dtype=dtype, device=device)
    zbuf = inf.scatter_reduce(1, pix.expand(B, -1), t, "amin")
    # Winner per pixel: the pair whose depth equals the z-buffer (ties: any of them).
    won = (t == zbuf.index_select(1, pix)) & torch.isfinite(t)
    prim = torch.full((B, H * W), -1, dtype=torch.long, device=device)
    flat_prim = torch.where(won, pseg.expand(B, -1), torch.full_like(t, -1, dtype=torch.long))
    prim = prim.scatter_reduce(1, pix.expand(B, -1), flat_prim, "amax")
    depth = torch.where(prim >= 0, zbuf, torch.zeros_like(zbuf)).reshape(B, H, W)
    prim = prim.reshape(B, H, W)
    return depth, prim


def render_body(
    q: torch.Tensor,
    body: BodyShape,
    intr: Intrinsics,
    kin: Kinematics | None = None,
    box: bool = True,
    geom: SegmentGeometry | None = None,
    details: bool = True,
) -> BodyRender:
    """Ray-cast the cylinder model at poses ``q``.

    Args:
        q: (B, 34) poses in camera frame.
        body: body parameters (unbatched or batch B).
        intr: intrinsics of the output image (H x W = intr.height x intr.width).
        kin: forward kinematics of ``q`` if already computed.
        box: cast only the pixels each capsule can cover (same result, faster); False casts
            every pixel against every primitive.
        geom: ``segment_geometry(body, q)`` if already computed (a tracker renders one body
            many times per frame).
        details: also compute every pixel's local point and normal; the tracker needs
            normals at a few pixels only (:func:`surface_normals`).
    Returns:
        :class:`BodyRender` with tensors on q's device, depth/points in q's dtype.
    """
    if q.dim() != 2 or q.shape[-1] != sk.NUM_DOFS:
        raise ValueError(f"q must have shape (B, {sk.NUM_DOFS}), got {tuple(q.shape)}")
    kin = forward_kinematics(q, body) if kin is None else kin
    geom = segment_geometry(body, q) if geom is None else geom
    rot, origin = geom.frames(kin)
    B, H, W = q.shape[0], intr.height, intr.width
    kernel = _compiled_kernel() if box and q.device.type == "cpu" else None
    if kernel is not None:  # the segments too, in the same loop
        depth, prim, segment = kernel.zbuffer_cpu(
            rot, origin, geom.basis, geom.scale, geom.span, intr, _NEAR, geom.segment
        )
    else:
        depth, prim = _zbuffer_torch(rot, origin, geom, intr, box)
        seg_of = geom.segment.index_select(0, prim.clamp_min(0).reshape(-1)).reshape(prim.shape)
        segment = torch.where(prim >= 0, seg_of, prim)
    lean = BodyRender(depth, segment >= 0, segment, None, None, kin, prim, geom, rot, origin)
    if not details:
        return lean
    # Surface coordinates and normals of the hit pixels (everything else is background).
    idx = lean.mask.nonzero()
    b, v, u = idx.unbind(1)
    ray = torch.stack(
        [(u.to(q.dtype) - intr.cx) / intr.fx, (v.to(q.dtype) - intr.cy) / intr.fy], -1
    )
    pts = depth[b, v, u, None] * torch.cat([ray, torch.ones_like(ray[:, :1])], -1)
    local = q.new_zeros(B, H, W, 3)
    normals = q.new_zeros(B, H, W, 3)
    local[b, v, u] = surface_local_points(lean, idx, pts)
    normals[b, v, u] = surface_normals(lean, idx, pts)
    return BodyRender(depth, segment >= 0, segment, local, normals, kin, prim, geom, rot, origin)


def render_body_depth(q: torch.Tensor, body: BodyShape, intr: Intrinsics) -> torch.Tensor:
    """Depth image (B, H, W) of the cylinder model at poses ``q``, metres, 0 = background."""
    return render_body(q, body, intr).depth


def part_labels(render: BodyRender, body: BodyShape) -> torch.Tensor:
    """Exact part labels (B, H, W) int64 (:mod:`shared.labels`, 0 = background) of a render with
    details of the unbatched ``body``: each pixel's segment, split at half its length where the
    segment carries two parts."""
    seg = render.segment
    axis = torch.as_tensor(sk.SEGMENT_AXIS, dtype=render.local_points.dtype)[seg.clamp_min(0)]
    frac = (render.local_points * axis).sum(-1) / body.lengths[seg.clamp_min(0)]
    return torch.from_numpy(segment_to_part(seg.numpy(), frac.numpy()).astype(np.int64))


def segment_distances(
    points: torch.Tensor,
    kin: Kinematics,
    body: BodyShape,
    geom: SegmentGeometry | None = None,
) -> torch.Tensor:
    """Signed distance of camera-frame points to each of the model's P primitives: (B, N, P),
    > 0 outside.

    Per primitive the distance is measured along the line from the point to its nearest point
    on the capsule's axis: exact for circular sections and spherical caps, an upper bound for
    the elliptic torso. ``geom``: ``segment_geometry(body, points)`` if already computed.
    """
    geom = segment_geometry(body, points) if geom is None else geom
    B = points.shape[0]
    rot, origin = geom.frames(kin)
    kernel = _compiled_kernel() if points.device.type == "cpu" else None
    inputs = (points, rot, origin, geom.span, geom.scale)
    if kernel is not None and not (
        torch.is_grad_enabled() and any(t.requires_grad for t in inputs)
    ):  # the compiled loop has no autograd
        return kernel.segment_distances_cpu(points, rot, origin, geom.basis, geom.span, geom.scale)
    rel = points[:, :, None, :] - origin[:, None]  # (B, N, P, 3)
    local = (rel[..., None, :] @ rot[:, None])[..., 0, :]
    coords = torch.einsum("kij,bnkj->bnki", geom.basis, local)
    span = geom.span.expand(B, -1, -1)[:, None]
    scale = geom.scale.expand(B, -1, -1)[:, None]
    signed, _ = capsule_signed_distance(coords, span, scale)
    return signed


def surface_distance(
    points: torch.Tensor,
    kin: Kinematics,
    body: BodyShape,
    geom: SegmentGeometry | None = None,
) -> torch.Tensor:
    """Approximate distance of camera-frame points to the model surface: (B, N).

    The union's signed distance is the minimum over :func:`segment_distances`; its absolute
    value is returned (points inside the body count by their depth inside).
    """
    return segment_distances(points, kin, body, geom).min(-1).values.abs()


def capsule_signed_distance(
    coords: torch.Tensor, span: torch.Tensor, scale: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Signed distance of points to capsules from the points' capsule coordinates.

    Measured along the line from the point to its nearest point on the capsule's axis:
    exact for circular sections and spherical caps, an upper bound for elliptic ones.

    Args:
        coords: (..., 3) the points along the capsule's two cross-section axes and its axis
            (:class:`SegmentGeometry` ``basis`` rows, from the span-0 axis point).
        span, scale: (..., 2), (..., 3) the capsule's ``span`` and ``scale`` (broadcast).
    Returns:
        signed (...) metres, > 0 outside; the offset (..., 3) from the nearest axis point, in
        the same coordinates.
    """
    axial = coords[..., 2] - coords[..., 2].clamp(span[..., 0], span[..., 1])
    offset = torch.stack([coords[..., 0], coords[..., 1], axial], -1)
    length = offset.norm(dim=-1)
    rho = (offset / scale).norm(dim=-1)
    return length * (1.0 - 1.0 / rho.clamp_min(1e-9)), offset
