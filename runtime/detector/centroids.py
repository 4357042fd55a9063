"""Class centroids as IK markers (Wei section 4.2, "3D pose reconstruction").

Wei uses the centroid of each class's surviving (inlier) pixels as a kinematic constraint.
Here each of the 19 part classes becomes one marker: a point on its segment's axis at the
middle of the part's axial span (:func:`part_markers`), so the IK (``shared.ik.fit_pose``) pulls
that axis point to the centroid.

Two corrections make the centroid and the marker the same point:

- Depth: the pixels lie on the visible surface, in front of the bone's axis. For a cylinder of
  radius r seen from the side, pixels are uniform across its image width, so their mean depth
  is ``(pi / 4) r`` in front of the axis. Each centroid is pushed away from the camera along its
  viewing ray by ``surface_offset * r`` (r: the geometric mean of the section's semi-axes, as
  the facing direction is unknown).
- Axial position: the marker fraction is the middle of the span the part's label covers on the
  segment: the whole segment including geometry beyond the joints (a forearm covers the hand,
  the pelvis reaches below the hips), or the upper / lower half of a split thigh or shank.

A class with fewer than ``min_pixels`` surviving pixels gives no marker (weight 0, target NaN):
missing and occluded parts are simply left out of the IK. Otherwise the weight is
``n / (n + weight_pixels)``, so a few visible pixels count less than a whole limb.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from depthmocap.shared.body import BodyShape
from depthmocap.shared.ik import Markers
from depthmocap.shared.labels import NUM_CLASSES, PART_NAMES, PART_SEGMENT

__all__ = ["ClassCentroids", "part_markers", "class_centroids"]


def part_markers(body: BodyShape) -> Markers:
    """One marker per part class 1..19 (index c - 1): the middle of the part's axial span."""
    lengths = body.lengths.detach().double().cpu()
    extents = body.extents.detach().double().cpu()
    segs, fracs = [], []
    for c in range(1, NUM_CLASSES):
        k = int(PART_SEGMENT[c])
        L = float(lengths[k])
        lo, hi = -float(extents[k, 0]) / L, 1.0 + float(extents[k, 1]) / L
        if PART_NAMES[c].endswith("_upper"):
            hi = 0.5
        elif PART_NAMES[c].endswith("_lower"):
            lo = 0.5
        segs.append(k)
        fracs.append(0.5 * (lo + hi))
    return Markers(tuple(segs), tuple(fracs))


@dataclass
class ClassCentroids:
    """Per-class centroids of the surviving points (index c - 1 for class c).

    Attributes:
        targets: (19, 3) marker targets (centroid pushed behind the surface), NaN if missing.
        weights: (19,) IK weight, 0 if missing.
        counts: (19,) surviving pixels per class.
    """

    targets: torch.Tensor
    weights: torch.Tensor
    counts: torch.Tensor


def class_centroids(
    points: torch.Tensor,
    labels: torch.Tensor,
    keep: torch.Tensor,
    body: BodyShape,
    surface_offset: float = 0.785,
    min_pixels: int = 12,
    weight_pixels: float = 30.0,
) -> ClassCentroids:
    """Centroids of the kept points per class (module docstring).

    Args:
        points: (N, 3) camera-frame points; labels: (N,) part labels 1..19; keep: (N,) bool.
        body: body model (unbatched), for the section radii.
    """
    dev, dt = points.device, points.dtype
    C = NUM_CLASSES - 1
    idx = (labels.long() - 1).clamp(0, C - 1)
    w = keep.to(dt)
    counts = torch.zeros(C, dtype=dt, device=dev).index_add(0, idx, w)
    sums = torch.zeros(C, 3, dtype=dt, device=dev).index_add(0, idx, points * w[:, None])
    centroid = sums / counts[:, None].clamp_min(1.0)
    seg = torch.as_tensor(PART_SEGMENT[1:], device=dev)
    radii = body.radii.to(device=dev, dtype=dt)[seg]  # (19, 2)
    radius = torch.sqrt(radii[:, 0] * radii[:, 1])
    ray = centroid / centroid.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    targets = centroid + surface_offset * radius[:, None] * ray
    present = counts >= min_pixels
    targets = torch.where(present[:, None], targets, torch.full_like(targets, float("nan")))
    weights = torch.where(present, counts / (counts + weight_pixels), torch.zeros_like(counts))
    return ClassCentroids(targets, weights, counts)
