"""One synthetic frame: pose an anny body, place a camera, render, add a scene and sensor noise.

Shared by the training-set builder (:mod:`train.synth.trainset_builder`) and the sequence renderer
(:mod:`train.synth.sequence`). World frame as in :mod:`train.synth.viewpoints` (y up, floor y = 0);
all outputs are in the OpenCV camera frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import field_doc
from depthmocap.shared.kinematics import transform_pose
from depthmocap.shared.sensor_noise import (
    BackgroundConfig,
    BackgroundScene,
    KinectNoiseConfig,
    add_floor_and_background,
    apply_kinect_noise,
    level_from_camera,
)
from depthmocap.shared.sensor_noise.background import (
    box_depth,
    cylinder_depth,
    random_background_scene,
)
from depthmocap.train.bodies.anny_body import AnnyBody, make_body, sample_phenotype
from depthmocap.train.bodies.measurements import anatomical_joints
from depthmocap.train.bodies.posing import pose_anny
from depthmocap.train.mocap.clip import axis_rotation
from depthmocap.train.synth.garments import GarmentConfig, dress_body
from depthmocap.train.synth.props import (
    PropConfig,
    attached_prop,
    chair_under,
    person_clutter_labels,
    pixel_heights,
)
from depthmocap.train.synth.render import DepthLabelRenderer
from depthmocap.train.synth.viewpoints import ViewpointConfig, Viewpoints, transform_points

__all__ = [
    "SceneConfig",
    "PlacedBody",
    "SynthFrame",
    "body_for_index",
    "face_forward",
    "place_on_floor",
    "render_frame",
]


@dataclass
class SceneConfig:
    """What surrounds the person and how the sensor sees it."""

    floor: bool = field_doc(True, "draw the floor (and back wall and boxes when `background`)")
    background: bool = field_doc(True, "random back wall and boxes behind/around the person")
    scene: BackgroundConfig = field_doc(
        default_factory=BackgroundConfig, help="ranges of the random wall and boxes"
    )
    noise: KinectNoiseConfig = field_doc(
        default_factory=KinectNoiseConfig, help="Kinect v1 sensor model (each effect switchable)"
    )
    viewpoints: ViewpointConfig = field_doc(
        default_factory=ViewpointConfig, help="camera distance, height, yaw, pitch and roll"
    )
    garments: GarmentConfig = field_doc(
        default_factory=GarmentConfig,
        help="clothing drawn over the bare body (closed leg gaps, cloth thickness); off by default",
    )
    props: PropConfig = field_doc(
        default_factory=PropConfig,
        help="furniture against the person and the person/clutter labels; off by default",
    )


class PlacedBody(NamedTuple):
    """A posed body on the floor of the world frame.

    Attributes:
        vertices: (F, V, 3) world vertices.
        joints: (F, J, 3) anatomical named joints (world).
        q: (F, 34) world-frame poses of the tracking skeleton.
    """

    vertices: np.ndarray
    joints: np.ndarray
    q: np.ndarray


class SynthFrame(NamedTuple):
    """One rendered frame in the camera frame.

    Attributes:
        depth_mm: (H, W) uint16 sensor depth, 0 = no reading.
        labels: (H, W) uint8 part labels, 0 = background or no reading.
        joints: (J, 3) float32 named joints, camera metres.
        q: (34,) float32 skeleton pose in the camera frame (the ``q`` given to
            :func:`render_frame`: the pose that drove the mesh, unless the caller fitted one).
    """

    depth_mm: np.ndarray
    labels: np.ndarray
    joints: np.ndarray
    q: np.ndarray


def body_for_index(seed: int, index: int) -> AnnyBody:
    """The ``index``-th random body of a run: a pure function of (seed, index)."""
    return make_body(sample_phenotype(np.random.default_rng([seed, 7919, index])))


def face_forward(q: np.ndarray, frames: int | None = 10) -> np.ndarray:
    """Turn world poses (F, 34) about the vertical so the person faces +z, the direction the
    viewpoint yaw is measured from (:mod:`train.synth.viewpoints`).

    Mocap clips face anywhere; without this the sampled view yaw adds to the clip's own
    heading and the front/side/back mix of the config is lost (uniform yaw instead).

    Args:
        frames: turn the whole sequence by one angle, the heading of the hip line averaged over
            its first ``frames`` frames (sequences: the person may then turn); None: turn every
            pose by its own heading (independent training poses).
    """
    from depthmocap.shared.body import BodyShape
    from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions

    qt = torch.as_tensor(q, dtype=torch.float64)
    used = qt if frames is None else qt[:frames]
    j = named_joint_positions(forward_kinematics(used, BodyShape.default(torch.float64)))
    left = j[:, sk.JOINT_NAMES.index("l_hip")] - j[:, sk.JOINT_NAMES.index("r_hip")]
    if frames is not None:
        left = left.mean(0, keepdim=True)
    up = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64).expand_as(left)
    forward = torch.linalg.cross(left, up)
    yaw = torch.atan2(forward[:, 0], forward[:, 2]).numpy()
    rot = torch.as_tensor(axis_rotation("y", -yaw)).expand(qt.shape[0], 3, 3)
    return transform_pose(qt, rot, torch.zeros(3, dtype=torch.float64)).numpy()


def place_on_floor(body: AnnyBody, q: np.ndarray, per_frame: bool) -> PlacedBody:
    """Pose ``body`` with world poses q and move it onto the floor at the origin.

    The lowest vertex touches y = 0 (per frame, or once for the whole sequence so that jumps
    stay in the air) and the pelvis is centred horizontally (per frame, or on its mean).

    Args:
        q: (F, 34) world-frame poses (any horizontal position and floor height).
    """
    q = np.asarray(q, dtype=np.float64)
    posed = pose_anny(body, q)
    verts = posed.vertices
    joints = anatomical_joints(body, posed)
    low = verts[..., 1].min(-1)  # (F,)
    pelvis = q[:, 0:3]
    if per_frame:
        shift = np.stack([-pelvis[:, 0], -low, -pelvis[:, 2]], -1)
    else:
        shift = np.array([-pelvis[:, 0].mean(), -low.min(), -pelvis[:, 2].mean()])
        shift = np.broadcast_to(shift, (q.shape[0], 3))
    q_out = q.copy()
    q_out[:, 0:3] += shift
    return PlacedBody(verts + shift[:, None], joints + shift[:, None], q_out)


def scene_behind(cfg: BackgroundConfig, person_distance: float, gap: float = 0.5):
    """``cfg`` with the wall and the boxes' near faces at least ``gap`` behind the person, so
    the background never hides the person (Wei's and Shotton's data have no occluders)."""
    near = person_distance + gap
    wall = (max(cfg.wall_distance_m[0], near + 0.5), max(cfg.wall_distance_m[1], near + 0.5))
    boxes = (max(cfg.box_near_m[0], near), max(cfg.box_near_m[1], near))
    return replace(cfg, wall_distance_m=wall, box_near_m=boxes)


def render_frame(
    renderer: DepthLabelRenderer,
    body: AnnyBody,
    vertices: np.ndarray,
    joints: np.ndarray,
    q: np.ndarray,
    view: Viewpoints,
    intr: Intrinsics,
    cfg: SceneConfig,
    rng: np.random.Generator,
    scene: BackgroundScene | None = None,
    sitting: bool = False,
) -> SynthFrame:
    """Render one placed body from viewpoint ``view`` (N = 1).

    Args:
        vertices: (V, 3) world vertices; joints: (J, 3) world; q: (34,) world pose.
        scene: a fixed background (sequences); drawn from ``rng`` when None.
        sitting: the body is seated (``props.sitting_pose``): the furniture drawn, if any, is
            a chair under it (without one, a crouch: the forest must not take a seated
            posture itself for furniture).
    """
    cam = view.cam_from_world[0]
    verts_cam = transform_points(cam, vertices).astype(np.float32)
    frame = renderer.render(verts_cam, body.faces, body.labels)
    depth, labels = dress_body(frame.depth, frame.labels, intr, cfg.garments, rng)
    furniture, level_rot, height = None, level_from_camera(cam), float(view.height[0])
    prop_px = np.zeros(depth.shape, bool)  # where the furniture is the nearest surface
    if cfg.floor:
        bg_cfg = scene_behind(cfg.scene, float(view.distance[0]))
        if scene is None:
            scene = (
                random_background_scene(rng, bg_cfg)
                if cfg.background
                else BackgroundScene(None, ())
            )
        if cfg.props.probability > 0 and rng.random() < cfg.props.probability:
            if sitting:  # a chair under the seated body
                pelvis = transform_points(cam, joints[None, sk.JOINT_NAMES.index("pelvis")])[0]
                furniture = chair_under(rng, verts_cam @ level_rot.T, level_rot @ pelvis)
            else:
                furniture = attached_prop(rng, verts_cam @ level_rot.T, height, cfg.props)
            scene = BackgroundScene(
                scene.wall_distance,
                scene.boxes + furniture.boxes,
                scene.cylinders + furniture.cylinders,
            )
        depth, labels = add_floor_and_background(
            depth, labels, intr, height, 0.0, rng=rng, cfg=bg_cfg, scene=scene,
            level_rot=level_rot,
        )  # fmt: skip
        if furniture is not None:
            near = [box_depth(intr, height, 0.0, b, level_rot) for b in furniture.boxes]
            near += [cylinder_depth(intr, height, 0.0, c, level_rot) for c in furniture.cylinders]
            prop_px = np.abs(np.min(near, axis=0) - depth) < 1e-4
    depth_mm, labels = apply_kinect_noise(depth, labels, intr, cfg.noise, rng)
    if cfg.props.person_clutter_labels:
        heights = pixel_heights(depth_mm / 1000.0, intr, level_rot, height)
        labels = person_clutter_labels(depth_mm, labels, prop_px, heights)
    rot = torch.as_tensor(cam[:3, :3])
    q_cam = transform_pose(torch.as_tensor(q)[None], rot, torch.as_tensor(cam[:3, 3]))[0]
    return SynthFrame(
        depth_mm,
        labels,
        transform_points(cam, joints).astype(np.float32),
        q_cam.numpy().astype(np.float32),
    )
