"""The synthetic training set (Wei section 4.1): real motion, varied bodies, many viewpoints.

Steps:

1. Motion: every clip under ``motion_folders`` (mocap) at ``motion_fps``, or the procedural
   motions when none is there (:mod:`train.mocap.motion_library`).
2. Pose selection: furthest-point sampling in heading-normalized joint space, no two poses
   closer than ``min_pose_distance`` (:mod:`train.mocap.pose_selection`), then retargeting of the
   picked poses onto the 34-DoF skeleton (batched IK; cached in ``poses.npz``).
3. Frames: frame i gets a pose (all picked poses are used before any repeats), one of
   ``bodies`` random anny bodies and a random viewpoint from which the whole body is seen;
   rendered with exact labels, composited with a floor and background, passed through the
   Kinect sensor model (:mod:`train.synth.frame`).
4. Shards of ``shard_frames`` frames rendered by a pool of worker processes; each shard is a
   pure function of (seed, shard index), written atomically, and listed in the manifest as soon
   as it is done, so a second run skips finished shards (resume) and gives the same bytes.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import config_to_dict, field_doc, save_config
from depthmocap.shared.labels import CLUTTER_CLASSES, PART_NAMES
from depthmocap.train.synth.frame import SceneConfig
from depthmocap.train.synth.props import PropConfig, sitting_pose
from depthmocap.train.synth.trainset import TrainSetError, file_sha256, write_manifest, write_shard

__all__ = ["SynthConfig", "prepare_poses", "frame_plan", "render_shard", "synthesize_set"]


@dataclass
class SynthConfig:
    """The training set: size, sources, bodies and rendering (``configs/synth.yaml``)."""

    frames: int = field_doc(20000, "number of frames to render")
    width: int = field_doc(320, "image width: 320 (320x240) or 640 (640x480), Kinect v1 optics")
    shard_frames: int = field_doc(250, "frames per shard file (the unit of resuming)")
    bodies: int = field_doc(48, "number of distinct random anny bodies")
    seed: int = field_doc(0, "the whole set is a pure function of this seed and the config")
    workers: int = field_doc(0, "rendering processes; 0 = one per CPU core")
    motion_folders: list[str] = field_doc(
        ["../shared/data/mocap/cmu", "../shared/data/mocap/hdm05/train"],
        help="folders searched for .bvh/.amc clips (relative to the working directory); "
        "when none holds a clip the procedural motions are used",
    )
    motion_fps: float = field_doc(30.0, "clips are resampled to this rate before pose selection")
    min_pose_distance: float = field_doc(
        0.05, "no two selected poses closer than this (largest joint distance, metres)"
    )
    max_poses: int = field_doc(20000, "most poses selected")
    procedural_random_poses: int = field_doc(
        2000, "random poses added to the procedural motions (no mocap only)"
    )
    procedural_motions: list[str] = field_doc(
        [], "only these procedural motions (no mocap only; empty = all), e.g. [t_pose]"
    )
    procedural_jitter_rad: float = field_doc(
        0.0, "uniform random offset (+-) on every joint angle of the procedural poses, radians"
    )
    scene: SceneConfig = field_doc(
        default_factory=SceneConfig, help="floor/background, sensor noise, viewpoint ranges"
    )

    def validate(self) -> None:
        if self.width not in (320, 640):
            raise ValueError(f"width must be 320 or 640, got {self.width}")
        for name in ("frames", "shard_frames", "bodies", "max_poses"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1")
        self.scene.props.validate()
        if self.scene.props.probability > 0 and not self.scene.floor:
            raise ValueError("scene.props stand on the floor: they need scene.floor")


def class_names(cfg: SynthConfig) -> tuple[str, ...]:
    """What the set's labels mean: body parts, or person/clutter (``scene.props``)."""
    return CLUTTER_CLASSES if cfg.scene.props.person_clutter_labels else PART_NAMES


def _worker_count(cfg: SynthConfig) -> int:
    return cfg.workers if cfg.workers > 0 else max(1, os.cpu_count() or 1)


def _procedural_options(cfg: SynthConfig) -> dict:
    """The procedural-motion options added after the first sets were made, when not at their
    defaults: keys and fingerprints of sets made before stay valid."""
    opts = {"procedural_motions": list(cfg.procedural_motions),
            "procedural_jitter_rad": cfg.procedural_jitter_rad}  # fmt: skip
    return opts if cfg.procedural_motions or cfg.procedural_jitter_rad else {}


