"""The body ray-caster's z-buffer, and points' distances to the capsules, as compiled loops
(numba): the CPU path.

Importing this module imports numba (an optional dependency, the ``runtime`` extra);
:func:`runtime.raycast.render_body` imports it lazily and keeps its torch ray-caster for GPUs,
for ``box=False`` and where numba is missing.

Why: the torch ray-caster lists the candidate (pixel, primitive) pairs, casts them all, and
resolves the z-buffer with two scatters: some 300 small ops, about 2 ms per render on the
CPU, once per Gauss-Newton iteration. Here each primitive's conservative pixel box
(:func:`runtime.capsule_pixels.segment_boxes`' bound, per pose) is cast in place against the
z-buffer, each of its rows cut to the band the capsule can cover
(:func:`~runtime.capsule_pixels.segment_row_spans`' bound, per pose: a limb running
diagonally fills a fraction of its box; thirty-third session). The intersection is the same
closed form (Inigo Quilez's capsule in the primitive's scaled frame) in float64; a pixel
where two primitives meet at the same depth to rounding may go to the other one, as in the
torch code's float32. The float64 z-buffer is one
pose's, and only the union of that pose's boxes is cleared and read back: the tracker's window
is several times the person, and whole-image passes were a quarter of a render.

:func:`segment_distances_cpu` is :func:`runtime.raycast.segment_distances` (every point to
every capsule, for the surface-error signal and the arm search's label checks), one pass over
(pose, point, capsule) in registers instead of some twenty (B, N, P, 3) temporaries.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch

__all__ = ["zbuffer_cpu", "segment_distances_cpu"]

# As runtime.capsule_pixels: a capsule this near the camera plane keeps its whole box rows,
# and every row's cut gets this rounding margin (pixels).
_SPAN_MIN_DEPTH = 0.05
_SPAN_SLACK_PX = 1.0


def _f64(t: torch.Tensor, *shape: int) -> np.ndarray:
    """``t`` expanded to ``shape`` as a contiguous float64 array (the kernels' input)."""
    return np.ascontiguousarray(t.detach().to(torch.float64).expand(*shape).numpy())


@numba.njit(inline="always")
def _capsule_frame(basis, rot, m):  # pragma: no cover - compiled
    """m = basis @ rot^T: camera directions to a capsule's (section, section, axis) frame."""
    for i in range(3):
        for j in range(3):
            m[i, j] = basis[i, 0] * rot[j, 0] + basis[i, 1] * rot[j, 1] + basis[i, 2] * rot[j, 2]


@numba.njit(inline="always")
def _pixel_box(
    rot, origin, basis, scale, span, near, fx, fy, cx, cy, H, W, cen
):  # pragma: no cover - compiled
    """(u0, u1, v0, v1), end-exclusive, of the pixels one capsule can cover; empty (u0 >= u1
    or v0 >= v1) when it lies behind the camera or its pose is not a number."""
    # The capsule lies in the hull of two spheres of its largest semi-axis around its cap
    # centres; each sphere's x/z and y/z are extreme at its box corners.
    radius = max(scale[0], max(scale[1], scale[2]))
    ul, uh, vl, vh = np.inf, -np.inf, np.inf, -np.inf
    for e in range(2):
        for i in range(3):
            axis = rot[i, 0] * basis[2, 0] + rot[i, 1] * basis[2, 1] + rot[i, 2] * basis[2, 2]
            cen[i] = origin[i] + span[e] * axis
        far = cen[2] + radius
        if far <= near:
            continue
        close = max(cen[2] - radius, near)
        for s in (-radius, radius):
            for zz in (close, far):
                ul = min(ul, (cen[0] + s) / zz)
                uh = max(uh, (cen[0] + s) / zz)
                vl = min(vl, (cen[1] + s) / zz)
                vh = max(vh, (cen[1] + s) / zz)
    if not (ul <= uh and vl <= vh):
        return 0, 0, 0, 0
    u0 = int(max(math.floor(max(min(ul * fx + cx, 1e6), -1e6)), 0.0))
    u1 = int(min(math.ceil(max(min(uh * fx + cx, 1e6), -1e6)) + 1.0, W))
    v0 = int(max(math.floor(max(min(vl * fy + cy, 1e6), -1e6)), 0.0))
    v1 = int(min(math.ceil(max(min(vh * fy + cy, 1e6), -1e6)) + 1.0, H))
    return u0, u1, v0, v1


@numba.njit(inline="always")
def _row_band(rot, origin, basis, scale, span, fx, fy, cx, cy):  # pragma: no cover - compiled
    """The band of image rows' columns a capsule can cover (:mod:`runtime.capsule_pixels`,
    per pose): its cap centres a, b project to points of the image, the capsule into the
    stadium of radius ``rho = f R max|c| / (z (z - R))`` around the segment between them (R
    the largest semi-axis, z the nearer centre's depth, plus a pixel), and row v's cut of the
    band around the segment's line is ``x_line(v) +- rho L / |dy|``. Returns (tight, u_a,
    v_a, du/dv, half-width); not tight (the whole box row) for a capsule within
    ``_SPAN_MIN_DEPTH`` of the camera plane or a segment along the rows."""
    radius = max(scale[0], max(scale[1], scale[2]))
    ends = np.empty((2, 3))
    for e in range(2):
        for i in range(3):
            axis = rot[i, 0] * basis[2, 0] + rot[i, 1] * basis[2, 1] + rot[i, 2] * basis[2, 2]
            ends[e, i] = origin[i] + span[e] * axis
    zmin = min(ends[0, 2], ends[1, 2])
    if not zmin - radius > _SPAN_MIN_DEPTH:
        return False, 0.0, 0.0, 0.0, 0.0
    ua = ends[0, 0] / ends[0, 2] * fx + cx
    va = ends[0, 1] / ends[0, 2] * fy + cy
    ub = ends[1, 0] / ends[1, 2] * fx + cx
    vb = ends[1, 1] / ends[1, 2] * fy + cy
    dx, dy = ub - ua, vb - va
    if not abs(dy) > 1e-6:
        return False, 0.0, 0.0, 0.0, 0.0
    far = 0.0
    for e in range(2):
        far = max(far, math.sqrt(ends[e, 0] ** 2 + ends[e, 1] ** 2 + ends[e, 2] ** 2))
    rho = max(fx, fy) * radius * far / (zmin * (zmin - radius)) + _SPAN_SLACK_PX
    return True, ua, va, dx / dy, rho * math.sqrt(dx * dx + dy * dy) / abs(dy)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _zbuffer(
    rot, origin, basis, scale, span, fx, fy, cx, cy, near, prim, segment_of, segment, out
):  # pragma: no cover
    B, P = origin.shape[0], origin.shape[1]
    H, W = prim.shape[1], prim.shape[2]
    m = np.empty((3, 3))
    cen = np.empty(3)
    boxes = np.empty((P, 4), np.int64)
    depth = np.empty((H, W))  # the float64 z-buffer of one pose, inside the boxes' union
    for b in range(B):
        # Background everywhere first (three plain fills); the z-buffer's own passes then
        # cover only the union of the capsules' boxes, a few times the person's pixels where
        # the window is ~10 times them.
        prim[b] = -1
        segment[b] = -1
        out[b] = 0.0
        U0, U1, V0, V1 = W, 0, H, 0
        for p in range(P):
            u0, u1, v0, v1 = _pixel_box(
                rot[b, p], origin[b, p], basis[p], scale[b, p], span[b, p], near, fx, fy, cx,
                cy, H, W, cen,
            )  # fmt: skip
            boxes[p, 0], boxes[p, 1], boxes[p, 2], boxes[p, 3] = u0, u1, v0, v1
            if u0 < u1 and v0 < v1:
                U0, U1, V0, V1 = min(U0, u0), max(U1, u1), min(V0, v0), max(V1, v1)
        for v in range(V0, V1):
            for u in range(U0, U1):
                depth[v, u] = np.inf
        for p in range(P):
            u0, u1, v0, v1 = boxes[p, 0], boxes[p, 1], boxes[p, 2], boxes[p, 3]
            if not (u0 < u1 and v0 < v1):
                continue
            # World -> scaled local: m = diag(1 / scale) basis R^T, o = -m origin.
            _capsule_frame(basis[p], rot[b, p], m)
            for i in range(3):
                for j in range(3):
                    m[i, j] /= scale[b, p, i]
            for i in range(3):  # the camera centre in the scaled frame: -m origin
                cen[i] = -(m[i, 0] * origin[b, p, 0] + m[i, 1] * origin[b, p, 1])
                cen[i] -= m[i, 2] * origin[b, p, 2]
            ox, oy, oz = cen[0], cen[1], cen[2]
            za, zb = span[b, p, 0] / scale[b, p, 2], span[b, p, 1] / scale[b, p, 2]
            tight, ua, va, slope, half = _row_band(
                rot[b, p], origin[b, p], basis[p], scale[b, p], span[b, p], fx, fy, cx, cy
            )
            for v in range(v0, v1):
                ry = (v - cy) / fy
                r0, r1 = u0, u1
                if tight:  # the row's cut of the band around the projected axis
                    x_line = ua + (v - va) * slope
                    r0 = max(u0, int(max(math.ceil(x_line - half), -1.0)))
                    r1 = min(u1, int(min(math.floor(x_line + half), W)) + 1)
                for u in range(r0, r1):
                    rx = (u - cx) / fx
                    dx = m[0, 0] * rx + m[0, 1] * ry + m[0, 2]
                    dy = m[1, 0] * rx + m[1, 1] * ry + m[1, 2]
                    dz = m[2, 0] * rx + m[2, 1] * ry + m[2, 2]
                    a = dx * dx + dy * dy
                    bb = ox * dx + oy * dy
                    cc = ox * ox + oy * oy - 1.0
                    h = bb * bb - a * cc
                    if h < 0.0:
                        continue
                    t = (-bb - math.sqrt(h)) / max(a, 1e-12)
                    z = oz + t * dz
                    if z < za or z > zb:  # through the cap on the side it met the cylinder
                        ocz = oz - (za if z < za else zb)
                        a_s = a + dz * dz
                        b_s = bb + ocz * dz
                        h_s = b_s * b_s - a_s * (cc + ocz * ocz)
                        if h_s < 0.0:
                            continue
                        t = (-b_s - math.sqrt(h_s)) / a_s
                    # Ties go to the later primitive, as the torch z-buffer's amax does.
                    if t > near and t <= depth[v, u]:
                        depth[v, u] = t
                        prim[b, v, u] = p
        for v in range(V0, V1):
            for u in range(U0, U1):
                p = prim[b, v, u]
                if p >= 0:
                    segment[b, v, u] = segment_of[p]
                    out[b, v, u] = depth[v, u]  # rounded to out's dtype, as torch's .to


def zbuffer_cpu(
    rot: torch.Tensor,
    origin: torch.Tensor,
    basis: torch.Tensor,
    scale: torch.Tensor,
    span: torch.Tensor,
    intr,
    near: float,
    segment_of: torch.Tensor | None = None,
) -> tuple[torch.Tensor, ...]:
    """Depth (B, H, W) in rot's dtype (0: background) and primitive (B, H, W) int64 (-1:
    background) of the capsules with frames ``rot`` (B, P, 3, 3), ``origin`` (B, P, 3) and the
    :class:`runtime.raycast.SegmentGeometry` fields ``basis`` (P, 3, 3), ``scale`` (..., P, 3),
    ``span`` (..., P, 2), on the image of ``intr``; hits nearer than ``near`` are ignored.
    With ``segment_of`` (P,) int64, also the segment (B, H, W) int64 each pixel hits (-1:
    background)."""
    B, P = origin.shape[:2]
    shape = (B, intr.height, intr.width)
    prim = np.empty(shape, dtype=np.int64)
    segment = np.empty(shape, dtype=np.int64)
    out = np.empty(shape, dtype=torch.empty(0, dtype=rot.dtype).numpy().dtype)
    table = np.zeros(P, np.int64) if segment_of is None else segment_of.numpy()
    _zbuffer(
        _f64(rot, B, P, 3, 3), _f64(origin, B, P, 3), _f64(basis, P, 3, 3), _f64(scale, B, P, 3),
        _f64(span, B, P, 2), float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy),
        float(near), prim, table, segment, out,
    )  # fmt: skip
    if segment_of is None:
        return torch.from_numpy(out), torch.from_numpy(prim)
    return torch.from_numpy(out), torch.from_numpy(prim), torch.from_numpy(segment)


