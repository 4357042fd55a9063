"""Failure signals of a tracked frame (Wei section 5) and the surface error (Helten IV).

- ``depth_error_cm``: mean absolute residual of the depth and extra depth terms, the hybrid's
  epsilon1 signal (Wei: switch to the detector above 2.5 cm). It averages |observed - rendered
  depth| over G and the 3D distance to the matched point over the extra term's query pixels
  (B1, B2, B3); a query without an eligible match counts as the depth gate (8 cm), so a lost
  track approaches 8 cm instead of hiding behind the gates. No data pixel at all gives 8 cm.
- ``overlap``: |R and O| / |R or O| of rendered and observed silhouettes (epsilon2 = 90%);
  0 when both are empty.
- ``surface_error_q97_mm``: 97% quantile of the distances from observed foreground points
  to the model surface (approximate point-to-capsule distance, see
  :func:`runtime.raycast.surface_distance`); 0 without observed points.
- ``limb_visibility``: how much of each limb the model shows at its pose (not a failure
  test: it tells the hybrid which limbs the data cannot be checking).
- ``joint_support_cm2``: the surface area near each named joint that the depth image
  confirms (:mod:`runtime.tracker.joint_support`): observed against inferred joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from depthmocap.runtime.raycast import BodyRender, surface_distance
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics

from .config import TrackerConfig
from .depth_term import depth_error_sum
from .extra_depth_term import ExtraResult
from .joint_support import joint_support_cm2
from .observation import Observation
from .regions import Regions, batch_slots, sample_pixels

__all__ = [
    "LIMB_SEGMENTS",
    "MAX_SURFACE_POINTS",
    "SURFACE_LEVEL",
    "FitSignals",
    "FrameSignals",
    "depth_error_cm",
    "frame_signals",
    "limb_visibility",
    "overlap",
    "surface_error_quantile",
]

# The surface-error quantile is taken over at most this many observed points (a strided
# subsample), for speed: each point costs a distance to every capsule of every pose.
MAX_SURFACE_POINTS = 600
# The surface error is this quantile of those points' distances (Wei's epsilon3 reads the 97%).
SURFACE_LEVEL = 0.97

# The segments of each limb, in the order of ``limb_visibility``: left arm, right arm (upper
# arm, forearm with hand), left leg, right leg (thigh, shank with foot).
LIMB_SEGMENTS: tuple[tuple[int, int], ...] = tuple(
    (sk.SEGMENT_NAMES.index(f"{side}_{upper}"), sk.SEGMENT_NAMES.index(f"{side}_{lower}"))
    for upper, lower in (("upper_arm", "forearm"), ("thigh", "shank"))
    for side in "lr"
)


@dataclass(frozen=True)
class FitSignals:
    """One fit's three failure signals (what the hybrid's tests and comparisons read).

    Attributes:
        depth_error_cm: mean depth / extra-depth residual (cm), Wei's epsilon1 signal.
        overlap: |R and O| / |R or O| of the rendered and observed silhouettes (epsilon2).
        surface_error_q97_mm: 97% quantile of observed points' distances to the model (mm).
    """

    depth_error_cm: float
    overlap: float
    surface_error_q97_mm: float

    def as_errors(self, prefix: str = "") -> dict[str, float]:
        """The signals as a result file's ``errors`` entries (keys optionally prefixed)."""
        return {
            f"{prefix}depth_error_cm": float(self.depth_error_cm),
            f"{prefix}overlap": float(self.overlap),
            f"{prefix}surface_error_q97_mm": float(self.surface_error_q97_mm),
        }


@dataclass
class FrameSignals:
    """Per-pose signals, each (B,); ``limb_visibility`` (B, 4); ``joint_support_cm2`` (B, J)."""

    depth_error_cm: torch.Tensor
    overlap: torch.Tensor
    surface_error_q97_mm: torch.Tensor
    limb_visibility: torch.Tensor
    joint_support_cm2: torch.Tensor


