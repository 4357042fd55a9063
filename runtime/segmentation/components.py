"""Step 4 of person segmentation: connected components, their metric statistics and
plausibility, what lies behind what, and the joining of body parts cut off from the person."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from depthmocap.shared.camera import Intrinsics

from .canvas import Canvas
from .config import SegmentationConfig

__all__ = [
    "Components",
    "box_sizes",
    "boxes",
    "join_nearby_parts",
    "occluded_by_large",
    "plausible_size",
]


def boxes(
    z: np.ndarray, labels: np.ndarray, count: int, cv: Canvas, intr: Intrinsics
) -> np.ndarray:
    """(count, 2, 3) metric bounding boxes (min, max of x, y, z) of a canvas's components;
    empty components get (inf, -inf).

    Measured on every second row and column: a pixel or two (centimetres) matters nothing
    against the metre-scale plausibility limits, and it is a quarter of the work.
    """
    rows, cols = np.nonzero(labels[::2, ::2])
    rows, cols = 2 * rows, 2 * cols
    zs = z[rows, cols]
    xs = (cols - cv.pad - intr.cx) / intr.fx * zs
    ys = ((rows - cv.pad) % (cv.h + cv.pad) - intr.cy) / intr.fy * zs
    # One 1-D scatter-max over (max x, y, z, -min x, -min y, -min z) is numpy's fast path.
    signed = np.stack([xs, ys, zs, -xs, -ys, -zs], 1).astype(np.float32)  # (N, 6)
    slots = labels[rows, cols][:, None] * 6 + np.arange(6)
    top = np.full(count * 6, -np.inf, dtype=np.float32)
    np.maximum.at(top, slots.reshape(-1), signed.reshape(-1))
    top = top.reshape(count, 2, 3)
    return np.stack([-top[:, 1], top[:, 0]], 1)


def box_sizes(box: np.ndarray) -> np.ndarray:
    """(..., 3) extents of (..., 2, 3) boxes, 0 for empty ones."""
    return np.maximum(box[..., 1, :] - box[..., 0, :], 0.0)


def plausible_size(size: np.ndarray, cfg: SegmentationConfig) -> np.ndarray:
    """(...,) bool: (..., 3) metric extents fit a person."""
    limits = np.array([cfg.max_width_m, cfg.max_height_m, cfg.max_depth_extent_m])
    return (size <= limits).all(-1)


def _extents_fit(
    in_person: np.ndarray,
    join: np.ndarray,
    box: np.ndarray,
    image_of: np.ndarray,
    b: int,
    cfg: SegmentationConfig,
) -> np.ndarray:
    """(count,) bool: joining each candidate keeps its image's person within plausible extents."""
    lo = np.full((b, 3), np.inf)
    hi = np.full((b, 3), -np.inf)
    np.minimum.at(lo, image_of[in_person], box[in_person, 0])
    np.maximum.at(hi, image_of[in_person], box[in_person, 1])
    merged = np.stack([np.minimum(lo[image_of], box[:, 0]), np.maximum(hi[image_of], box[:, 1])], 1)
    return ~join | plausible_size(box_sizes(merged), cfg)


def occluded_by_large(
    lab_nb: np.ndarray,
    step: np.ndarray,
    jump: np.ndarray,
    comp_area: np.ndarray,
    count: int,
    min_area: float,
) -> np.ndarray:
    """(count,) bool: components seen behind a nearer component of at least ``min_area``.

    Every cut pixel sits on the far side of a depth step: its similar-depth neighbours name
    the hidden component, its much nearer neighbours the occluder.

    Args:
        lab_nb: (M, 4) component labels of the 4-neighbours of the M cut pixels (0 = none).
        step: (M, 4) cut pixel's depth minus its neighbours'.
        jump: (M, 1) depth step that separates surfaces at each cut pixel.
    """
    labelled = lab_nb > 0
    nearer = (step > jump) & labelled
    similar = (np.abs(step) <= jump) & labelled
    hidden = np.where(similar, lab_nb, 0).max(1, initial=0)
    # A step inside one component (chin over neck) is self-occlusion, not background.
    other = nearer & (lab_nb != hidden[:, None])
    occluder_area = np.where(other, comp_area[lab_nb], 0.0).max(1, initial=0.0)
    behind = np.zeros(count, dtype=bool)
    behind[hidden[(hidden > 0) & (occluder_area >= min_area)]] = True
    return behind


