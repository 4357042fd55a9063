"""Clothing drawn over a rendered bare body, in the image: what the anny mesh lacks.

Real people wear trousers and jackets. On real Kinect v1 depth (UTD-MHAD) a forest trained on
bare bodies labels trousered thighs that touch, or nearly, as abdomen, and the shanks below as
thighs: its leg labels are right on a fifth of the pixels the reference skeleton puts on the
legs, against nine tenths on rendered bodies (docs/real_data.md). A bare body shows a clear gap
between the thighs all the way up, which clothing closes. Two effects, both on the clean render
(metric depth and labels, before the scene and the sensor model so that both apply to the
cloth too):

- :func:`close_leg_gaps`: along each image row, background between a left-leg and a right-leg
  pixel that is no wider than ``max_gap_m`` becomes cloth spanning the legs, its depth
  interpolated between the two edges, each half labelled as the leg it adjoins (the label says
  which bone lies under the cloth, as the forest must learn it).
- :func:`thicken_silhouette`: the silhouette grown by a cloth thickness; a grown pixel takes the
  depth and part of the nearest body pixel (a silhouette edge is seen at the depth of its side).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import field_doc
from depthmocap.shared.labels import PART_NAMES

__all__ = ["GarmentConfig", "close_leg_gaps", "thicken_silhouette", "dress_body"]

# (C,) whether each part lies on the left or the right leg.
_LEFT_LEG = np.array([n.startswith(("l_thigh", "l_shank")) for n in PART_NAMES])
_RIGHT_LEG = np.array([n.startswith(("r_thigh", "r_shank")) for n in PART_NAMES])


@dataclass
class GarmentConfig:
    """Clothing over the bare body (off by default: the evaluation recordings stay bare)."""

    probability: float = field_doc(0.0, "share of frames drawn clothed (0: every body bare)")
    thickness_m: tuple[float, float] = field_doc(
        (0.0, 0.03), "range of the cloth thickness grown around the silhouette (m), per frame"
    )
    leg_gap_m: tuple[float, float] = field_doc(
        (0.0, 0.15), "range of the widest gap between the legs that cloth closes (m), per frame"
    )
    max_depth_step_m: float = field_doc(
        0.1, "no cloth spans two leg edges further apart than this in depth (m)"
    )

    def validate(self) -> None:
        """Raise ``ValueError`` on values that make no sense."""
        if not 0.0 <= self.probability <= 1.0:
            raise ValueError(f"garments.probability must be in [0, 1], not {self.probability}")
        for name in ("thickness_m", "leg_gap_m"):
            lo, hi = getattr(self, name)
            if not 0.0 <= lo <= hi:
                raise ValueError(f"garments.{name} must be a range 0 <= lo <= hi, not {lo, hi}")
        if self.max_depth_step_m <= 0:
            raise ValueError("garments.max_depth_step_m must be positive")


def _nearest_person_columns(person: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of an (H, W) mask, the column of the nearest mask pixel at or left of it and at
    or right of it in its row (-1 where there is none); ``cols`` is each pixel's column."""
    w = person.shape[1]
    left = np.maximum.accumulate(np.where(person, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(person, cols, w)[:, ::-1], axis=1)[:, ::-1]
    return left, np.where(right == w, -1, right)


def close_leg_gaps(
    depth_m: np.ndarray,
    labels: np.ndarray,
    intr: Intrinsics,
    max_gap_m: float,
    max_depth_step_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Cloth across the background between the two legs, row by row.

    Args:
        depth_m: (H, W) clean metric depth, 0 = no surface; labels: (H, W) uint8 parts.
        max_gap_m: widest background run closed, measured at the depth of its edges (m).
        max_depth_step_m: runs whose two edges differ more in depth stay open.
    Returns:
        (depth_m, labels), new arrays; the input is not changed.
    """
    person = labels > 0
    h, w = person.shape
    rows, cols = (
        np.broadcast_to(np.arange(h)[:, None], (h, w)),
        np.broadcast_to(np.arange(w), (h, w)),
    )
    left, right = _nearest_person_columns(person, cols)
    gap = ~person & (left >= 0) & (right >= 0)
    lc, rc = np.where(gap, left, 0), np.where(gap, right, 0)
    lab_l, lab_r = labels[rows, lc], labels[rows, rc]
    d_l, d_r = depth_m[rows, lc], depth_m[rows, rc]
    legs = (_LEFT_LEG[lab_l] & _RIGHT_LEG[lab_r]) | (_RIGHT_LEG[lab_l] & _LEFT_LEG[lab_r])
    width_px = (rc - lc - 1).astype(np.float64)
    width_m = width_px * 0.5 * (d_l + d_r) / intr.fx
    fill = gap & legs & (width_m <= max_gap_m) & (np.abs(d_l - d_r) <= max_depth_step_m)
    t = (cols - lc) / np.maximum(rc - lc, 1)
    depth_out = np.where(fill, d_l + t * (d_r - d_l), depth_m).astype(depth_m.dtype)
    labels_out = np.where(fill, np.where(t < 0.5, lab_l, lab_r), labels).astype(labels.dtype)
    return depth_out, labels_out


def thicken_silhouette(
    depth_m: np.ndarray, labels: np.ndarray, intr: Intrinsics, thickness_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The silhouette grown by ``thickness_m`` of cloth (measured at the nearest body pixel's
    depth); grown pixels copy that pixel's depth and part.

    Args:
        depth_m: (H, W) clean metric depth, 0 = no surface; labels: (H, W) uint8 parts.
    Returns:
        (depth_m, labels), new arrays.
    """
    from scipy.ndimage import distance_transform_edt

    person = labels > 0
    if thickness_m <= 0 or not person.any():
        return depth_m.copy(), labels.copy()
    dist_px, (iv, iu) = distance_transform_edt(~person, return_indices=True)
    near_depth = depth_m[iv, iu]
    grow = ~person & (depth_m <= 0) & (dist_px * near_depth <= thickness_m * intr.fx)
    depth_out = np.where(grow, near_depth, depth_m).astype(depth_m.dtype)
    labels_out = np.where(grow, labels[iv, iu], labels).astype(labels.dtype)
    return depth_out, labels_out


def dress_body(
    depth_m: np.ndarray,
    labels: np.ndarray,
    intr: Intrinsics,
    cfg: GarmentConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Clothe a clean render with probability ``cfg.probability`` (leg gaps closed, then the
    silhouette thickened). Draws nothing from ``rng`` when the probability is 0, so frames
    rendered without garments stay exactly as before.

    Args:
        depth_m: (H, W) clean metric depth, 0 = no surface; labels: (H, W) uint8 parts.
    """
    cfg.validate()
    if cfg.probability <= 0 or rng.random() >= cfg.probability:
        return depth_m, labels
    gap = rng.uniform(*cfg.leg_gap_m)
    thickness = rng.uniform(*cfg.thickness_m)
    depth_m, labels = close_leg_gaps(depth_m, labels, intr, gap, cfg.max_depth_step_m)
    return thicken_silhouette(depth_m, labels, intr, thickness)
