"""Step 5 of person segmentation: which plausible component is the person.

The largest plausible component is not always the person: a cupboard, a door or a box of a
person's size may be larger, above all when the person is far, seen from the side or
crouching. Two cues tell them apart without knowing anything about the scene:

- **Shape.** A person's silhouette is far from convex (head over shoulders, arms, the gap
  between the legs): the share of its convex hull it fills (its solidity) is 0.4-0.8. A box, a
  door, a cupboard or a wall section projects to a convex polygon, whose solidity is close to 1.
  A component's area counts for less the more convex it is (:func:`person_likeness`).
- **Continuity.** Between frames of a stream the person moves a few centimetres: a component
  lying mostly where the previous frame's person was (``continuity_overlap`` of its pixels)
  is favoured (``continuity_gain``), so the choice does not flip between the person and an
  object of similar score.

Both are soft: the only plausible component is the person even if it is convex (a person
slab in a test scene, a person wrapped in a blanket), and a clearly better candidate wins
against continuity (the track can recover from a wrong first choice).
"""

from __future__ import annotations

import numpy as np

from .config import SegmentationConfig

__all__ = ["component_solidity", "person_likeness", "person_scores"]


def component_solidity(
    labels: np.ndarray, stats: np.ndarray, which: np.ndarray, cv2, erosion_px: int = 0
) -> np.ndarray:
    """Solidity (pixel area / convex hull area) of the components ``which`` of a label canvas.

    Args:
        labels: (H, W) component labels (OpenCV's, 0 = none).
        stats: (count, 5) OpenCV component statistics (left, top, width, height, area).
        which: (K,) component labels to measure.
        erosion_px: measure each component eroded by this many pixels (a square), so that
            its ragged fringe does not count: a sensor's flying pixels along a box's edge
            swell its hull and make it look less convex than it is. A component the erosion
            removes entirely is measured as it is.
    Returns:
        (K,) solidity in (0, 1]. The hull is taken through pixel centres, so its area is grown
        by half its perimeter plus one (the pixels' own extent), making a filled rectangle 1.
    """
    out = np.ones(len(which))
    kernel = np.ones((2 * erosion_px + 1,) * 2, np.uint8)
    for i, k in enumerate(which):
        x, y, w, h, _ = stats[k]
        sub = (labels[y : y + h, x : x + w] == k).view(np.uint8)
        if erosion_px > 0:
            padded = np.pad(sub, erosion_px)  # with background: the bounding box's edge erodes
            core = cv2.morphologyEx(padded, cv2.MORPH_OPEN, kernel)
            sub = core if core.any() else sub
        n = int(np.count_nonzero(sub))
        contours, _ = cv2.findContours(sub, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        hull = cv2.convexHull(np.concatenate(contours))
        out[i] = n / max(cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True) + 1.0, 1.0)
    return np.minimum(out, 1.0)


def person_likeness(solidity: np.ndarray, cfg: SegmentationConfig) -> np.ndarray:
    """(...,) weight in [``convex_weight``, 1] of a component's area by its solidity: 1 up to
    ``person_max_solidity``, falling linearly to ``convex_weight`` at ``convex_solidity``."""
    lo, hi = cfg.person_max_solidity, cfg.convex_solidity
    ramp = np.clip((hi - solidity) / max(hi - lo, 1e-6), 0.0, 1.0)
    return cfg.convex_weight + (1.0 - cfg.convex_weight) * ramp


def person_scores(
    area: np.ndarray, solidity: np.ndarray, previous_share: np.ndarray, cfg: SegmentationConfig
) -> np.ndarray:
    """(K,) scores of K plausible components; in each image the highest is the person.

    Args:
        area: (K,) metric areas, m^2.
        solidity: (K,) from :func:`component_solidity`.
        previous_share: (K,) share of each component's pixels that were the person in the
            previous frame (0 without one: the first frame, or a single image).
    """
    score = area * person_likeness(solidity, cfg)
    return np.where(previous_share >= cfg.continuity_overlap, score * cfg.continuity_gain, score)
