"""Label term (not in Wei): observed limb pixels pull the surface of the limb the forest names.

Wei's data terms match observed points to whatever model surface is nearest, so a limb the
model has in the wrong place (an arm slipped behind the torso in profile, a hidden leg) is
never pulled back: its real pixels are explained by the torso turned a little. The forest's
per-pixel part labels, which the hybrid computes anyway for the detector, say which limb a
pixel belongs to. Each labelled limb pixel p gives one row with the closest point x on that
limb's capsule: the residual is p's signed distance to the capsule (> 0 outside) and the
direction the unit vector from the capsule's axis towards p, so ``g^T dx/dq dq = r`` moves x
onto p (point-to-surface ICP with the correspondences fixed by the labels). Torso and head
labels add little the depth terms lack and are not used. Labels are noisy (left/right swaps,
part borders): pixels farther than ``LABEL_GATE_M`` from their limb are ignored, and at
most ``MAX_LABEL_PIXELS`` of them are used, weighted like the other terms' samples.
"""

from __future__ import annotations

import torch
from depthmocap.runtime.raycast import SegmentGeometry, capsule_signed_distance
from depthmocap.shared.compiled import compiled_float32
from depthmocap.shared.kinematics import Kinematics

from .config import TrackerConfig
from .gauss_newton import Rows
from .observation import Observation, label_term_pixels
from .regions import sample_pixels

__all__ = ["LABEL_GATE_M", "MAX_LABEL_PIXELS", "capsule_offsets", "label_rows"]

# Labelled pixels farther than this from their limb's surface are ignored (m): a left/right
# swap of the forest must not drag a limb across the body.
LABEL_GATE_M = 0.15
# At most this many labelled limb pixels per frame (a fixed-lattice subsample), for speed;
# each kept pixel is weighed for the ones it stands for, so the cap does not shift the
# balance between the terms.
MAX_LABEL_PIXELS = 300


def capsule_offsets(
    points: torch.Tensor,
    rot: torch.Tensor,
    origin: torch.Tensor,
    basis: torch.Tensor,
    span: torch.Tensor,
    scale: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Signed distance of each point to its own capsule, and the direction from the capsule's
    axis to the point (:func:`runtime.raycast.capsule_signed_distance` for one capsule per
    point).

    Args:
        points: (N, 3) camera-frame points.
        rot, origin: (N, 3, 3), (N, 3) each point's capsule frame
            (:meth:`runtime.raycast.SegmentGeometry.frames`).
        basis, span, scale: (N, 3, 3), (N, 2), (N, 3) that capsule's
            :class:`~runtime.raycast.SegmentGeometry` entries.
    Returns:
        signed (N,) metres, > 0 outside; direction (N, 3) unit, camera frame.
    """
    local = ((points - origin)[:, None, :] @ rot)[:, 0]
    coords = (basis @ local[..., None])[..., 0]
    signed, offset = capsule_signed_distance(coords, span, scale)
    unit = offset / offset.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    direction = (rot @ (basis.transpose(-1, -2) @ unit[..., None]))[..., 0]
    return signed, direction


def label_rows(
    kin: Kinematics, geom: SegmentGeometry, obs: Observation, cfg: TrackerConfig
) -> Rows:
    """Label-term rows for a subsample of the labelled limb pixels of ``obs`` (needs
    ``obs.labels``; no rows without it)."""
    labels = obs.labels if obs.labels is not None else torch.full_like(obs.depth, -1).long()
    use = label_term_pixels(obs)
    kernel = compiled_float32("depthmocap.runtime.tracker.label_kernel", obs.points, kin.origins)
    if obs.labels is not None and kernel is not None:  # one compiled call, the same rows
        return Rows(
            *kernel.label_rows_cpu(
                kin, geom, obs, use, MAX_LABEL_PIXELS, LABEL_GATE_M, cfg.sigma_label_m
            )
        )
    idx, _, ratio = sample_pixels(use, MAX_LABEL_PIXELS)
    b, v, u = idx.unbind(1)
    points, segment = obs.points[b, v, u], labels[b, v, u]
    rot, origin = geom.frames(kin)
    span = geom.span.expand(kin.origins.shape[0], -1, -1)[b, segment]
    scale = geom.scale.expand(kin.origins.shape[0], -1, -1)[b, segment]
    signed, direction = capsule_offsets(
        points, rot[b, segment], origin[b, segment], geom.basis[segment], span, scale
    )
    surface = points - signed[:, None] * direction
    keep = (signed.abs() < LABEL_GATE_M).to(points.dtype)
    weight = keep * (ratio**0.5 / cfg.sigma_label_m).to(points.dtype)
    return Rows(b, surface, segment, direction, signed, weight)
