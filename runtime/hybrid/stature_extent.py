"""The person's stature read off the silhouette of an upright frame: a check on the size search.

The size search (:mod:`runtime.hybrid.body_scale`) sizes the body whose refits cover the
silhouette best. Whatever else is in the mask and hugs the body draws it too large: a seated
person's lap and chair (real Kinect depth, UTD-MHAD sit to stand: 0.08-0.11 above the same
person's size in the other actions), and frames that come later cannot undo it, since their
refits start from poses already bent to the wrong body. The person's extent along their own
torso axis, head top to soles, measured on frames where they stand upright with the hands
below the head, does not see the chair (it lies between the feet and the head) and depends on
no fit: for each of UTD-MHAD's four people its medians over all twelve actions, seated ones
included, span 2-3.5%. On rendered people it gives the stature within 1.6% on average
(the search: 2.9%). Its ratio is taken against the body the search finds there, so the two
agree in the median on renders, and the search keeps its size unless they disagree by more
than the rendered people's 99th percentile, either way (``BodyScaleConfig.extent_check``).
On real depth the search also errs large for people who stand throughout: a silhouette
widened by clothing and the sensor's edges is covered best by a body too tall
(``BodyScaleConfig.extent_sizes``).
"""

from __future__ import annotations

import numpy as np
import torch
from depthmocap.shared.camera import Intrinsics, masked_points
from depthmocap.shared.skeleton import JOINT_NAMES

from .body_scale import fold_angle_deg

__all__ = ["EXTENT_QUANTILE", "is_upright", "torso_extent", "upright_extent"]

# The extent runs between these quantiles of the points' heights: flying pixels and stray
# bits of the mask at either end must not set it.
EXTENT_QUANTILE = 0.002

_NECK, _PELVIS, _HEAD = (JOINT_NAMES.index(n) for n in ("neck", "pelvis", "head"))
_WRISTS = [JOINT_NAMES.index("l_wrist"), JOINT_NAMES.index("r_wrist")]


def _torso_up(joints: np.ndarray) -> np.ndarray:
    """(..., 3) unit vectors from the pelvis to the neck of (..., J, 3) joints."""
    up = joints[..., _NECK, :] - joints[..., _PELVIS, :]
    return up / np.linalg.norm(up, axis=-1, keepdims=True)


def is_upright(joints: np.ndarray, max_fold_deg: float = 20.0) -> np.ndarray:
    """Whether a pose stands at its full height: a thigh within ``max_fold_deg`` of the
    torso's line (:func:`~runtime.hybrid.body_scale.fold_angle_deg`: one leg may be raised,
    the other carries the person's height) and both wrists below the head along that line.
    The knees are not read: a body tracked too large bends its knees while the person
    stands straight, and that is the body the check exists for.

    Args:
        joints: (..., J, 3) named joints (``shared.skeleton.JOINT_NAMES`` order).

    Returns:
        (...,) bool; False where a bone has zero length.
    """
    j = np.asarray(joints, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        up = _torso_up(j)
        head = (j[..., _HEAD, :] * up).sum(-1)
        hands_low = ((j[..., _WRISTS, :] * up[..., None, :]).sum(-1) < head[..., None]).all(-1)
        return (fold_angle_deg(j) <= max_fold_deg) & hands_low


def torso_extent(points: torch.Tensor, joints: np.ndarray) -> float:
    """The span of the person's points along their torso's line (pelvis to neck), between the
    :data:`EXTENT_QUANTILE` quantiles at either end: head top to soles on an upright frame.

    Args:
        points: (N, 3) the person's camera-frame points, metres.
        joints: (J, 3) the frame's named joints, which give the torso's line.

    Returns:
        Metres; NaN without points or with a degenerate torso.
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        up = _torso_up(np.asarray(joints, dtype=np.float64))
    up = torch.as_tensor(up, dtype=points.dtype)
    if points.shape[0] == 0 or not bool(torch.isfinite(up).all()):
        return float("nan")
    heights = points @ up.to(points.device)
    q = heights.new_tensor([EXTENT_QUANTILE, 1.0 - EXTENT_QUANTILE])
    lo, hi = torch.quantile(heights, q).tolist()
    return hi - lo


def upright_extent(
    depth_m: torch.Tensor, mask: torch.Tensor, intr: Intrinsics, joints: np.ndarray
) -> float:
    """The person's :func:`torso_extent` on a frame that shows their full height: the pose is
    upright (:func:`is_upright`) and the mask reaches neither the top nor the bottom row of
    the image (a head or feet cut by the frame's edge would shorten it).

    Args:
        depth_m: (H, W) metric depth; mask: (H, W) bool, the person's pixels.
        intr: the image's intrinsics; joints: (J, 3) the frame's named joints.

    Returns:
        Metres; NaN where the frame does not show it.
    """
    if not bool(is_upright(joints)) or not bool(mask.any()):
        return float("nan")
    if bool(mask[0].any()) or bool(mask[-1].any()):
        return float("nan")
    return torso_extent(masked_points(depth_m, mask, intr), joints)