@numba.njit(cache=True, nogil=True, boundscheck=False)
def _segment_distances(points, rot, origin, basis, span, scale, out):  # pragma: no cover
    B, N, P = out.shape[0], out.shape[1], out.shape[2]
    m = np.empty((3, 3))
    for b in range(B):
        for p in range(P):
            _capsule_frame(basis[p], rot[b, p], m)  # c = basis R^T (x - o)
            m00, m01, m02 = m[0, 0], m[0, 1], m[0, 2]
            m10, m11, m12 = m[1, 0], m[1, 1], m[1, 2]
            m20, m21, m22 = m[2, 0], m[2, 1], m[2, 2]
            ox, oy, oz = origin[b, p, 0], origin[b, p, 1], origin[b, p, 2]
            lo, hi = span[b, p, 0], span[b, p, 1]
            s0, s1, s2 = scale[b, p, 0], scale[b, p, 1], scale[b, p, 2]
            for n in range(N):
                rx, ry, rz = points[b, n, 0] - ox, points[b, n, 1] - oy, points[b, n, 2] - oz
                c0 = m00 * rx + m01 * ry + m02 * rz
                c1 = m10 * rx + m11 * ry + m12 * rz
                c2 = m20 * rx + m21 * ry + m22 * rz
                axial = c2 - min(max(c2, lo), hi)
                length = math.sqrt(c0 * c0 + c1 * c1 + axial * axial)
                rho = math.sqrt((c0 / s0) ** 2 + (c1 / s1) ** 2 + (axial / s2) ** 2)
                out[b, n, p] = length * (1.0 - 1.0 / max(rho, 1e-9))


def segment_distances_cpu(
    points: torch.Tensor,
    rot: torch.Tensor,
    origin: torch.Tensor,
    basis: torch.Tensor,
    span: torch.Tensor,
    scale: torch.Tensor,
) -> torch.Tensor:
    """Signed distance (B, N, P) in points' dtype, > 0 outside, of the points (B, N, 3) to the
    P capsules with frames ``rot`` (B, P, 3, 3), ``origin`` (B, P, 3) and the
    :class:`runtime.raycast.SegmentGeometry` fields ``basis`` (P, 3, 3), ``span`` (..., P, 2),
    ``scale`` (..., P, 3): :func:`runtime.raycast.capsule_signed_distance`'s measure."""
    B, N = points.shape[:2]
    P = origin.shape[1]

    out = np.empty((B, N, P))
    _segment_distances(
        _f64(points, B, N, 3), _f64(rot, B, P, 3, 3), _f64(origin, B, P, 3), _f64(basis, P, 3, 3),
        _f64(span, B, P, 2), _f64(scale, B, P, 3), out,
    )  # fmt: skip
    return torch.from_numpy(out).to(points.dtype)
