"""A simple background scene for rendered body frames: a floor, a back wall, boxes (and
vertical cylinders: the round seats and legs of the furniture drawn against people).

:func:`add_floor_and_background` is a pure helper for the renderer: it fills the background of a
rendered body frame with a floor plane, optionally a back wall and a few boxes standing on the
floor, with proper occlusion (a box in front of the body hides it and its labels become 0).
Call it before :func:`shared.sensor_noise.kinect.apply_kinect_noise`, so that the body casts
its projector shadow onto the background as it does in real frames.

Numpy only and vectorized (loops run over boxes, never over pixels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import field_doc
from depthmocap.shared.sensor_noise.kinect import check_depth_image

__all__ = [
    "BackgroundBox",
    "BackgroundConfig",
    "BackgroundCylinder",
    "BackgroundScene",
    "add_floor_and_background",
    "box_depth",
    "cylinder_depth",
    "floor_depth",
    "level_from_camera",
    "random_background_scene",
    "wall_depth",
]


@dataclass
class BackgroundConfig:
    """Random background scenes for :func:`random_background_scene`."""

    wall_prob: float = field_doc(0.7, "probability that a back wall is present")
    wall_distance_m: tuple[float, float] = field_doc(
        (3.0, 6.0), "range of the wall's horizontal distance from the camera (m)"
    )
    max_boxes: int = field_doc(3, "at most this many boxes (uniform count from 0)")
    box_width_m: tuple[float, float] = field_doc((0.3, 1.2), "box extent along x (m)")
    box_depth_m: tuple[float, float] = field_doc((0.3, 1.0), "box extent along the floor (m)")
    box_height_m: tuple[float, float] = field_doc((0.2, 1.5), "box height above the floor (m)")
    box_x_m: tuple[float, float] = field_doc((-2.5, 2.5), "range of box centres across (m)")
    box_near_m: tuple[float, float] = field_doc(
        (1.0, 5.5), "range of a box's near face distance from the camera (m)"
    )
    max_distance_m: float = field_doc(
        10.0, "background farther than this (camera z, m) is left empty (e.g. floor at horizon)"
    )


@dataclass(frozen=True)
class BackgroundBox:
    """Axis-aligned box standing on the floor, in the level floor frame: the camera frame
    un-pitched (x right, y down, z horizontal forward, origin at the camera)."""

    x_min: float
    x_max: float
    z_min: float
    z_max: float
    height: float


@dataclass(frozen=True)
class BackgroundCylinder:
    """Vertical cylinder in the level floor frame (as :class:`BackgroundBox`): its axis at
    ``(x, z)``, spanning heights ``bottom`` to ``top`` above the floor (a round seat, a leg)."""

    x: float
    z: float
    radius: float
    bottom: float
    top: float


@dataclass(frozen=True)
class BackgroundScene:
    """A background: floor always, an optional back wall (horizontal distance), boxes and
    vertical cylinders."""

    wall_distance: float | None
    boxes: tuple[BackgroundBox, ...] = ()
    cylinders: tuple[BackgroundCylinder, ...] = ()


def _rays(intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Pixel ray components ``r_x`` (1, W) and ``r_y`` (H, 1) of ``r = (r_x, r_y, 1)``; a hit at
    ray parameter t has camera depth z = t."""
    rx = (np.arange(intr.width, dtype=np.float64) - intr.cx) / intr.fx
    ry = (np.arange(intr.height, dtype=np.float64) - intr.cy) / intr.fy
    return rx[None, :], ry[:, None]


def _level_rays(intr: Intrinsics, pitch: float, level_from_camera: np.ndarray | None = None):
    """Pixel rays in the level floor frame, each (H, W): ``p_level = R p_cam`` where the camera
    looks down by ``pitch`` radians (its optical axis is (0, sin, cos) in the level frame), or
    ``R = level_from_camera`` (3, 3) when given (any pitch and roll; see
    :func:`level_from_camera`)."""
    rx, ry = _rays(intr)
    if level_from_camera is None:
        c, s = math.cos(pitch), math.sin(pitch)
        rot = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])
    else:
        rot = np.asarray(level_from_camera, dtype=np.float64)
    shape = (intr.height, intr.width)
    return tuple(
        np.broadcast_to(rot[i, 0] * rx + rot[i, 1] * ry + rot[i, 2], shape) for i in range(3)
    )