def _poses_key(cfg: SynthConfig, clips: list[Path]) -> str:
    h = hashlib.sha256()
    for p in clips:
        h.update(f"{p.name}:{p.stat().st_size}".encode())
    h.update(
        json.dumps(
            [cfg.motion_fps, cfg.min_pose_distance, cfg.max_poses, cfg.seed,
             cfg.procedural_random_poses, *_procedural_options(cfg).values()]
        ).encode()
    )  # fmt: skip
    return h.hexdigest()[:16]


def _retarget_task(args):
    import torch
    from depthmocap.train.mocap.retarget import body_from_named_joints, retarget_joints

    torch.set_num_threads(1)
    all_joints, picked = args
    body = body_from_named_joints(all_joints)
    q, rms = retarget_joints(all_joints[picked], body, passes=1)
    return q, rms


def prepare_poses(cfg: SynthConfig, cache_dir: Path, log=print) -> tuple[np.ndarray, dict]:
    """Select and retarget the training poses, cached in ``cache_dir/poses.npz``.

    Returns:
        q: (K, 34) world-frame poses; info: source, counts, retarget error.
    """
    from depthmocap.train.mocap.motion_library import (
        find_clips,
        heading_normalized_joints,
        mocap_library,
        procedural_library,
    )
    from depthmocap.train.mocap.pose_selection import furthest_point_sample

    clips = find_clips(cfg.motion_folders)
    key = _poses_key(cfg, clips)
    cache = Path(cache_dir) / "poses.npz"
    if cache.is_file():
        with np.load(cache, allow_pickle=False) as data:
            if str(data["key"]) == key:
                return data["q"], json.loads(str(data["info"]))
    rng = np.random.default_rng([cfg.seed, 1])
    if clips:
        log(f"reading {len(clips)} clips at {cfg.motion_fps:g} fps")
        lib = mocap_library(cfg.motion_folders, cfg.motion_fps)
        source = "mocap"
    else:
        log("no mocap clips found: using the procedural motions")
        lib = procedural_library(
            rng, cfg.motion_fps, cfg.procedural_random_poses, cfg.procedural_motions,
            cfg.procedural_jitter_rad,
        )  # fmt: skip
        source = "procedural"
    counts = np.array([len(s.joints) for s in lib])
    starts = np.concatenate([[0], np.cumsum(counts)])
    flat = np.concatenate([heading_normalized_joints(s.joints) for s in lib])
    picked = np.sort(furthest_point_sample(flat, cfg.max_poses, cfg.min_pose_distance, cfg.seed))
    seq_of = np.searchsorted(starts, picked, side="right") - 1
    log(f"{len(picked)} of {len(flat)} candidate poses are >= {cfg.min_pose_distance} m apart")
    if source == "procedural":
        q = np.concatenate([lib[s].q[picked[seq_of == s] - starts[s]] for s in np.unique(seq_of)])
        rms = np.zeros(len(q))
    else:
        tasks = [(lib[s].joints, picked[seq_of == s] - starts[s]) for s in np.unique(seq_of)]
        log(f"retargeting {len(picked)} poses onto the tracking skeleton")
        results = _pool_map(_retarget_task, tasks, _worker_count(cfg))
        q = np.concatenate([r[0] for r in results])
        rms = np.concatenate([r[1] for r in results])
    info = {
        "source": source,
        "clips": len(lib),
        "candidates": int(len(flat)),
        "poses": int(len(q)),
        "retarget_rms_mm_mean": float(rms.mean() * 1000),
        "retarget_rms_mm_max": float(rms.max() * 1000),
    }
    Path(cache_dir).mkdir(parents=True, exist_ok=True)
    np.savez(cache, q=q, key=np.array(key), info=np.array(json.dumps(info)))
    return q, info


