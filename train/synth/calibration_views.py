"""The two calibration views of personalization (Helten et al. 2013, Fig. 2), with ground truth.

One random anny body (seeded, or a given phenotype) stands in the reference calibration pose
(arms lowered about 40 degrees sideways, feet slightly apart; each view's joint angles jittered
so that the pose is held only roughly) in front of a fixed camera, once facing it and once
turned by 180 degrees. Each view is rendered like every synthetic frame (floor, optional
background, Kinect v1 noise; :func:`train.synth.frame.render_frame`) and written as a
one-frame recording::

    DIR/front/               recording (meta.json, depth/, labels/, groundtruth.npz)
    DIR/back/
    DIR/groundtruth_body.npz rest_vertices (V, 3) body frame, faces (F, 3), vertex_segment (V,),
                             phenotype_keys, phenotype (6,), q_front, q_back (34,) camera-frame
                             poses that drove the mesh

``runtime-personalize --input DIR`` reads exactly this layout. Command line (until
``train-synth`` gets a flag for it)::

    python -m depthmocap.train.synth.calibration_views --out DIR [--seed S] \
        [--phenotype-from REC] [--clean]

``--phenotype-from`` takes the subject of a synthetic recording (its ``phenotype.json``), so
that the personalized body can be compared with the default one when tracking that recording.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import field_doc
from depthmocap.shared.kinematics import clamp_to_limits
from depthmocap.shared.recording import RecordingWriter
from depthmocap.train.bodies.anny_body import PHENOTYPE_KEYS, make_body, sample_phenotype
from depthmocap.train.synth.frame import SceneConfig, place_on_floor, render_frame
from depthmocap.train.synth.viewpoints import Viewpoints, look_at

__all__ = ["CalibrationViewConfig", "CALIBRATION_POSE_DEG", "calibration_world_pose",
           "render_calibration_views", "main"]  # fmt: skip

# Same reference pose as runtime.personalize.reference_pose.CALIBRATION_POSE_DEG (train may not
# import runtime; keep the two in step).
CALIBRATION_POSE_DEG: dict[str, float] = {
    "l_humerus_abd": 40.0,
    "r_humerus_abd": 40.0,
    "l_femur_abd": 6.0,
    "r_femur_abd": 6.0,
}


@dataclass
class CalibrationViewConfig:
    """Camera and pose of the two synthetic calibration views."""

    width: int = field_doc(320, help="depth image width (Kinect v1 intrinsics scaled)")
    distance_m: float = field_doc(2.8, help="camera to the person's vertical axis, metres")
    camera_height_m: float = field_doc(1.0, help="camera height above the floor, metres")
    target_height_m: float = field_doc(0.9, help="height the camera aims at, metres")
    pose_jitter_deg: float = field_doc(
        5.0, help="s.d. of the per-view jitter of every joint angle (a roughly held pose)"
    )
    yaw_jitter_deg: float = field_doc(8.0, help="s.d. of the person's turn about the vertical")
    offset_m: float = field_doc(0.1, help="s.d. of the person's position on the floor, metres")
    background: bool = field_doc(False, help="random wall and boxes behind the person")
    noise: bool = field_doc(True, help="Kinect v1 sensor noise (off: clean depth in mm)")


def calibration_world_pose(view: str, rng: np.random.Generator, cfg: CalibrationViewConfig):
    """World pose (34,) of one view: upright on the floor origin, y up, facing +z (front) or
    -z (back), the reference pose with jitter (clamped into the joint limits)."""
    q = np.zeros(sk.NUM_DOFS)
    for name, deg in CALIBRATION_POSE_DEG.items():
        q[sk.DOF_NAMES.index(name)] = math.radians(deg)
    q[6:] += rng.normal(0.0, math.radians(cfg.pose_jitter_deg), sk.NUM_DOFS - 6)
    yaw = (math.pi if view == "back" else 0.0) + rng.normal(0.0, math.radians(cfg.yaw_jitter_deg))
    q[3:6] = (0.0, yaw, 0.0)
    q[0], q[2] = rng.normal(0.0, cfg.offset_m, 2)
    return clamp_to_limits(torch.as_tensor(q)[None])[0].numpy()


def _camera(cfg: CalibrationViewConfig) -> Viewpoints:
    eye = np.array([[0.0, cfg.camera_height_m, cfg.distance_m]])
    cam = look_at(eye, np.array([0.0, cfg.target_height_m, 0.0]))
    one = np.ones(1)
    return Viewpoints(cam, eye, one * cfg.distance_m, one * cfg.camera_height_m, 0 * one, 0 * one)


def render_calibration_views(
    out: str | Path,
    seed: int = 0,
    phenotype: dict[str, float] | None = None,
    cfg: CalibrationViewConfig | None = None,
    overwrite: bool = False,
) -> Path:
    """Render ``out/front``, ``out/back`` and ``out/groundtruth_body.npz``; returns ``out``.

    Args:
        seed: seeds the body (when ``phenotype`` is None), the jitter and the sensor noise.
        phenotype: anny phenotype of the subject (missing keys 0.5); random when None.
    """
    from depthmocap.train.synth.render import DepthLabelRenderer

    cfg = cfg or CalibrationViewConfig()
    rng = np.random.default_rng([seed, 4242])
    body = make_body(sample_phenotype(rng) if phenotype is None else phenotype)
    intr = Intrinsics.kinect_v1(cfg.width)
    view = _camera(cfg)
    scene = SceneConfig(background=cfg.background)
    if not cfg.noise:
        noise = scene.noise
        noise = replace(noise, quantize=False, noise=False, shadows=False, grazing=False)
        scene = replace(scene, noise=noise)
    out = Path(out)
    q_cam = {}
    with DepthLabelRenderer(intr) as renderer:
        for name in ("front", "back"):
            q_world = calibration_world_pose(name, rng, cfg)[None]
            placed = place_on_floor(body, q_world, per_frame=False)
            # place_on_floor centres the pelvis; put the jittered floor position back.
            shift = np.array([q_world[0, 0], 0.0, q_world[0, 2]])
            verts, joints = placed.vertices[0] + shift, placed.joints[0] + shift
            q_placed = placed.q[0].copy()
            q_placed[0:3] += shift
            frame = render_frame(renderer, body, verts, joints, q_placed, view, intr, scene, rng)
            with RecordingWriter(
                out / name, intr, fps=30.0, source=f"train-synth:calibration-{name}:seed={seed}",
                overwrite=overwrite,
            ) as writer:  # fmt: skip
                writer.write_frame(frame.depth_mm, frame.labels)
                writer.write_groundtruth(frame.joints[None], sk.JOINT_NAMES, q=frame.q[None])
            q_cam[name] = frame.q.astype(np.float64)
    np.savez_compressed(
        out / "groundtruth_body.npz",
        rest_vertices=body.vertices.astype(np.float32),
        faces=body.faces.astype(np.int32),
        vertex_segment=body.vertex_segment.astype(np.int8),
        phenotype_keys=np.array(PHENOTYPE_KEYS),
        phenotype=np.array([body.phenotype[k] for k in PHENOTYPE_KEYS]),
        q_front=q_cam["front"],
        q_back=q_cam["back"],
    )
    return out


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.synth.calibration_views",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("--out", required=True, help="directory for front/, back/ and ground truth")
    p.add_argument("--seed", type=int, default=0, help="seed of body, pose jitter and noise")
    p.add_argument("--phenotype-from", help="recording whose phenotype.json gives the subject")
    p.add_argument("--clean", action="store_true", help="no Kinect noise")
    p.add_argument("--overwrite", action="store_true", help="replace existing recordings")
    args = p.parse_args(argv)
    phenotype = None
    if args.phenotype_from:
        path = Path(args.phenotype_from) / "phenotype.json"
        if not path.is_file():
            print(f"error: {path}: no such file (a train-synth recording?)", file=sys.stderr)
            return 2
        phenotype = json.loads(path.read_text())
    try:
        out = render_calibration_views(
            args.out, args.seed, phenotype, CalibrationViewConfig(noise=not args.clean),
            overwrite=args.overwrite,
        )  # fmt: skip
    except (FileExistsError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"calibration views written to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
