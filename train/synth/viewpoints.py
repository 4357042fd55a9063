"""Camera viewpoints for synthetic training frames.

World frame of a training frame: metres, y up, floor at y = 0, the person's root at the origin
horizontally (x = z = 0), the person facing +z (so +x is the person's left, as in
``shared.skeleton``'s body frame). Cameras use the OpenCV convention (x right, y down,
z forward). Every sampler returns ``cam_from_world``, the 4x4 rigid transform with
``p_cam = R p_world + t``.

A viewpoint is drawn as:

- horizontal distance d from the person's vertical axis, uniform in
  [``distance_min``, ``distance_max``];
- camera height h above the floor, uniform in [``height_min``, ``height_max``];
- person yaw psi: the angle, about +y, from the person's facing direction to the direction from
  the person to the camera (psi = 0: the camera sees the front; +90 deg: the person's left side;
  180 deg: the back). A three-way mixture: front (|psi| <= ``front_half_angle_deg``), sides,
  back (|psi| >= 180 - ``back_half_angle_deg``), uniform within each, with weights
  ``front_weight``, ``side_weight``, ``back_weight``. The camera sits at
  ``(d sin psi, h, d cos psi)``;
- aim: the camera looks at the point ``(0, target_height, 0)`` (about the body's centre), then
  turns by small uniform yaw and pitch jitters (``aim_jitter_deg``) and rolls about its optical
  axis by at most ``roll_max_deg``. The pitch needed to look at the target follows from h, d
  and the target height (up to about 30 deg at the nearest, highest settings).

With 1.5 m as the nearest distance a tall person does not fit into a Kinect's field of view
(about 43 deg vertically); :func:`fits_in_view` tells, and :func:`sample_viewpoint_in_view`
redraws until a given point set (the posed body) fits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from depthmocap.shared.camera import Intrinsics, points_to_pixels
from depthmocap.shared.config import field_doc
from depthmocap.train.mocap.clip import axis_rotation

__all__ = [
    "ViewpointConfig",
    "Viewpoints",
    "sample_person_yaw",
    "look_at",
    "sample_viewpoints",
    "transform_points",
    "fits_in_view",
    "sample_viewpoint_in_view",
]


@dataclass
class ViewpointConfig:
    """Ranges of the camera viewpoints of synthetic training frames (see module docstring)."""

    distance_min: float = field_doc(
        1.5, "nearest horizontal distance from the person's vertical axis to the camera, metres"
    )
    distance_max: float = field_doc(
        4.0, "farthest horizontal distance from the person's vertical axis to the camera, metres"
    )
    height_min: float = field_doc(0.6, "lowest camera height above the floor, metres")
    height_max: float = field_doc(1.8, "highest camera height above the floor, metres")
    front_weight: float = field_doc(
        0.6, "probability of a frontal view (|yaw| <= front_half_angle_deg)"
    )
    side_weight: float = field_doc(0.25, "probability of a side view (between front and back)")
    back_weight: float = field_doc(
        0.15, "probability of a back view (|yaw| >= 180 - back_half_angle_deg)"
    )
    front_half_angle_deg: float = field_doc(
        45.0, "half-width of the frontal yaw sector around 0 deg (person facing the camera)"
    )
    back_half_angle_deg: float = field_doc(
        45.0, "half-width of the back yaw sector around 180 deg (person facing away)"
    )
    target_height: float = field_doc(
        0.9, "height above the floor of the point the camera aims at (about the body centre), m"
    )
    aim_jitter_deg: float = field_doc(
        3.0, "uniform jitter of the aim direction in yaw and in pitch, +- degrees"
    )
    roll_max_deg: float = field_doc(5.0, "uniform camera roll about its optical axis, +- degrees")

    def validate(self) -> None:
        """Raise ``ValueError`` on empty ranges, negative weights or overlapping sectors."""
        if not 0.0 < self.distance_min <= self.distance_max:
            raise ValueError(
                f"need 0 < distance_min <= distance_max, got "
                f"{self.distance_min}, {self.distance_max}"
            )
        if not self.height_min <= self.height_max:
            raise ValueError(
                f"need height_min <= height_max, got {self.height_min}, {self.height_max}"
            )
        weights = (self.front_weight, self.side_weight, self.back_weight)
        if min(weights) < 0.0 or sum(weights) <= 0.0:
            raise ValueError(f"yaw weights must be >= 0 with a positive sum, got {weights}")
        if not (
            0.0 <= self.front_half_angle_deg
            and 0.0 <= self.back_half_angle_deg
            and self.front_half_angle_deg + self.back_half_angle_deg <= 180.0
        ):
            raise ValueError(
                "need front_half_angle_deg, back_half_angle_deg >= 0 with a sum <= 180, got "
                f"{self.front_half_angle_deg}, {self.back_half_angle_deg}"
            )
        if self.aim_jitter_deg < 0.0 or self.roll_max_deg < 0.0:
            raise ValueError("aim_jitter_deg and roll_max_deg must be >= 0")


class Viewpoints(NamedTuple):
    """A batch of N sampled viewpoints.

    Attributes:
        cam_from_world: (N, 4, 4) float64, ``p_cam = T[:3, :3] p_world + T[:3, 3]``.
        position: (N, 3) camera centre in the world frame, metres.
        distance: (N,) horizontal distance to the person's axis, metres.
        height: (N,) camera height above the floor, metres.
        yaw: (N,) person yaw relative to the camera in (-pi, pi), radians (0 = front view).
        roll: (N,) camera roll about its optical axis, radians.
    """

    cam_from_world: np.ndarray
    position: np.ndarray
    distance: np.ndarray
    height: np.ndarray
    yaw: np.ndarray
    roll: np.ndarray


def sample_person_yaw(rng: np.random.Generator, n: int, cfg: ViewpointConfig) -> np.ndarray:
    """Person yaw relative to the camera from the front/side/back mixture.

    Returns:
        (n,) radians in (-pi, pi); 0 = camera in front of the person.
    """
    weights = np.array([cfg.front_weight, cfg.side_weight, cfg.back_weight], dtype=np.float64)
    sector = rng.choice(3, size=n, p=weights / weights.sum())
    front = math.radians(cfg.front_half_angle_deg)
    back_start = math.pi - math.radians(cfg.back_half_angle_deg)
    # |yaw| ranges of the three sectors; the sign (left/right) is drawn separately.
    low = np.array([0.0, front, back_start])[sector]
    high = np.array([front, back_start, math.pi])[sector]
    magnitude = rng.uniform(low, high)
    sign = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    return sign * magnitude


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """OpenCV ``cam_from_world`` transforms of cameras at ``eye`` looking at ``target``.

    No roll: the camera's x axis (image right) is horizontal, and its y axis (image down)
    points away from world ``up``.

    Args:
        eye: (N, 3) camera centres.
        target: (N, 3) or (3,) points to look at.
        up: (3,) world up; default +y.
    Returns:
        (N, 4, 4) float64.
    """
    eye = np.asarray(eye, dtype=np.float64)
    up = np.array([0.0, 1.0, 0.0]) if up is None else np.asarray(up, dtype=np.float64)
    forward = np.broadcast_to(np.asarray(target, dtype=np.float64), eye.shape) - eye
    forward = forward / np.linalg.norm(forward, axis=-1, keepdims=True)
    # right = forward x up, down = forward x right: a right-handed x-right, y-down, z-forward
    # frame. (Looking straight up or down is degenerate; the samplers never do.)
    right = np.cross(forward, up)
    right = right / np.linalg.norm(right, axis=-1, keepdims=True)
    down = np.cross(forward, right)
    rot = np.stack([right, down, forward], axis=-2)  # rows: camera axes in world coordinates
    out = np.zeros(eye.shape[:-1] + (4, 4))
    out[..., :3, :3] = rot
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rot, eye)
    out[..., 3, 3] = 1.0
    return out


def sample_viewpoints(
    rng: np.random.Generator,
    n: int,
    cfg: ViewpointConfig | None = None,
    target_height: float | None = None,
) -> Viewpoints:
    """Draw ``n`` camera viewpoints around a person standing at the world origin.

    Args:
        rng: source of randomness (the result is a pure function of its state).
        n: number of viewpoints.
        cfg: ranges; defaults to :class:`ViewpointConfig`'s.
        target_height: aim height above the floor for this person (e.g. the pelvis height of
            the posed body); defaults to ``cfg.target_height``.
    Returns:
        :class:`Viewpoints` with (N, ...) arrays.
    """
    cfg = ViewpointConfig() if cfg is None else cfg
    cfg.validate()
    distance = rng.uniform(cfg.distance_min, cfg.distance_max, n)
    height = rng.uniform(cfg.height_min, cfg.height_max, n)
    yaw = sample_person_yaw(rng, n, cfg)
    jitter = math.radians(cfg.aim_jitter_deg)
    aim_yaw = rng.uniform(-jitter, jitter, n)
    aim_pitch = rng.uniform(-jitter, jitter, n)
    roll_max = math.radians(cfg.roll_max_deg)
    roll = rng.uniform(-roll_max, roll_max, n)

    position = np.stack([distance * np.sin(yaw), height, distance * np.cos(yaw)], axis=-1)
    aim = cfg.target_height if target_height is None else float(target_height)
    cam_from_world = look_at(position, np.array([0.0, aim, 0.0]))
    # Jitter and roll act in the camera frame: turn about the camera's own y (yaw), then x
    # (pitch), then z (roll); the camera centre stays where it is.
    turn = axis_rotation("z", roll) @ axis_rotation("x", aim_pitch) @ axis_rotation("y", aim_yaw)
    cam_from_world[:, :3, :] = turn @ cam_from_world[:, :3, :]
    return Viewpoints(cam_from_world, position, distance, height, yaw, roll)


def transform_points(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply rigid 4x4 transforms.

    Args:
        transform: (..., 4, 4).
        points: (..., P, 3), broadcast against ``transform``'s batch dimensions.
    Returns:
        (..., P, 3).
    """
    transform = np.asarray(transform)
    # matmul, not einsum: einsum's generic loop is ~10x slower for these shapes.
    return points @ np.swapaxes(transform[..., :3, :3], -1, -2) + transform[..., None, :3, 3]


