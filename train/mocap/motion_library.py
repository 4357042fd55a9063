"""Motion sources for synthesis: mocap clips from folders, or the built-in procedural motions.

A *motion library* is a list of named joint sequences (``skeleton.JOINT_NAMES`` order, metres,
y up) resampled to a common frame rate. Mocap clips are found recursively in the configured
folders: ``*.bvh`` on their own, ``*.amc`` with the ``.asf`` skeleton of their folder (HDM05
names it ``HDM_<actor>.asf`` for ``HDM_<actor>_*.amc``). With no folder configured, or none
present (a fresh machine without ``../shared``), the procedural motions stand in.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
from depthmocap.shared.procedural_motion import procedural_sequences, random_poses
from depthmocap.train.mocap import read_amc, read_asf, read_bvh
from depthmocap.train.mocap.retarget import clip_named_joints

__all__ = [
    "MotionSequence",
    "find_clips",
    "load_clip_joints",
    "mocap_library",
    "procedural_library",
    "heading_normalized_joints",
]


@dataclass
class MotionSequence:
    """Named joints of one motion.

    Attributes:
        name: clip file stem or procedural motion name.
        joints: (F, J, 3) named joints in metres, y up.
        fps: frame rate of ``joints``.
        q: (F, 34) world-frame poses when known exactly (procedural), else ``None``.
    """

    name: str
    joints: np.ndarray
    fps: float
    q: np.ndarray | None = None


def find_clips(folders: list[str | Path]) -> list[Path]:
    """All ``.bvh`` and ``.amc`` files under the existing ``folders``, sorted."""
    out: list[Path] = []
    for folder in folders:
        root = Path(folder)
        if root.is_dir():
            out += sorted(p for p in root.rglob("*") if p.suffix.lower() in (".bvh", ".amc"))
    return out


def _asf_for(amc: Path) -> Path:
    asfs = sorted(amc.parent.glob("*.asf"))
    for asf in asfs:
        if amc.name.startswith(asf.stem + "_"):
            return asf
    if len(asfs) == 1:
        return asfs[0]
    raise ValueError(f"{amc}: no matching .asf skeleton in {amc.parent}")


def load_clip_joints(path: Path, fps: float, asf: Path | None = None) -> MotionSequence:
    """Read one clip, map it onto the named joints and resample to ``fps`` (nearest frames)."""
    path = Path(path)
    if path.suffix.lower() == ".bvh":
        clip = read_bvh(path)
    else:
        clip = read_amc(path, read_asf(asf or _asf_for(path)))
    joints = clip_named_joints(clip)
    step = max(1, int(round(clip.fps / fps)))
    return MotionSequence(path.stem, joints[::step], clip.fps / step)


def mocap_library(folders: list[str | Path], fps: float) -> list[MotionSequence]:
    """Every clip under ``folders`` as named joints at about ``fps``; unreadable clips raise."""
    return [load_clip_joints(p, fps) for p in find_clips(folders)]


def procedural_library(
    rng: np.random.Generator,
    fps: float,
    random_count: int = 2000,
    motions: list[str] | tuple[str, ...] = (),
    jitter_rad: float = 0.0,
) -> list[MotionSequence]:
    """The parametric motions (several variations) plus grounded random poses.

    Args:
        motions: keep only these parametric motions (empty: all), e.g. ``["t_pose"]`` for a
            forest restricted to the calibration pose (Wei section 6).
        jitter_rad: uniform random offset in [-jitter, jitter] added to every joint angle of
            every parametric pose (then clamped to the limits): variety for small motion sets.
    """
    from depthmocap.shared.kinematics import clamp_to_limits
    from depthmocap.shared.procedural_motion import MOTIONS, ground_poses

    unknown = set(motions) - set(MOTIONS)
    if unknown:
        raise ValueError(f"unknown procedural motions {sorted(unknown)}; known: {list(MOTIONS)}")
    body = BodyShape.default(torch.float64)
    seqs: dict[str, np.ndarray] = {}
    for k in range(3):
        for name, q in procedural_sequences(rng, fps=fps, seconds=4.0, body=body).items():
            if motions and name not in motions:
                continue
            if jitter_rad > 0:
                q = q.copy()
                q[:, 6:] += rng.uniform(-jitter_rad, jitter_rad, q[:, 6:].shape)
                q = clamp_to_limits(torch.as_tensor(q)).numpy()
                q = ground_poses(q, body)
            seqs[f"{name}_{k}"] = q
    if random_count > 0:
        seqs["random"] = random_poses(random_count, rng)
    out = []
    for name, q in seqs.items():
        joints = named_joint_positions(forward_kinematics(torch.as_tensor(q), body)).numpy()
        out.append(MotionSequence(name, joints, fps, q))
    return out


def heading_normalized_joints(joints: np.ndarray) -> np.ndarray:
    """Joints relative to the pelvis, turned about y so the hips' left direction is +x.

    Args:
        joints: (N, J, 3) named joints, y up.
    Returns:
        (N, J, 3): poses that differ only by a position on the floor and a heading coincide.
    """
    pelvis = joints[:, sk.JOINT_NAMES.index("pelvis")]
    left = joints[:, sk.JOINT_NAMES.index("l_hip")] - joints[:, sk.JOINT_NAMES.index("r_hip")]
    yaw = np.arctan2(left[:, 2], left[:, 0])  # turning by it about +y maps `left` onto +x
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.zeros((len(joints), 3, 3))
    rot[:, 0, 0], rot[:, 0, 2], rot[:, 1, 1], rot[:, 2, 0], rot[:, 2, 2] = c, s, 1.0, -s, c
    return np.einsum("nij,nkj->nki", rot, joints - pelvis[:, None])
