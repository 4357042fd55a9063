"""Body-part label set of the per-pixel forest (Wei section 4): 19 parts plus background.

The 15 skeleton segments, with thighs and shanks each split at mid-length into an upper and a
lower part (so a leg's bone direction is observable from two centroids). Label 0 is
background. Label images are uint8.
"""

from __future__ import annotations

import numpy as np

from .skeleton import JOINT_NAMES, NUM_SEGMENTS, SEGMENT_NAMES

__all__ = [
    "PART_NAMES",
    "CLUTTER_CLASSES",
    "CLUTTER_SMOOTH_WINDOW",
    "NUM_CLASSES",
    "BACKGROUND",
    "PART_SEGMENT",
    "SPLIT_SEGMENTS",
    "segment_to_part",
    "PART_COLORS",
    "JOINT_PARTS",
]

BACKGROUND = 0
PART_NAMES: tuple[str, ...] = (
    "background",
    "pelvis", "abdomen", "chest", "neck", "head",
    "l_clavicle", "r_clavicle", "l_upper_arm", "r_upper_arm", "l_forearm", "r_forearm",
    "l_thigh_upper", "l_thigh_lower", "r_thigh_upper", "r_thigh_lower",
    "l_shank_upper", "l_shank_lower", "r_shank_upper", "r_shank_lower",
)  # fmt: skip
NUM_CLASSES = len(PART_NAMES)  # 20 including background
assert NUM_CLASSES == 20

# The person/clutter forest's classes (``runtime.segmentation.clutter``): outside the mask,
# the person, and furniture the segmentation left attached to them.
CLUTTER_CLASSES: tuple[str, ...] = ("background", "person", "clutter")
# Its posteriors are averaged over this box of pixels at the same depth before the threshold
# (as the part labels are): a forest decides each pixel alone, so a lone doubtful pixel inside
# the body is not cut out.
CLUTTER_SMOOTH_WINDOW = 5

# Segments whose label is split at half their length.
SPLIT_SEGMENTS: tuple[int, ...] = tuple(
    SEGMENT_NAMES.index(n) for n in ("l_thigh", "r_thigh", "l_shank", "r_shank")
)

# Segment each part lies on (background: -1).
PART_SEGMENT = np.array(
    [-1]
    + [
        SEGMENT_NAMES.index(n.removesuffix("_upper").removesuffix("_lower")) for n in PART_NAMES[1:]
    ],
    dtype=np.int64,
)

# (segment, lower-half?) -> part; for unsplit segments both halves map to the same part.
_SEG_TO_PART = np.zeros((NUM_SEGMENTS, 2), dtype=np.uint8)
for _p, _name in enumerate(PART_NAMES[1:], start=1):
    _k = PART_SEGMENT[_p]
    if _name.endswith("_upper"):
        _SEG_TO_PART[_k, 0] = _p
    elif _name.endswith("_lower"):
        _SEG_TO_PART[_k, 1] = _p
    else:
        _SEG_TO_PART[_k, :] = _p


def segment_to_part(segment: np.ndarray, fraction: np.ndarray) -> np.ndarray:
    """Part label of points on ``segment`` at ``fraction`` of its length from its origin.

    Args:
        segment: (...) int segment indices; negative means background.
        fraction: (...) position along the segment, 0 at its joint, 1 at its end.
    Returns:
        (...) uint8 part labels (0 for background).
    """
    segment = np.asarray(segment)
    lower = (np.asarray(fraction) >= 0.5).astype(np.int64)
    part = _SEG_TO_PART[np.clip(segment, 0, None), lower]
    return np.where(segment >= 0, part, BACKGROUND).astype(np.uint8)


def _palette() -> np.ndarray:
    # Distinct, stable colours for visualizations (HSV wheel, alternating brightness).
    cols = np.zeros((NUM_CLASSES, 3), dtype=np.uint8)
    for i in range(1, NUM_CLASSES):
        h = (i * 0.618034) % 1.0
        v = 1.0 if i % 2 else 0.75
        k = (np.array([5.0, 3.0, 1.0]) + h * 6.0) % 6.0
        rgb = v - v * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)
        cols[i] = (rgb * 255).astype(np.uint8)
    return cols


PART_COLORS = _palette()  # (20, 3) uint8 RGB; background black


def _joint_parts() -> dict[str, tuple[tuple[str, ...], float]]:
    # The radius spans the flesh between a joint centre and the surface a camera sees: 10 cm
    # at the limbs' joints (upper arm 5-6 cm, forearm 3.6 cm, thigh about 9 cm on the dev
    # bodies), 15 cm at the hips (inside the thigh's top), 20 cm at the trunk's joints (the
    # spine lies some 5 cm behind the middle of a trunk 25 cm deep).
    limb_m, hip_m, trunk_m = 0.10, 0.15, 0.20
    table = {
        "head": (("head", "neck"), trunk_m),
        "neck": (("neck", "chest", "l_clavicle", "r_clavicle"), trunk_m),
        "spine": (("abdomen", "chest"), trunk_m),
        "pelvis": (("pelvis", "abdomen"), trunk_m),
    }
    limbs = {
        "shoulder": (("clavicle", "upper_arm"), limb_m),
        "elbow": (("upper_arm", "forearm"), limb_m),
        "wrist": (("forearm",), limb_m),  # the hand is the forearm's end
        "hip": (("thigh_upper",), hip_m),
        "knee": (("thigh_lower", "shank_upper"), limb_m),
        "ankle": (("shank_lower",), limb_m),  # the foot hangs on the shank
    }
    for joint, (parts, radius) in limbs.items():
        for side in "lr":
            table[f"{side}_{joint}"] = (tuple(f"{side}_{p}" for p in parts), radius)
    return {name: table[name] for name in JOINT_NAMES}


# Named joint -> (the parts that meet at it, radius in metres): a joint is seen where enough
# of those parts' surface lies within the radius of it (the evaluation's ground-truth
# visibility, train.evaluation.visibility, and the runtime's observed joints,
# runtime.tracker.joint_support).
JOINT_PARTS: dict[str, tuple[tuple[str, ...], float]] = _joint_parts()