def fits_in_view(
    points_cam: np.ndarray | torch.Tensor,
    intrinsics: Intrinsics,
    margin_px: float = 0.0,
    min_depth: float = 0.0,
    max_depth: float = float("inf"),
) -> np.ndarray:
    """Whether all points project inside the image, at least ``margin_px`` from its border.

    Projection is :func:`shared.camera.points_to_pixels`; the image spans
    [-0.5, W - 0.5] x [-0.5, H - 0.5] in its pixel coordinates (pixel centres at integers).

    Args:
        points_cam: (..., P, 3) camera-frame points (numpy or torch).
        intrinsics: the camera.
        margin_px: required distance from the image border, pixels.
        min_depth: points must also lie farther than this along z (e.g. the renderer's znear).
        max_depth: and nearer than this (e.g. the sensor's range, so no part goes unseen).
    Returns:
        (...) bool numpy array (a 0-d array for a single point set).
    """
    points = torch.as_tensor(points_cam)
    if not points.is_floating_point():
        points = points.to(torch.float64)
    if points.ndim < 2 or points.shape[-1] != 3:
        raise ValueError(f"points_cam must be (..., P, 3), got {tuple(points.shape)}")
    z = points[..., 2]
    in_front = z > max(min_depth, 0.0)
    # Points behind the camera give non-finite or mirrored pixels: project them from z = 1.
    uv = points_to_pixels(
        torch.where(in_front[..., None], points, torch.ones_like(points)), intrinsics
    )
    lo = margin_px - 0.5
    inside = (
        in_front
        & (z < max_depth)
        & (uv[..., 0] >= lo)
        & (uv[..., 0] <= intrinsics.width - 0.5 - margin_px)
        & (uv[..., 1] >= lo)
        & (uv[..., 1] <= intrinsics.height - 0.5 - margin_px)
    )
    return inside.all(dim=-1).cpu().numpy()


def sample_viewpoint_in_view(
    rng: np.random.Generator,
    points_world: np.ndarray,
    intrinsics: Intrinsics,
    cfg: ViewpointConfig | None = None,
    margin_px: float = 2.0,
    min_depth: float = 0.5,
    target_height: float | None = None,
    max_tries: int = 64,
    max_depth: float = float("inf"),
) -> Viewpoints | None:
    """One viewpoint from which all ``points_world`` (e.g. the posed body's vertices) are seen.

    Draws ``max_tries`` candidates in one batch (vectorized) and keeps the first that fits.

    Args:
        points_world: (P, 3) points in the world frame.
        max_depth: every point must also lie nearer than this along the camera's z (m).
    Returns:
        :class:`Viewpoints` with N = 1, or ``None`` when no candidate fits (e.g. a configured
        distance range too short for the field of view).
    """
    views = sample_viewpoints(rng, max_tries, cfg, target_height)
    points_cam = transform_points(views.cam_from_world, np.asarray(points_world)[None])
    ok = fits_in_view(points_cam, intrinsics, margin_px, min_depth, max_depth)
    if not ok.any():
        return None
    i = int(np.argmax(ok))
    return Viewpoints(*(field[i : i + 1] for field in views))