@dataclass
class Components:
    """Connected components of a canvas and their statistics.

    Attributes:
        labels: canvas of component labels (0 = none); the arrays below are indexed by label.
        pixels, depth, area: (count,) pixel count, mean depth (m), metric area (m^2).
        box: (count, 2, 3) metric bounding boxes (see :func:`boxes`).
        image_of: (count,) batch index.
    """

    labels: np.ndarray
    pixels: np.ndarray
    depth: np.ndarray
    area: np.ndarray
    box: np.ndarray
    image_of: np.ndarray


def join_nearby_parts(
    in_person: np.ndarray, comps: Components, b: int, cfg: SegmentationConfig, cv2
) -> np.ndarray:
    """Grow the (count,) bool person components by the parts of the body cut off from them.

    Limbs pointing at the camera are foreshortened, so their depth changes faster between
    pixels than the cut threshold and hands come out as separate components; and a limb
    crossing in front of the body cuts off what lies behind it (an arm swung down in front of
    the hips parts the legs from the trunk, a squat's thighs part the trunk from the feet).
    Components within ``merge_radius_px`` of the person join when
    - their depth range overlaps the person's, with ``merge_depth_margin_m`` to spare:
      cut-off parts of the same body, of any size (the legs are half the body), as long as
      the joined person keeps plausible extents (a wall behind lies beyond the person's
      depths; a side wall or a floor reaching into them makes the person too large). An
      object at the person's depth that touches it without a depth step was never cut from
      it in the first place; or
    - their mean depth is at most ``merge_depth_margin_m`` behind the person's and at most
      ``merge_max_front_m`` in front of it (arm reach), and they are small
      (``merge_max_area_fraction`` of the person: a hand, not a second person).
    """
    r = cfg.merge_radius_px
    if r <= 0 or cfg.merge_rounds <= 0 or not in_person.any():
        return in_person
    c = comps
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    margin = cfg.merge_depth_margin_m
    for _ in range(cfg.merge_rounds):
        # The person is a union of whole components: its statistics come from theirs.
        weight = in_person * c.pixels
        person_depth = np.bincount(c.image_of, weight * c.depth, minlength=b) / np.maximum(
            np.bincount(c.image_of, weight, minlength=b), 1
        )
        person_area = np.bincount(c.image_of, in_person * c.area, minlength=b)
        mask = in_person[c.labels]
        near = cv2.dilate(mask.view(np.uint8), kernel).view(bool)
        touching = np.zeros_like(in_person)
        touching[c.labels[near & ~mask]] = True

        z_lo, z_hi = np.full(b, np.inf), np.full(b, -np.inf)
        np.minimum.at(z_lo, c.image_of[in_person], c.box[in_person, 0, 2])
        np.maximum.at(z_hi, c.image_of[in_person], c.box[in_person, 1, 2])
        cut_off = (c.box[:, 0, 2] <= z_hi[c.image_of] + margin) & (
            c.box[:, 1, 2] >= z_lo[c.image_of] - margin
        )
        offset = c.depth - person_depth[c.image_of]
        in_front = (
            (offset >= -cfg.merge_max_front_m)
            & (offset <= margin)
            & (c.area <= cfg.merge_max_area_fraction * person_area[c.image_of])
        )
        join = touching & ~in_person & (cut_off | in_front)
        join[0] = False
        if join.any():
            join &= _extents_fit(in_person, join, c.box, c.image_of, b, cfg)
        if not join.any():
            break
        in_person = in_person | join
    return in_person