def level_from_camera(cam_from_world: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) from a camera frame to its level floor frame, for a y-up world.

    The level frame has y pointing down along world -y, z along the camera's optical axis
    projected on the floor, x = y cross z; camera pitch and roll both end up in it.

    Args:
        cam_from_world: (4, 4) or (3, 3) OpenCV camera pose, ``p_cam = R p_world + t``.
    """
    rot = np.asarray(cam_from_world, dtype=np.float64)[:3, :3]
    forward = rot[2].copy()  # optical axis in world coordinates
    forward[1] = 0.0
    forward /= max(np.linalg.norm(forward), 1e-12)
    down = np.array([0.0, -1.0, 0.0])
    level_from_world = np.stack([np.cross(down, forward), down, forward])
    return level_from_world @ rot.T


def floor_depth(
    intr: Intrinsics, camera_height: float, pitch: float, level_rot: np.ndarray | None = None
) -> np.ndarray:
    """Camera depth of the floor plane ``y_level = camera_height`` (y down), camera pitched down
    by ``pitch`` radians: ``z = h / (cos(pitch) r_y + sin(pitch))``.

    Returns:
        (H, W) float64 metres, ``inf`` where the ray does not reach the floor (above horizon).
    """
    _, dy, _ = _level_rays(intr, pitch, level_rot)
    with np.errstate(divide="ignore"):
        return np.where(dy > 1e-9, camera_height / np.where(dy > 1e-9, dy, 1.0), np.inf)


def wall_depth(
    intr: Intrinsics, pitch: float, distance: float, level_rot: np.ndarray | None = None
) -> np.ndarray:
    """Camera depth of a vertical wall facing the camera at horizontal distance ``distance``.

    Returns:
        (H, W) float64 metres, ``inf`` for rays that never reach it.
    """
    _, _, dz = _level_rays(intr, pitch, level_rot)
    return np.where(dz > 1e-9, distance / np.where(dz > 1e-9, dz, 1.0), np.inf)


def box_depth(
    intr: Intrinsics,
    camera_height: float,
    pitch: float,
    box: BackgroundBox,
    level_rot: np.ndarray | None = None,
):
    """Camera depth of the visible face of one box on the floor (slab ray-box intersection).

    Returns:
        (H, W) float64 metres, ``inf`` where the ray misses the box.
    """
    dirs = _level_rays(intr, pitch, level_rot)
    lows = (box.x_min, camera_height - box.height, box.z_min)
    highs = (box.x_max, camera_height, box.z_max)
    t_near = np.zeros((intr.height, intr.width))
    t_far = np.full((intr.height, intr.width), np.inf)
    for d, lo, hi in zip(dirs, lows, highs):
        # A zero direction component never crosses that slab; a tiny value gives the same
        # +-inf limits without 0/0.
        d = np.where(np.abs(d) < 1e-12, 1e-12, d)
        t0, t1 = lo / d, hi / d
        t_near = np.maximum(t_near, np.minimum(t0, t1))
        t_far = np.minimum(t_far, np.maximum(t0, t1))
    return np.where((t_near <= t_far) & (t_near > 0), t_near, np.inf)


def cylinder_depth(
    intr: Intrinsics,
    camera_height: float,
    pitch: float,
    cyl: BackgroundCylinder,
    level_rot: np.ndarray | None = None,
) -> np.ndarray:
    """Camera depth of the visible surface of one vertical cylinder: its side or its top or
    bottom disc, whichever a ray meets first.

    Returns:
        (H, W) float64 metres, ``inf`` where the ray misses it.
    """
    dx, dy, dz = _level_rays(intr, pitch, level_rot)
    # A ray point at parameter t is t (dx, dy, dz) (level frame, y down); heights above the
    # floor are camera_height - t dy.
    a = dx * dx + dz * dz
    b = dx * cyl.x + dz * cyl.z
    c = cyl.x**2 + cyl.z**2 - cyl.radius**2
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        t_side = np.where((disc >= 0) & (a > 1e-12), (b - np.sqrt(np.maximum(disc, 0))) / a, np.inf)
    height = camera_height - t_side * dy
    side = np.where((t_side > 0) & (height >= cyl.bottom) & (height <= cyl.top), t_side, np.inf)
    best = side
    for level in (cyl.top, cyl.bottom):  # the two discs
        safe = np.where(np.abs(dy) > 1e-12, dy, 1e-12)
        t = (camera_height - level) / safe
        inside = (t * dx - cyl.x) ** 2 + (t * dz - cyl.z) ** 2 <= cyl.radius**2
        best = np.minimum(best, np.where((t > 0) & inside, t, np.inf))
    return best


def random_background_scene(rng: np.random.Generator, cfg: BackgroundConfig) -> BackgroundScene:
    """Draw a wall (with ``cfg.wall_prob``) and 0..``cfg.max_boxes`` boxes."""
    wall = None
    if rng.random() < cfg.wall_prob:
        wall = float(rng.uniform(*cfg.wall_distance_m))
    boxes = []
    for _ in range(int(rng.integers(0, cfg.max_boxes + 1))):
        width = rng.uniform(*cfg.box_width_m)
        depth = rng.uniform(*cfg.box_depth_m)
        x = rng.uniform(*cfg.box_x_m)
        z0 = rng.uniform(*cfg.box_near_m)
        boxes.append(
            BackgroundBox(
                float(x - width / 2),
                float(x + width / 2),
                float(z0),
                float(z0 + depth),
                float(rng.uniform(*cfg.box_height_m)),
            )
        )
    return BackgroundScene(wall, tuple(boxes))


def add_floor_and_background(
    depth: np.ndarray,
    labels: np.ndarray | None,
    intr: Intrinsics,
    camera_height: float,
    pitch: float,
    rng: np.random.Generator | None = None,
    cfg: BackgroundConfig | None = None,
    scene: BackgroundScene | None = None,
    level_rot: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Composite a floor, optional back wall and boxes with a rendered body frame.

    The nearer surface wins at every pixel (a z-buffer): the background fills pixels with no
    surface and hides body pixels that lie behind a box (or behind the floor/wall, if the
    body was rendered through them); labels of every background pixel are 0.

    Args:
        depth: (H, W) float metric depth of the body, 0 = nothing rendered.
        labels: (H, W) uint8 body-part labels or None.
        intr: intrinsics of the image.
        camera_height: height of the camera centre above the floor (m).
        pitch: downward tilt of the camera (rad; positive looks down).
        rng: draws the scene when ``scene`` is None.
        cfg: ranges for the random scene (defaults if None).
        scene: a fixed background instead of a random one.
        level_rot: (3, 3) :func:`level_from_camera` of the camera pose; overrides ``pitch``
            and also accounts for roll.
    Returns:
        depth: (H, W) float32 metres; 0 where nothing is within ``cfg.max_distance_m``.
        labels: (H, W) uint8 with background/occluded pixels 0 (None if None).
    """
    depth = np.asarray(depth)
    check_depth_image(depth, labels, intr)
    cfg = BackgroundConfig() if cfg is None else cfg
    if scene is None:
        if rng is None:
            raise ValueError("give rng (to draw a random scene) or scene")
        scene = random_background_scene(rng, cfg)

    bg = floor_depth(intr, camera_height, pitch, level_rot)
    if scene.wall_distance is not None:
        bg = np.minimum(bg, wall_depth(intr, pitch, scene.wall_distance, level_rot))
    for box in scene.boxes:
        bg = np.minimum(bg, box_depth(intr, camera_height, pitch, box, level_rot))
    for cyl in scene.cylinders:
        bg = np.minimum(bg, cylinder_depth(intr, camera_height, pitch, cyl, level_rot))
    bg = np.where(bg <= cfg.max_distance_m, bg, np.inf)

    body = np.where(depth > 0, depth, np.inf)
    use_bg = bg < body
    out = np.where(use_bg, bg, body)
    out = np.where(np.isfinite(out), out, 0.0).astype(np.float32)
    out_labels = None
    if labels is not None:
        out_labels = np.where(use_bg, 0, labels).astype(np.uint8)
    return out, out_labels
