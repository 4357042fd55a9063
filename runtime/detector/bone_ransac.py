"""Outlier removal by RANSAC bone fitting (Wei section 4.2).

For every bone (skeleton segment; a thigh or shank takes the pixels of both its label halves)
the classified depth pixels, back-projected to 3D points, vote for the bone's location: a
random pair of the bone's points is a hypothesis of where the bone lies, and its score is the
number of the bone's points that lie on or within the bone so placed. Pairs farther apart than
the bone's reach or closer than a fifth of it are discarded without scoring (Wei's speed-up:
two points on one rigid bone are never farther apart than the bone, and close pairs fix its
direction badly). The winner's inliers survive; every other pixel of the class was
misclassified (it sits on another limb, or is a stray pixel of the forest).

The pair is two points of the visible surface, so the line through them runs along the surface
roughly parallel to the axis. A point of the same bone then lies

- within one diameter of that line (``2 r_max`` plus a noise margin; r_max the larger semi-axis
  of the bone's section), and
- at an axial position ``t`` (from the first point, towards the second at ``t = d``) inside
  ``[d - reach, reach]``: wherever the bone lies along the line, it covers both points.

"Reach" is the bone's largest extent, the diagonal of its cylinder including the geometry
beyond the joints (a forearm covers the hand): ``sqrt((L + e0 + e1)^2 + (2 r_max)^2)``. For a
limb that is the bone length to within a few per cent; for the wide torso segments it keeps
pairs across the body.

Everything is vectorized over bones x samples x points; bones are padded to a common size.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.compiled import compiled_module
from depthmocap.shared.labels import PART_SEGMENT

__all__ = ["BoneFit", "bone_reach", "fit_bones", "inlier_counts"]


@dataclass
class BoneFit:
    """Result of :func:`fit_bones`.

    Attributes:
        inlier: (N,) bool, the point survives (it lies on its bone's best hypothesis).
        found: (K,) bool, a hypothesis passed the length test for bone k (K = 15 segments);
            bones without one keep all their points.
        line_point: (K, 3) first point of the winning pair (undefined where not found).
        line_dir: (K, 3) unit direction of the winning pair (undefined where not found).
        score: (K,) inlier count of the winner on the scored subset.
    """

    inlier: torch.Tensor
    found: torch.Tensor
    line_point: torch.Tensor
    line_dir: torch.Tensor
    score: torch.Tensor


def bone_reach(body: BodyShape) -> tuple[torch.Tensor, torch.Tensor]:
    """Largest extent and largest section radius of each bone: ((15,), (15,)) metres."""
    full = body.lengths + body.extents.sum(-1)
    r_max = body.radii.amax(-1)
    return torch.sqrt(full * full + (2.0 * r_max) ** 2), r_max


def _inliers(
    x: torch.Tensor, p1: torch.Tensor, u: torch.Tensor, d: torch.Tensor, reach, max_perp
) -> torch.Tensor:
    """Points x (..., 3) on the bone hypothesised by line (p1, u) with pair distance d."""
    rel = x - p1
    t = (rel * u).sum(-1)
    perp2 = (rel * rel).sum(-1) - t * t
    return (perp2 <= max_perp * max_perp) & (t >= d - reach) & (t <= reach)


def _compiled_kernel():
    """:mod:`runtime.detector.ransac_kernel` (numba's compiled fit), or None without numba."""
    return compiled_module("depthmocap.runtime.detector.ransac_kernel")


def inlier_counts(
    sub: torch.Tensor,
    sub_ok: torch.Tensor,
    a: torch.Tensor,
    u: torch.Tensor,
    d: torch.Tensor,
    reach: torch.Tensor,
    max_perp: torch.Tensor,
) -> torch.Tensor:
    """Each pair's inliers among its bone's valid subset points: (K, S) int64.

    Args:
        sub: (K, P, 3) subset points per bone; sub_ok: (K, P) bool, valid entries.
        a: (K, S, 3) first point of each pair; u: (K, S, 3) its unit direction; d: (K, S)
            pair distance; reach, max_perp: (K,) per bone.
    On the CPU with numba a compiled loop (the same counts); otherwise torch over (K, S, P)."""
    kernel = _compiled_kernel() if sub.device.type == "cpu" else None
    if kernel is not None and not sub.requires_grad:
        return kernel.inlier_counts_cpu(sub, sub_ok, a, u, d, reach, max_perp)
    hit = _inliers(
        sub[:, None], a[:, :, None], u[:, :, None], d[..., None], reach[:, None, None],
        max_perp[:, None, None],
    ) & sub_ok[:, None]  # fmt: skip
    return hit.sum(-1)


def fit_bones(
    points: torch.Tensor,
    labels: torch.Tensor,
    body: BodyShape,
    samples: int = 2500,
    scored: int = 256,
    max_points: int = 600,
    min_pair_fraction: float = 0.2,
    margin_m: float = 0.03,
    generator: torch.Generator | None = None,
) -> BoneFit:
    """RANSAC bone fits for labelled points (module docstring).

    Args:
        points: (N, 3) camera-frame points of the labelled pixels, metres.
        labels: (N,) int part labels (``shared.labels``; 1..19, background excluded).
        body: body model (unbatched) giving bone lengths and radii.
        samples: random pairs drawn per bone.
        scored: pairs passing the length test that are scored, per bone at most.
        max_points: inliers are counted on a random subset of this many points per bone.
        min_pair_fraction: pairs shorter than this fraction of the reach are discarded.
        margin_m: slack on the distance-from-line test, metres.
        generator: random source (CPU generator; draws are moved to the points' device).
    Returns:
        :class:`BoneFit`.
    """
    dev, dt = points.device, points.dtype
    K, N = sk.NUM_SEGMENTS, points.shape[0]
    reach, r_max = (x.to(device=dev, dtype=dt) for x in bone_reach(body))
    max_perp = 2.0 * r_max + margin_m
    seg = torch.as_tensor(PART_SEGMENT, device=dev)[labels.long()]  # (N,)

    def rand(*shape):
        return torch.rand(*shape, generator=generator).to(device=dev, dtype=dt)

    if N == 0:  # no points: no bone found (the paths below gather from the points)
        found = torch.zeros(K, dtype=torch.bool, device=dev)
        line = torch.zeros(K, 3, device=dev, dtype=dt)
        score = torch.zeros(K, dtype=torch.long, device=dev)
        return BoneFit(found[:0], found, line, line.clone(), score)
    kernel = _compiled_kernel() if dev.type == "cpu" and dt == torch.float32 else None
    if kernel is not None and not points.requires_grad:  # the same fit, compiled
        inlier, found, p1, u1, best = kernel.fit_bones_cpu(
            points, seg, reach, max_perp, max_points, samples, scored, min_pair_fraction, rand
        )
        return BoneFit(inlier, found, p1, u1, best)

    # Random order within each bone: sort by (segment, random key); rank inside the group.
    order = torch.argsort(seg.to(dt) + rand(N) * 0.5)
    counts = torch.bincount(seg, minlength=K)[:K]
    start = torch.cumsum(counts, 0) - counts
    rank = torch.arange(N, device=dev) - start[seg[order]]
    P = max(1, min(max_points, int(counts.max()) if N else 1))
    keep = rank < P
    table = torch.full((K, P), -1, dtype=torch.long, device=dev)
    table[seg[order][keep], rank[keep]] = order[keep]
    n_sub = counts.clamp(max=P)  # (K,) valid entries per row
    sub = points[table.clamp_min(0)]  # (K, P, 3)
    sub_ok = table >= 0

    # Pairs drawn among the subset, discarded by Wei's length test before any scoring.
    ij = (rand(K, samples, 2) * n_sub[:, None, None].to(dt)).long()
    ij = torch.minimum(ij, (n_sub[:, None, None] - 1).clamp_min(0))
    kk = torch.arange(K, device=dev)[:, None]
    a, b = sub[kk, ij[..., 0]], sub[kk, ij[..., 1]]  # (K, S, 3)
    d = (b - a).norm(dim=-1)
    ok = (d <= reach[:, None]) & (d >= min_pair_fraction * reach[:, None]) & (n_sub[:, None] >= 2)
    pick = torch.topk(ok.to(dt) + rand(K, samples) * 0.5, min(scored, samples), dim=1).indices
    a, b, d, ok = a[kk, pick], b[kk, pick], d[kk, pick], ok[kk, pick]  # (K, S', ...)
    u = (b - a) / d[..., None].clamp_min(1e-9)

    counts = inlier_counts(sub, sub_ok, a, u, d, reach, max_perp)
    score = torch.where(ok, counts, torch.full_like(d, -1, dtype=torch.long))
    best = score.argmax(1)  # (K,)
    found = ok[torch.arange(K, device=dev), best]
    p1 = a[torch.arange(K, device=dev), best]
    u1 = u[torch.arange(K, device=dev), best]
    d1 = d[torch.arange(K, device=dev), best]

    # Final inliers over all points of each bone, against that bone's winner.
    inl = _inliers(points, p1[seg], u1[seg], d1[seg], reach[seg], max_perp[seg])
    inlier = inl | ~found[seg]
    return BoneFit(inlier, found, p1, u1, score.amax(1).clamp_min(0))
