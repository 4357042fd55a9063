"""Static surfaces seen behind the tracked body are not the person: furniture in the mask.

The segmentation keeps what touches the person at a smooth depth step. A chair or stool the
person stands in front of, sits on or gets up from meets the thighs in a ramp of a few
centimetres per pixel and stays in the person's mask (real Kinect depth, UTD-MHAD sit to stand
and stand to sit, whose background removal keeps the chair). The tracker then pulls the legs
into it, the detector fits it as legs and the size search sizes the person larger to cover
it. Removed by an oracle from the Kinect SDK's skeleton, those two actions' agreement went
97.1 -> 74.7 and 85.8 -> 62.7 mm (``docs/experiments.md``, twenty-seventh session).

What marks such a surface without any reference: a camera sees the front of the body, so a
body point it sees lies at most about a limb's radius behind the axis of the body part it
belongs to, never ``behind_m`` behind the nearest one; and a piece of furniture does not move.
A mask pixel is dropped once it has been both, behind the last tracked pose's nearest segment
axis by more than ``behind_m`` and at the same depth (within ``static_tol_m``), for
``static_frames`` frames in a row. A limb the model has lost lies beside or in front of the
model's other parts, not far behind them, and moves; a far leg in a side view lies behind the
near one but moves with the walk. Nothing is dropped without a track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics, masked_points
from depthmocap.shared.compiled import compiled_module
from depthmocap.shared.config import ConfigError, field_doc
from depthmocap.shared.kinematics import Kinematics, segment_axis_points

__all__ = ["BehindModelConfig", "StaticBehindMask", "depth_behind_axes", "segment_axes"]


@dataclass
class BehindModelConfig:
    """Dropping static surfaces seen far behind the tracked body (module docstring)."""

    behind_m: float = field_doc(
        0.12,
        "a pixel counts as behind the body when it lies this much farther from the camera than "
        "the closest point of the nearest segment axis of the last tracked pose (m): a seen "
        "body point lies in front of its own axis, and up to a limb's radius (5-8 cm) behind "
        "a neighbouring one, plus the tracker's few centimetres of error. 0.2 caught little of "
        "a chair the model's legs had already been drawn towards (docs/experiments.md)",
    )
    static_frames: int = field_doc(
        5, "frames in a row a pixel must be behind and at the same depth before it is dropped"
    )
    static_tol_m: float = field_doc(
        0.03, "depth change between frames (m) up to which a pixel counts as the same surface"
    )

    def __post_init__(self) -> None:
        ok = (
            math.isfinite(self.behind_m) and self.behind_m > 0
            and math.isfinite(self.static_tol_m) and self.static_tol_m > 0
            and self.static_frames >= 1
        )  # fmt: skip
        if not ok:
            raise ConfigError(
                "behind_model: behind_m and static_tol_m must be positive and finite and "
                f"static_frames at least 1, got {self.behind_m}, {self.static_tol_m}, "
                f"{self.static_frames}"
            )


def segment_axes(kin: Kinematics) -> tuple[torch.Tensor, torch.Tensor]:
    """Both ends of every segment's axis in the camera frame: (B, S, 3) each."""
    seg = torch.arange(sk.NUM_SEGMENTS, device=kin.origins.device)
    zero = torch.zeros(sk.NUM_SEGMENTS, dtype=kin.origins.dtype, device=kin.origins.device)
    return segment_axis_points(kin, seg, zero), segment_axis_points(kin, seg, zero + 1.0)


def depth_behind_axes(points: torch.Tensor, start: torch.Tensor, end: torch.Tensor) -> torch.Tensor:
    """How far each point lies behind (along the camera's z) the closest point of the nearest
    segment axis.

    Args:
        points: (N, 3) camera-frame points; start, end: (S, 3) the axes' ends.
    Returns:
        (N,) metres, z of the point minus z of that axis point (negative: in front of it).
    """
    axis = end - start  # (S, 3)
    length2 = (axis * axis).sum(-1).clamp_min(1e-12)  # (S,)
    t = (((points[:, None] - start[None]) * axis[None]).sum(-1) / length2).clamp(0.0, 1.0)
    closest = start[None] + t[..., None] * axis[None]  # (N, S, 3)
    nearest = (points[:, None] - closest).norm(dim=-1).argmin(1)  # (N,)
    rows = torch.arange(len(points), device=points.device)
    return points[:, 2] - closest[rows, nearest, 2]


class StaticBehindMask:
    """Per-pixel memory of a stream: how long each pixel has been behind the body and still.

    Args:
        cfg: the thresholds.
    """

    def __init__(self, cfg: BehindModelConfig, compiled: bool = True) -> None:
        self.cfg = cfg
        self.compiled = compiled  # False: the torch code even where numba is installed
        self._depth: torch.Tensor | None = None  # (H, W) the last frame's depth
        self._count: torch.Tensor | None = None  # (H, W) int32 frames behind and still

    def reset(self) -> None:
        """Forget the stream (a new one, or a lost track)."""
        self._depth = self._count = None

    def update(
        self, depth_m: torch.Tensor, mask: torch.Tensor, kin: Kinematics | None, intr: Intrinsics
    ) -> torch.Tensor:
        """Count this frame and return the mask pixels to drop: (H, W) bool.

        Args:
            depth_m: (H, W) metres; mask: (H, W) bool person pixels; kin: the last tracked
                pose (batch 1), or None without a track (nothing is counted or dropped).
        """
        if kin is None:
            self.reset()
            return torch.zeros_like(mask)
        start, end = (a[0] for a in segment_axes(kin))
        cfg = self.cfg
        kernel = None
        if self.compiled and depth_m.device.type == "cpu" and depth_m.dtype == torch.float32:
            kernel = compiled_module("depthmocap.runtime.hybrid.behind_kernel")
        if kernel is not None:
            count, drop = kernel.behind_update_cpu(
                depth_m, mask, self._depth, self._count, start.detach(), end.detach(), intr,
                cfg.behind_m, cfg.static_tol_m, cfg.static_frames,
            )  # fmt: skip
        else:
            count, drop = self._update_torch(depth_m, mask, start.detach(), end.detach(), intr)
        # The frame's depth is never written to, so it is kept, not copied.
        self._depth, self._count = depth_m, count
        return drop

    def _update_torch(self, depth_m, mask, start, end, intr) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`update`'s count and drop in torch ops (GPUs, CPUs without numba)."""
        cfg = self.cfg
        count = torch.zeros_like(mask, dtype=torch.int32)
        if self._depth is None or self._depth.shape != depth_m.shape:
            return count, torch.zeros_like(mask)
        still = (depth_m.double() - self._depth.double()).abs() <= cfg.static_tol_m
        candidates = mask & still
        behind = torch.zeros_like(mask)
        if candidates.any():
            points = masked_points(depth_m.double(), candidates, intr)
            far = depth_behind_axes(points, start.double(), end.double()) > cfg.behind_m
            behind[candidates] = far
        before = self._count
        if before is not None and before.shape == mask.shape:
            count = torch.where(behind, before + 1, count)
        else:
            count = behind.to(torch.int32)
        return count, count >= cfg.static_frames
