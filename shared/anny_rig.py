"""The facts about ``anny`` that the project relies on, in one place (no ``anny`` import).

``anny`` (PyPI; Apache-2.0 code, CC0 MakeHuman data) is a MakeHuman-based statistical body
model. Two places build on it: synthesis (:mod:`train.bodies.anny_body`, rest bodies and part
labels) and personalization (:mod:`runtime.personalize.shape_model`, the fitted shape model).
Both must agree on how anny's frame maps onto ours, which of its bones belong to which
tracking-skeleton segment and where our named joints sit on its bones, or the personalized
body and the synthetic ground truth would silently differ. This module holds those facts; the
``anny`` package itself stays a lazy import of its two users (it pulls in torch and large data).

anny facts (read from its source, version 0.6):

- ``anny.Anny(rig="cmu_mb", topology=...)``: 31 bones with CMU names (``BONE_SEGMENT`` lists
  them), ``bone_orientation="blender"`` (bones have heads and tails), rest pose = A-pose.
- Topologies: ``"anny"`` (the native MakeHuman body: 13,718 vertices, 27,420 triangles, with
  eyes and tongue), ``"anny-noeyes-notongue"``, ``"makehuman"`` (quads, unattached helper
  vertices kept), ``"notoes"`` (12,272 vertices, 24,540 triangles), ``"notoes_collapse10pc"``
  (1,229 vertices, 2,454 triangles), ``..._collapse5pc``, ``..._collapse3pc``, ``"soma"``,
  ``"anny_from_soma"``, ``"legacy_default"``. ``"smpl"``/``"smplx"`` download non-free data and
  are refused (:func:`is_forbidden_topology`).
- Phenotype parameters in [0, 1] (``PHENOTYPE_KEYS``): gender (0 = male, 1 = female), age
  (anchors: 0 baby, 1/3 child, 2/3 young adult, 1 old), muscle, weight, height, proportions.
  Heights outside ``SAFE_HEIGHT_RANGE`` move the knee joint off the mesh.
- Anny frame: metres, Z up, the body faces -Y, its "Left" bones lie at +X. Since
  up x forward = Z x (-Y) = +X, +X is the person's anatomical left: anny's "Left" is the
  person's left.
- anny reads ``ANNY_CACHE_DIR`` once, at import, for where it caches its built model data
  (:func:`default_cache_dir`, :func:`export_cache_dir`).

Our body frame (as ``shared.skeleton``): x = the person's left, y = up, z = the person's
forward, origin at the hip centre (midpoint of the LeftUpLeg and RightUpLeg heads). The
conversion is the proper rotation ``p_body = ANNY_TO_BODY @ (p_anny - hip_centre_anny)``,
i.e. (x, y, z) = (X, Z, -Y).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .resources import cache_root

__all__ = [
    "ANNY_TO_BODY",
    "BONE_SEGMENT",
    "DEFAULT_RIG",
    "DEFAULT_TOPOLOGY",
    "FORBIDDEN_TOPOLOGIES",
    "HIP_BONES",
    "JOINT_RECIPES",
    "PHENOTYPE_KEYS",
    "SAFE_HEIGHT_RANGE",
    "SEGMENT_BONES",
    "default_cache_dir",
    "export_cache_dir",
    "is_forbidden_topology",
]

# The rig whose bone names the tables below use.
DEFAULT_RIG = "cmu_mb"
# The native MakeHuman mesh (13,718 vertices, 27,420 triangles).
DEFAULT_TOPOLOGY = "anny"
# Topologies that download non-commercial data on first use: never allowed here.
FORBIDDEN_TOPOLOGIES = ("smpl", "smplx")

# anny frame (X = left, Y = backward, Z = up) -> body frame (x = left, y = up, z = forward).
ANNY_TO_BODY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

PHENOTYPE_KEYS: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions")
SAFE_HEIGHT_RANGE = (0.2, 0.8)

# The two bones whose heads are the hip joints; their midpoint is the body-frame origin.
HIP_BONES = ("LeftUpLeg", "RightUpLeg")

# Segment of shared.skeleton that each cmu_mb bone's vertices belong to.
BONE_SEGMENT: dict[str, str] = {
    "Hips": "pelvis",
    "LHipJoint": "pelvis",
    "RHipJoint": "pelvis",
    "LowerBack": "abdomen",
    "Spine": "chest",
    "Spine1": "chest",
    "Neck": "neck",
    "Neck1": "neck",
    "Head": "head",
    "LeftShoulder": "l_clavicle",
    "RightShoulder": "r_clavicle",
    "LeftArm": "l_upper_arm",
    "RightArm": "r_upper_arm",
    # Our forearm segment's geometry covers the hand.
    "LeftForeArm": "l_forearm",
    "LeftHand": "l_forearm",
    "LThumb": "l_forearm",
    "LeftFingerBase": "l_forearm",
    "LeftHandFinger1": "l_forearm",
    "RightForeArm": "r_forearm",
    "RightHand": "r_forearm",
    "RThumb": "r_forearm",
    "RightFingerBase": "r_forearm",
    "RightHandFinger1": "r_forearm",
    "LeftUpLeg": "l_thigh",
    "RightUpLeg": "r_thigh",
    # Our shank segment's geometry reaches the sole: the foot is its lower part.
    "LeftLeg": "l_shank",
    "LeftFoot": "l_shank",
    "LeftToeBase": "l_shank",
    "RightLeg": "r_shank",
    "RightFoot": "r_shank",
    "RightToeBase": "r_shank",
}


def _segment_bones() -> dict[str, tuple[str, ...]]:
    out: dict[str, list[str]] = {}
    for bone, segment in BONE_SEGMENT.items():
        out.setdefault(segment, []).append(bone)
    return {segment: tuple(bones) for segment, bones in out.items()}


# The inverse table: cmu_mb bones of each segment, in BONE_SEGMENT order (the first bone of a
# segment is the one running along it, e.g. LeftForeArm for l_forearm).
SEGMENT_BONES: dict[str, tuple[str, ...]] = _segment_bones()

# Named joints of shared.skeleton.JOINT_NAMES (same order) as weighted sums of bone ends:
# (bone, "head" or "tail", weight).
JOINT_RECIPES: dict[str, tuple[tuple[str, str, float], ...]] = {
    "head": (("Head", "head", 0.5), ("Head", "tail", 0.5)),  # middle of the Head bone
    "neck": (("Neck", "head", 1.0),),  # base of the neck = top of Spine1
    "spine": (("Spine", "head", 1.0),),  # top of the lumbar spine (LowerBack tail)
    "pelvis": (("LeftUpLeg", "head", 0.5), ("RightUpLeg", "head", 0.5)),  # hip centre
    "l_shoulder": (("LeftArm", "head", 1.0),),
    "r_shoulder": (("RightArm", "head", 1.0),),
    "l_elbow": (("LeftForeArm", "head", 1.0),),
    "r_elbow": (("RightForeArm", "head", 1.0),),
    "l_wrist": (("LeftHand", "head", 1.0),),
    "r_wrist": (("RightHand", "head", 1.0),),
    "l_hip": (("LeftUpLeg", "head", 1.0),),
    "r_hip": (("RightUpLeg", "head", 1.0),),
    "l_knee": (("LeftLeg", "head", 1.0),),
    "r_knee": (("RightLeg", "head", 1.0),),
    "l_ankle": (("LeftFoot", "head", 1.0),),
    "r_ankle": (("RightFoot", "head", 1.0),),
}


def is_forbidden_topology(topology: str) -> bool:
    """True for topologies that download non-free data (smpl, smplx and their variants)."""
    return topology.split("-")[0] in FORBIDDEN_TOPOLOGIES


def default_cache_dir() -> Path:
    """Where anny caches its built model data: ``$ANNY_CACHE_DIR`` or ``<cache root>/anny``
    (:func:`depthmocap.shared.resources.cache_root`)."""
    env = os.environ.get("ANNY_CACHE_DIR")
    return Path(env) if env else cache_root() / "anny"


def export_cache_dir(cache_dir: str | Path | None = None) -> Path:
    """Resolve the anny cache directory and publish it as ``ANNY_CACHE_DIR``, unless set.

    anny reads the variable once, at import: call this before importing anny (and still pass
    the result to ``anny.paths.set_anny_cache_path``, in case anny was imported earlier).

    Args:
        cache_dir: the directory; None for :func:`default_cache_dir`.
    Returns:
        the directory as a ``Path``.
    """
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    os.environ.setdefault("ANNY_CACHE_DIR", str(cache))
    return cache