# Thread pools of the native libraries. Each worker already owns a core; OpenBLAS/OpenMP
# threads inside every worker oversubscribe the machine (measured on 2 cores: 2 workers
# rendered no faster than 1 until these were pinned to 1, then 1.85x faster).
_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _single_threaded_pool(workers: int):
    """A spawn pool whose workers run their native libraries on one thread each."""
    import multiprocessing as mp

    saved = {k: os.environ.get(k) for k in _THREAD_ENV}
    os.environ.update({k: "1" for k in _THREAD_ENV})
    try:  # spawned children copy the environment when they start
        return mp.get_context("spawn").Pool(workers)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _pool_map(fn, tasks, workers: int):
    if workers <= 1 or len(tasks) <= 1:
        return [fn(t) for t in tasks]
    with _single_threaded_pool(workers) as pool:
        return pool.map(fn, tasks, chunksize=1)


def frame_plan(cfg: SynthConfig, num_poses: int) -> tuple[np.ndarray, np.ndarray]:
    """Pose and body index of every frame: (frames,) each. Poses cycle through random
    permutations, so every pose is used before any is used twice."""
    rng = np.random.default_rng([cfg.seed, 2])
    reps = -(-cfg.frames // num_poses)
    poses = np.concatenate([rng.permutation(num_poses) for _ in range(reps)])[: cfg.frames]
    bodies = rng.integers(0, cfg.bodies, cfg.frames)
    return poses, bodies


# Per-process state of the rendering workers (one EGL context and body cache each).
_WORKER: dict = {}


def _worker_state(width: int):
    import torch

    torch.set_num_threads(1)
    if "renderer" not in _WORKER:
        from depthmocap.train.synth.render import DepthLabelRenderer

        intr = Intrinsics.kinect_v1(width)
        _WORKER.update(renderer=DepthLabelRenderer(intr), intr=intr, bodies={})
    return _WORKER


def render_shard(task: dict) -> dict:
    """Render and write one shard; a pure function of ``task`` (config, poses, indices).

    Returns the manifest entry of the shard plus its class pixel counts and timing.
    """
    from depthmocap.train.synth.frame import (
        body_for_index,
        face_forward,
        place_on_floor,
        render_frame,
    )
    from depthmocap.train.synth.trainset import Shard
    from depthmocap.train.synth.viewpoints import sample_viewpoint_in_view

    t0 = time.perf_counter()
    cfg: SynthConfig = task["cfg"]
    state = _worker_state(cfg.width)
    intr, renderer = state["intr"], state["renderer"]
    rng = np.random.default_rng([cfg.seed, 3, task["shard"]])
    n = len(task["poses"])
    poses = face_forward(task["poses"], frames=None)  # view yaw is relative to the person
    h, w = intr.height, intr.width
    depth = np.zeros((n, h, w), np.uint16)
    labels = np.zeros((n, h, w), np.uint8)
    joints = np.zeros((n, len(sk.JOINT_NAMES), 3), np.float32)
    q_cam = np.zeros((n, sk.NUM_DOFS), np.float32)
    # Frames of one body together: switching meshes costs more than rendering a frame.
    for k in np.argsort(task["bodies"], kind="stable"):
        b = int(task["bodies"][k])
        if b not in state["bodies"]:
            state["bodies"][b] = body_for_index(cfg.seed, b)
        body = state["bodies"][b]
        props = cfg.scene.props
        sitting = props.sitting > 0 and bool(rng.random() < props.sitting)
        pose = sitting_pose(poses[k], rng) if sitting else poses[k]
        placed = place_on_floor(body, pose[None], per_frame=True)
        view = None
        for _ in range(8):
            view = sample_viewpoint_in_view(
                rng,
                placed.vertices[0][::25],
                intr,
                cfg.scene.viewpoints,
                target_height=float(placed.q[0, 1]),
            )
            if view is not None:
                break
        if view is None:
            raise RuntimeError(
                "no viewpoint sees the whole body: widen scene.viewpoints.distance_max"
            )
        frame = render_frame(
            renderer, body, placed.vertices[0], placed.joints[0], placed.q[0], view, intr,
            cfg.scene, rng, sitting=sitting,
        )  # fmt: skip
        depth[k], labels[k], joints[k], q_cam[k] = frame
    path = Path(task["out"]) / f"shard_{task['shard']:05d}.npz"
    sha = write_shard(
        path,
        Shard(
            depth, labels, joints, q_cam, np.asarray(task["bodies"], np.int32),
            np.array([intr.fx, intr.fy, intr.cx, intr.cy]),
        ),
    )  # fmt: skip
    return {
        "shard": task["shard"],
        "file": path.name,
        "frames": n,
        "sha256": sha,
        "class_pixels": np.bincount(labels.ravel(), minlength=len(class_names(cfg))).tolist(),
        "seconds": time.perf_counter() - t0,
    }


# Bumped whenever the frames rendered for a config change, so a resumed run never mixes
# shards of two generator versions. 2: poses turned to face +z before the view is drawn.
GENERATOR_VERSION = 2


def _config_fingerprint(cfg: SynthConfig) -> str:
    data = config_to_dict(cfg)
    data.pop("workers", None)  # does not change the output
    data["generator_version"] = GENERATOR_VERSION
    for key in ("procedural_motions", "procedural_jitter_rad"):
        data.pop(key, None)
    if cfg.scene.props == PropConfig():  # sets made before props existed keep their key
        data["scene"].pop("props", None)
    data.update(_procedural_options(cfg))
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def synthesize_set(cfg: SynthConfig, out: Path, progress: bool = True, log=print) -> dict:
    """Build (or finish) the training set in ``out``; returns the manifest."""
    cfg.validate()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fingerprint = _config_fingerprint(cfg)
    done: dict[int, dict] = {}
    manifest_path = out / "manifest.json"
    if manifest_path.is_file():
        old = json.loads(manifest_path.read_text())
        if old.get("config_fingerprint") != fingerprint:
            raise TrainSetError(
                f"{out} holds a set made with another config or generator version; choose "
                "another --out or delete it"
            )
        for entry in old.get("shards", []):
            if (out / entry["file"]).is_file() and file_sha256(out / entry["file"]) == entry[
                "sha256"
            ]:
                done[entry["shard"]] = entry
    save_config(cfg, out / "synth_config.yaml")

    t0 = time.perf_counter()
    poses, pose_info = prepare_poses(cfg, out, log=log)
    t_poses = time.perf_counter() - t0
    pose_idx, body_idx = frame_plan(cfg, len(poses))
    intr = Intrinsics.kinect_v1(cfg.width)
    n_shards = -(-cfg.frames // cfg.shard_frames)
    tasks = []
    for s in range(n_shards):
        if s in done:
            continue
        sel = slice(s * cfg.shard_frames, min(cfg.frames, (s + 1) * cfg.shard_frames))
        tasks.append(
            {"cfg": cfg, "shard": s, "out": str(out), "poses": poses[pose_idx[sel]],
             "bodies": body_idx[sel]}
        )  # fmt: skip
    log(f"{n_shards - len(tasks)} of {n_shards} shards already done; rendering {len(tasks)}")

    def write(extra_stats: dict) -> dict:
        entries = [done[s] for s in sorted(done)]
        counts = (
            np.sum([e["class_pixels"] for e in entries], axis=0)
            if entries
            else np.zeros(len(class_names(cfg)), np.int64)
        )
        return write_manifest(
            out, intr,
            [{k: e[k] for k in ("shard", "file", "frames", "sha256", "class_pixels")}
             for e in entries],
            counts, cfg.seed, config_to_dict(cfg), class_names=class_names(cfg),
            extra={"config_fingerprint": fingerprint, "complete": len(done) == n_shards,
                   "poses": pose_info, **extra_stats},
        )  # fmt: skip

    t1 = time.perf_counter()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.frames, initial=sum(e["frames"] for e in done.values()),
                   unit="frame", desc="train-synth")  # fmt: skip
    rendered = 0
    workers = min(_worker_count(cfg), max(1, len(tasks)))
    if workers <= 1:
        results = map(render_shard, tasks)
        pool = None
    else:
        pool = _single_threaded_pool(workers)
        results = pool.imap_unordered(render_shard, tasks)
    try:
        for entry in results:
            done[entry["shard"]] = entry
            rendered += entry["frames"]
            write({})
            if bar is not None:
                bar.update(entry["frames"])
    finally:
        if pool is not None:
            pool.terminate()
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - t1
    stats = {
        "render_seconds": round(seconds, 2),
        "pose_seconds": round(t_poses, 2),
        "frames_per_second": round(rendered / seconds, 2) if rendered else None,
        "workers": workers,
    }
    return write(stats)
