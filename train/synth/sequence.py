"""Render one motion clip as a recording with ground truth (the input of runtime-track and of
evaluation).

One random anny body performs the clip (retargeted with temporal continuity) in front of one
fixed camera, in a fixed random scene, at ``fps`` (Kinect: 30). The camera is drawn so that the
whole motion stays in view and within the sensor's depth range. ``groundtruth.npz`` holds per
frame the anatomical named joints in camera metres, the skeleton pose q (camera frame;
fitted to those joints by IK, RMS in ``q_fit_rms_m``) and the skeleton body; ``body.json``
beside it is that body as a body file (what ``runtime-track --body`` loads);
``phenotype.json`` is the anny phenotype.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.procedural_motion import MOTIONS, ground_poses, motion_poses
from depthmocap.shared.recording import RecordingWriter
from depthmocap.train.bodies.anny_body import AnnyBody, make_body
from depthmocap.train.synth.frame import (
    PlacedBody,
    SceneConfig,
    body_for_index,
    face_forward,
    place_on_floor,
    render_frame,
)
from depthmocap.train.synth.viewpoints import Viewpoints

__all__ = ["OutOfRangeError", "sequence_poses", "render_sequence"]


class OutOfRangeError(RuntimeError):
    """No camera keeps the whole motion within the sensor's range."""


def sequence_poses(
    motion: str, fps: float, frames: int | None, rng: np.random.Generator, asf: str | None = None
) -> tuple[np.ndarray, str]:
    """World poses (F, 34) of a clip file or a procedural motion name, at ``fps``."""
    if motion in MOTIONS:
        from depthmocap.shared.body import BodyShape

        n = frames or int(4 * fps)
        q = motion_poses(motion, n, fps, rng)
        return ground_poses(q, BodyShape.default(torch.float64)), f"procedural:{motion}"
    path = Path(motion)
    if not path.is_file():
        raise FileNotFoundError(
            f"{motion}: no such clip file and not a built-in motion ({', '.join(MOTIONS)})"
        )
    from depthmocap.train.mocap.motion_library import load_clip_joints
    from depthmocap.train.mocap.retarget import body_from_named_joints, retarget_joints

    seq = load_clip_joints(path, fps, Path(asf) if asf else None)
    joints = seq.joints[:frames] if frames else seq.joints
    q, _ = retarget_joints(joints, body_from_named_joints(seq.joints), passes=2)
    return q, str(path)