def overlap(rendered: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
    """Intersection over union of two (B, H, W) bool silhouettes: (B,), 0 if both empty."""
    inter = (rendered & observed).sum((1, 2))
    union = (rendered | observed).sum((1, 2))
    return inter.double() / union.clamp_min(1).double()


def surface_error_quantile(
    obs: Observation,
    render: BodyRender,
    body: BodyShape,
    max_points: int,
    level: float = SURFACE_LEVEL,
) -> torch.Tensor:
    """``level`` quantile (mm) of observed points' distances to the model surface: (B,)."""
    B = obs.depth.shape[0]
    shared = B == 1 or obs.valid.stride(0) == 0  # one frame, or one frame's batch of views
    idx, _, _ = sample_pixels(obs.valid[:1] if shared else obs.valid, max_points)
    if idx.shape[0] == 0:
        return obs.depth.new_zeros(B, dtype=torch.float64)
    b, v, u = idx.unbind(1)
    real = None  # every pose samples the same points (the cap is per mask): no padding
    if shared:
        pts = obs.points[0, v, u].expand(B, -1, -1)
    else:
        slot, real = batch_slots(b, B)  # each pose's own points only: (B, K)
        pts = obs.points[b, v, u][slot]
    dist = surface_distance(pts, render.kin, body, render.geom)  # (B, K)
    if real is not None:
        dist = torch.where(real, dist, torch.full_like(dist, float("nan")))
    q = torch.nanquantile(dist.double(), level, dim=1) * 1e3
    return torch.nan_to_num(q, nan=0.0)


def frame_signals(
    render: BodyRender,
    obs: Observation,
    regions: Regions,
    extra: ExtraResult,
    body: BodyShape,
    cfg: TrackerConfig,
) -> FrameSignals:
    """The three signals for the poses ``render`` was cast at."""
    return FrameSignals(
        depth_error_cm(regions, extra, cfg),
        overlap(render.mask, obs.silhouette),
        surface_error_quantile(obs, render, body, MAX_SURFACE_POINTS),
        limb_visibility(render, obs.intr, body),
        joint_support_cm2(render, regions, obs.intr, obs.labels),
    )


def depth_error_cm(regions: Regions, extra: ExtraResult, cfg: TrackerConfig) -> torch.Tensor:
    """Wei's epsilon1 signal (module docstring), (B,) float64 centimetres."""
    err, n = depth_error_sum(regions)
    total = err.double() + extra.error_sum.double()
    count = n.double() + extra.count.double()
    mean = torch.where(
        count > 0, total / count.clamp_min(1e-9), torch.full_like(total, cfg.depth_gate_m)
    )
    return mean * 100.0


def limb_visibility(render: BodyRender, intr: Intrinsics, body: BodyShape) -> torch.Tensor:
    """Visible fraction of each limb in the rendering: (B, 4) in ``LIMB_SEGMENTS`` order.

    The limb's rendered pixels (where it is the front-most segment) over the area it would
    cover seen side-on, unoccluded, at its segments' mid-points: sum of 2 r L fx fy / z^2
    (r: mean cross-section radius). About 1 for a limb in plain view (a little more: the
    hand and foot caps), near 0 for one hidden behind the torso; foreshortening (a limb
    pointing at the camera) also lowers it.

    Args:
        render: B poses rendered with ``intr`` (the working resolution).
        intr: intrinsics of the rendering.
        body: the body rendered (unbatched).
    """
    seg = render.segment.reshape(render.segment.shape[0], -1)
    B, S = seg.shape[0], sk.NUM_SEGMENTS
    # Integer counts from a broadcast one: a float64 ones image of the batch's window cost
    # six times the count (the arm search's 8 poses: 3.0 -> 0.5 ms); exact in float64.
    pixels = seg.new_zeros(B, S + 1)
    pixels.scatter_add_(1, seg + 1, seg.new_ones(()).expand(seg.shape))
    pixels = pixels.double()
    kin = render.kin
    axis = torch.as_tensor(sk.SEGMENT_AXIS, dtype=kin.origins.dtype, device=seg.device)
    half = (kin.rotations @ axis[None, :, :, None])[..., 0] * (kin.lengths[..., None] / 2)
    z = (kin.origins + half)[..., 2].clamp_min(0.1)
    radius = body.radii.to(z).mean(-1)
    area = (2 * radius * kin.lengths * intr.fx * intr.fy / z**2).double()
    limbs = torch.as_tensor(LIMB_SEGMENTS, device=seg.device)  # (4, 2)
    seen = pixels[:, 1:][:, limbs].sum(-1)
    return seen / area[:, limbs].sum(-1).clamp_min(1e-9)