def render_sequence(
    motion: str,
    out: str | Path,
    *,
    overwrite: bool = False,
    asf: str | None = None,
    frames: int | None = None,
    seed: int = 0,
    fps: float = 30.0,
    width: int = 320,
    cfg: SceneConfig | None = None,
    front_only: bool = True,
    progress: bool = False,
    require_in_range: bool = False,
    phenotype: dict[str, float] | None = None,
    camera: Callable[[PlacedBody, AnnyBody, Intrinsics, float], Viewpoints] | None = None,
) -> Path:
    """Render ``motion`` into the recording directory ``out``; returns its path.

    ``require_in_range``: raise :class:`OutOfRangeError` (writing nothing) when no sampled
    camera keeps the whole motion within the sensor's range, instead of rendering it anyway.
    ``phenotype``: the anny body to render (default: the ``seed``-th random body).
    ``camera``: chooses the viewpoint (N = 1) from the placed motion, the body, the
    intrinsics and the sensor's range instead of the random draw (``front_only`` and the
    config's viewpoint ranges are then unused); it may raise :class:`OutOfRangeError`.
    """
    from depthmocap.shared.sensor_noise import random_background_scene
    from depthmocap.train.bodies.posing import skeleton_body_of
    from depthmocap.train.synth.render import DepthLabelRenderer
    from depthmocap.train.synth.viewpoints import sample_viewpoint_in_view

    cfg = SceneConfig() if cfg is None else cfg
    rng = np.random.default_rng([seed, 11])
    q_world, source = sequence_poses(motion, fps, frames, rng, asf)
    q_world = face_forward(q_world)
    body = body_for_index(seed, 1_000_000 + seed) if phenotype is None else make_body(phenotype)
    placed = place_on_floor(body, q_world, per_frame=False)
    skeleton_body = skeleton_body_of(body)
    # Ground-truth q: the skeleton fitted to the mesh's anatomical joints. The pose that drove
    # the mesh is not it: anny's shoulders sit below the neck and its rest legs are splayed, so
    # the same angles put the skeleton's joints several cm away.
    from depthmocap.train.mocap.retarget import retarget_joints

    q_fit, fit_rms = retarget_joints(placed.joints, skeleton_body, passes=2)
    intr = Intrinsics.kinect_v1(width)
    vp_cfg = cfg.viewpoints
    if front_only:  # evaluation sequences face the camera, as in Wei's and Helten's setups
        from dataclasses import replace

        vp_cfg = replace(vp_cfg, front_weight=1.0, side_weight=0.0, back_weight=0.0)
    hull = placed.vertices[:, ::40].reshape(-1, 3)
    # A capture session keeps the person inside the sensor's range, not only its field of view:
    # a clip that wanders beyond it (jogging in a circle) has no depth to track there.
    max_depth = cfg.noise.max_depth_m if cfg.noise.range_limit else float("inf")
    view = None if camera is None else camera(placed, body, intr, max_depth)
    for attempt in range(32 if view is None else 0):
        # Half the attempts keep the motion in range; a clip that cannot be is still rendered
        # (with a warning) so that it fits the field of view at least.
        in_range = max_depth if attempt < 16 else float("inf")
        view = sample_viewpoint_in_view(
            rng, hull, intr, vp_cfg, target_height=float(np.median(placed.q[:, 1])),
            max_depth=in_range,
        )  # fmt: skip
        if view is not None:
            if attempt >= 16 and require_in_range:
                raise OutOfRangeError(
                    f"{motion}: no camera keeps the whole motion within {max_depth} m"
                )
            if attempt >= 16:
                warnings.warn(
                    f"{motion}: no camera keeps the whole motion within {max_depth} m; parts of "
                    "it will have no depth",
                    stacklevel=2,
                )
            break
    if view is None:
        raise RuntimeError(f"{motion}: the motion does not fit in view from any sampled camera")
    from depthmocap.train.synth.frame import scene_behind

    far = float(np.linalg.norm(hull[:, [0, 2]], axis=-1).max())  # the motion's reach
    bg_cfg = scene_behind(cfg.scene, float(view.distance[0]) + far)
    scene = random_background_scene(rng, bg_cfg) if cfg.background else None
    out = Path(out)
    n = len(q_world)
    joints = np.zeros((n, len(sk.JOINT_NAMES), 3), np.float32)
    q_cam = np.zeros((n, sk.NUM_DOFS), np.float32)
    bar = range(n)
    if progress:
        from tqdm import tqdm

        bar = tqdm(bar, unit="frame", desc="train-synth --sequence")
    with (
        DepthLabelRenderer(intr) as renderer,
        RecordingWriter(
            out, intr, fps=fps, source=f"train-synth:{source}:seed={seed}", overwrite=overwrite
        ) as writer,
    ):
        for i in bar:
            frame = render_frame(
                renderer, body, placed.vertices[i], placed.joints[i], q_fit[i], view, intr,
                cfg, rng, scene=scene,
            )  # fmt: skip
            writer.write_frame(frame.depth_mm, frame.labels)
            joints[i], q_cam[i] = frame.joints, frame.q
        body_json = json.dumps(skeleton_body.to_json_dict())
        writer.write_groundtruth(
            joints,
            sk.JOINT_NAMES,
            q=q_cam,
            body_lengths=skeleton_body.lengths.numpy(),
            body_radii=skeleton_body.radii.numpy(),
            body_json=np.array(body_json),
            cam_from_world=view.cam_from_world[0],
            q_fit_rms_m=fit_rms.astype(np.float32),
        )
    skeleton_body.save(out / "body.json")
    (out / "phenotype.json").write_text(json.dumps(body.phenotype, indent=1))
    return out
