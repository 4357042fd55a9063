"""Anny body meshes in our body frame: rest shape, skinning, part labels, posing.

``anny`` (PyPI; Apache-2.0 code, CC0 MakeHuman data) is a MakeHuman-based statistical body
model. This module turns one anny phenotype into plain numpy arrays in the project's body frame
and poses them with our own linear blend skinning (LBS): identical results to anny's forward
pass ('world-orient' parameterization, tested to 1e-9 m) in about 1 ms per pose instead of
about 55 ms on a 2-core CPU, and it takes the per-bone global rotations that retargeting by
bone directions produces (see ``/work/shared/data/mocap/README.md``).

anny facts this module relies on (read from its source, version 0.6):

- ``anny.Anny(rig="cmu_mb", topology=...)``: 31 bones with CMU names (``BONE_SEGMENT`` lists
  them), ``bone_orientation="blender"`` (bones have heads and tails), rest pose = A-pose.
- Topologies: ``"anny"`` (the native MakeHuman body: 13,718 vertices, 27,420 triangles, with
  eyes and tongue), ``"anny-noeyes-notongue"``, ``"makehuman"`` (quads, unattached helper
  vertices kept), ``"notoes"`` (12,272 vertices, 24,540 triangles), ``"notoes_collapse10pc"``
  (1,229 vertices, 2,454 triangles), ``..._collapse5pc``, ``..._collapse3pc``, ``"soma"``,
  ``"anny_from_soma"``, ``"legacy_default"``. ``"smpl"``/``"smplx"`` download non-free data and
  are refused here.
- Phenotype parameters in [0, 1]: gender (0 = male, 1 = female), age (anchors: 0 baby, 1/3
  child, 2/3 young adult, 1 old), muscle, weight, height, proportions. Heights outside
  [0.2, 0.8] move the knee joint off the mesh (refused by ``make_body``).
- Anny frame: metres, Z up, the body faces -Y, its "Left" bones lie at +X. Since
  up x forward = Z x (-Y) = +X, +X is the person's anatomical left: anny's "Left" is the
  person's left.

Our body frame (as ``shared.skeleton``): x = the person's left, y = up, z = the person's
forward, origin at the hip centre (midpoint of the LeftUpLeg and RightUpLeg heads). The
conversion is the proper rotation ``p_body = ANNY_TO_BODY @ (p_anny - hip_centre_anny)``,
i.e. (x, y, z) = (X, Z, -Y).

Posing convention (``pose_body``): bone b gets a global rotation ``G_b`` relative to its rest
orientation, ``G_b = R_out_bone_posed @ R_body_bone_rest^T``: it maps a direction fixed on the
bone in the rest body frame to the same direction in the output frame. A point x fixed on bone
b goes to ``G_b (x - h_b) + p_b``, where h_b is the rest head and the posed heads follow the
tree, ``p_b = p_parent + G_parent (h_b - h_parent)``. The body-frame origin (hip centre) rides
on the root bone (Hips) and goes to ``root_position``. All rotations identity and root 0 give
the rest mesh. The output frame is whatever the rotations map into: to pose directly in camera
coordinates, left-multiply every ``G_b`` by the root orientation and pass the camera-frame root
position.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from shared.labels import segment_to_part
from shared.skeleton import JOINT_NAMES, NUM_SEGMENTS, SEGMENT_NAMES

if TYPE_CHECKING:  # anny imports torch and builds large data: import it lazily.
    import anny

__all__ = [
    "ANNY_TO_BODY",
    "BONE_SEGMENT",
    "DEFAULT_TOPOLOGY",
    "PHENOTYPE_KEYS",
    "SAFE_HEIGHT_RANGE",
    "AnnyBody",
    "PosedBody",
    "anatomical_joints",
    "body_measurements",
    "bone_segments",
    "default_cache_dir",
    "load_anny_model",
    "make_body",
    "pose_body",
    "sample_phenotype",
    "segment_lengths",
    "segment_to_bone_rotations",
    "vertex_labels",
]

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_RIG = "cmu_mb"
# The native MakeHuman mesh (13,718 vertices, 27,420 triangles).
DEFAULT_TOPOLOGY = "anny"
# Topologies that download non-commercial data on first use: never allowed here.
_FORBIDDEN_TOPOLOGIES = ("smpl", "smplx")

# anny frame (X = left, Y = backward, Z = up) -> body frame (x = left, y = up, z = forward).
ANNY_TO_BODY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

PHENOTYPE_KEYS: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions")
SAFE_HEIGHT_RANGE = (0.2, 0.8)

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
# Bone whose head->tail segment measures the upper/lower split of each split segment.
_SPLIT_BONE = {"l_thigh": "LeftUpLeg", "r_thigh": "RightUpLeg", "l_shank": "LeftLeg",
               "r_shank": "RightLeg"}  # fmt: skip

# Named joints of shared.skeleton.JOINT_NAMES as weighted sums of bone heads/tails.
_JOINT_RECIPES: dict[str, tuple[tuple[str, str, float], ...]] = {
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
assert tuple(_JOINT_RECIPES) == JOINT_NAMES

# Joint-to-joint definition of each segment's length, matching shared.body.DEFAULT_LENGTHS:
# (start joint, end joint) as named joints or bone ends.
_SEGMENT_ENDS: dict[str, tuple[str, str]] = {
    "pelvis": ("pelvis", "LowerBack.head"),
    "abdomen": ("LowerBack.head", "spine"),
    "chest": ("spine", "neck"),
    "neck": ("neck", "Head.head"),
    "head": ("Head.head", "Head.tail"),
    "l_clavicle": ("neck", "l_shoulder"),
    "r_clavicle": ("neck", "r_shoulder"),
    "l_upper_arm": ("l_shoulder", "l_elbow"),
    "r_upper_arm": ("r_shoulder", "r_elbow"),
    "l_forearm": ("l_elbow", "l_wrist"),
    "r_forearm": ("r_elbow", "r_wrist"),
    "l_thigh": ("l_hip", "l_knee"),
    "r_thigh": ("r_hip", "r_knee"),
    "l_shank": ("l_knee", "l_ankle"),
    "r_shank": ("r_knee", "r_ankle"),
}

_MODELS: dict[tuple[str, str], Any] = {}  # (rig, topology) -> anny.Anny, one build per process


# ---------------------------------------------------------------------------------------------
# Model loading


def default_cache_dir() -> Path:
    """Where anny caches its built model data: ``$ANNY_CACHE_DIR`` or ``<repo>/.cache/anny``."""
    env = os.environ.get("ANNY_CACHE_DIR")
    return Path(env) if env else REPO_ROOT / ".cache" / "anny"


def load_anny_model(
    topology: str = DEFAULT_TOPOLOGY, rig: str = DEFAULT_RIG, cache_dir: str | Path | None = None
) -> anny.Anny:
    """The anny model for ``(rig, topology)``, built once per process.

    The first build on a machine takes 40-80 s and writes up to 0.8 GB under the cache
    directory; later processes load it from there in about 2 s.

    Args:
        topology: anny topology name (``DEFAULT_TOPOLOGY`` = native mesh); smpl/smplx refused.
        rig: anny rig name; the rest of this module expects ``"cmu_mb"``.
        cache_dir: anny cache directory; default ``default_cache_dir()``.
    Returns:
        The ``anny.Anny`` torch module (float64, CPU), in eval mode.
    """
    if topology.split("-")[0] in _FORBIDDEN_TOPOLOGIES:
        raise ValueError(f"topology {topology!r} downloads non-free data; use 'anny'")
    key = (rig, topology)
    if key in _MODELS:
        return _MODELS[key]
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    cache.mkdir(parents=True, exist_ok=True)
    # anny reads ANNY_CACHE_DIR once at import: set it before, and set it explicitly in case
    # anny was imported earlier by someone else.
    os.environ.setdefault("ANNY_CACHE_DIR", str(cache))
    import anny
    import anny.paths

    anny.paths.set_anny_cache_path(cache)
    # Plain torch LBS: the default warp backend needs a JIT compile and is not used here.
    model = anny.Anny(rig=rig, topology=topology, skinning_method="lbs")
    model.eval()
    _MODELS[key] = model
    return model


# ---------------------------------------------------------------------------------------------
# Phenotypes


def sample_phenotype(rng: np.random.Generator) -> dict[str, float]:
    """A random adult anny phenotype (values in [0, 1]).

    Continuous draws, so every call gives a distinct shape: both genders (mostly clearly male
    or female, some in between), adult ages (anny age 0.70-0.92, about 17-80 years by anny's
    own calibration), a wide spread of muscle, weight and proportions. Height centres on anny's
    own adult calibration (``shape_distribution``: Beta means 0.39 male, 0.35 female, s.d. 0.07),
    widened to s.d. 0.09 for coverage and clipped well inside ``SAFE_HEIGHT_RANGE``. Measured on
    60 draws: stature 1.74 +- 0.09 m (male), 1.63 +- 0.07 m (female), range 1.49-1.91 m.

    Args:
        rng: numpy random generator; the result depends only on its state.
    Returns:
        dict with the keys ``PHENOTYPE_KEYS``, python floats.
    """
    female = rng.random() < 0.5
    # Distance from the pure male/female target: half-normal, so blends are rarer.
    blend = min(abs(rng.normal(0.0, 0.15)), 0.5)
    gender = 1.0 - blend if female else blend
    lo, hi = SAFE_HEIGHT_RANGE
    height = np.clip(rng.normal(0.39 - 0.04 * gender, 0.09), lo + 0.03, hi - 0.03)
    return {
        "gender": float(gender),
        "age": float(rng.uniform(0.70, 0.92)),
        "muscle": float(rng.uniform(0.1, 0.9)),
        "weight": float(rng.uniform(0.1, 0.9)),
        "height": float(height),
        "proportions": float(rng.uniform(0.0, 1.0)),
    }


def _check_phenotype(phenotype: dict[str, float]) -> dict[str, float]:
    unknown = set(phenotype) - set(PHENOTYPE_KEYS)
    if unknown:
        raise ValueError(f"unknown phenotype keys {sorted(unknown)}; known: {PHENOTYPE_KEYS}")
    full = {k: float(phenotype.get(k, 0.5)) for k in PHENOTYPE_KEYS}
    for k, v in full.items():
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"phenotype {k}={v} outside [0, 1]")
    lo, hi = SAFE_HEIGHT_RANGE
    if not lo <= full["height"] <= hi:
        raise ValueError(f"height {full['height']} outside {SAFE_HEIGHT_RANGE}: knee off mesh")
    return full


# ---------------------------------------------------------------------------------------------
# Rest body


@dataclasses.dataclass(frozen=True, eq=False)
class AnnyBody:
    """One anny body in its rest A-pose, in our body frame (metres; see the module docstring).

    Attributes:
        phenotype: the phenotype it was built from (all ``PHENOTYPE_KEYS``).
        vertices: (V, 3) float64 rest vertices.
        faces: (F, 3) int64 triangles, counter-clockwise seen from outside.
        bone_names: (n_bones,) anny bone names (cmu_mb: 31).
        bone_parents: (n_bones,) int64 parent index, -1 for the root; parents precede children.
        bone_heads: (n_bones, 3) float64 rest bone heads (joint positions).
        bone_tails: (n_bones, 3) float64 rest bone tails.
        skin_weights: (V, n_bones) float64 dense LBS weights, rows sum to 1.
        vertex_segment: (V,) int64 shared.skeleton segment of each vertex (its dominant bone's).
        labels: (V,) uint8 part labels of shared.labels (1..19; never background).
        hip_centre_anny: (3,) the body-frame origin in anny's frame (for converting back).
    """

    phenotype: dict[str, float]
    vertices: np.ndarray
    faces: np.ndarray
    bone_names: tuple[str, ...]
    bone_parents: np.ndarray
    bone_heads: np.ndarray
    bone_tails: np.ndarray
    skin_weights: np.ndarray
    vertex_segment: np.ndarray
    labels: np.ndarray
    hip_centre_anny: np.ndarray
    # Per-body derived arrays for pose_body (dtype-converted weights, chain matrices).
    _cache: dict = dataclasses.field(default_factory=dict, repr=False)

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_bones(self) -> int:
        return len(self.bone_names)

    def bone_index(self, name: str) -> int:
        """Index of the bone called ``name``."""
        return self.bone_names.index(name)


def _to_numpy(x: Any) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def _dense_weights(weights: np.ndarray, indices: np.ndarray, num_bones: int) -> np.ndarray:
    """(V, K) sparse weights and bone indices -> (V, n_bones) dense weights.

    Accumulates so that repeated indices (padding entries of weight 0) are harmless.
    """
    dense = np.zeros((weights.shape[0], num_bones))
    rows = np.broadcast_to(np.arange(weights.shape[0])[:, None], indices.shape)
    np.add.at(dense, (rows, indices), weights)
    return dense / dense.sum(axis=1, keepdims=True)


def bone_segments(bone_names: tuple[str, ...] | list[str]) -> np.ndarray:
    """(n_bones,) int64 shared.skeleton segment index of each bone (``BONE_SEGMENT``)."""
    missing = [n for n in bone_names if n not in BONE_SEGMENT]
    if missing:
        raise KeyError(f"bones without a segment: {missing} (is the rig cmu_mb?)")
    return np.array([SEGMENT_NAMES.index(BONE_SEGMENT[n]) for n in bone_names], dtype=np.int64)


def vertex_labels(
    vertices: np.ndarray,
    skin_weights: np.ndarray,
    bone_names: tuple[str, ...],
    bone_heads: np.ndarray,
    bone_tails: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Segment and part label of every vertex, from its dominant skinning bone.

    Thigh and shank vertices are split at mid-length of the thigh bone (hip->knee) and of the
    shank bone (knee->ankle) by projecting them onto that bone; foot vertices project beyond
    the ankle and so are "lower".

    Args:
        vertices: (V, 3) rest vertices.
        skin_weights: (V, n_bones) dense weights.
        bone_names: (n_bones,) names.
        bone_heads, bone_tails: (n_bones, 3) rest bone ends.
    Returns:
        segment (V,) int64 and labels (V,) uint8.
    """
    segment = bone_segments(bone_names)[np.argmax(skin_weights, axis=1)]
    fraction = np.zeros(vertices.shape[0])
    for seg_name, bone_name in _SPLIT_BONE.items():
        b = bone_names.index(bone_name)
        axis = bone_tails[b] - bone_heads[b]
        on_segment = segment == SEGMENT_NAMES.index(seg_name)
        fraction[on_segment] = (vertices[on_segment] - bone_heads[b]) @ axis / (axis @ axis)
    return segment, segment_to_part(segment, fraction)


def make_body(
    phenotype: dict[str, float] | None = None, topology: str = DEFAULT_TOPOLOGY
) -> AnnyBody:
    """Build the rest body of one phenotype (about 70-80 ms once the model is loaded).

    Args:
        phenotype: values in [0, 1] for any of ``PHENOTYPE_KEYS`` (missing ones: 0.5);
            height must lie in ``SAFE_HEIGHT_RANGE``.
        topology: anny topology (``load_anny_model``).
    Returns:
        The ``AnnyBody`` in our body frame.
    """
    import torch

    full = _check_phenotype(phenotype or {})
    model = load_anny_model(topology=topology)
    with torch.no_grad():
        out = model(phenotype_kwargs=full)  # identity pose; we read only the rest_* outputs
    verts_a = _to_numpy(out["rest_vertices"][0]).astype(np.float64)
    heads_a = _to_numpy(out["rest_bone_heads"][0]).astype(np.float64)
    tails_a = _to_numpy(out["rest_bone_tails"][0]).astype(np.float64)
    names = tuple(model.bone_labels)
    parents = np.array(model.bone_parents, dtype=np.int64)
    if not np.all(parents[1:] < np.arange(1, len(parents))):
        raise ValueError("anny bone order: parents must precede children")

    hip_centre = 0.5 * (heads_a[names.index("LeftUpLeg")] + heads_a[names.index("RightUpLeg")])

    def to_body(p: np.ndarray) -> np.ndarray:
        return (p - hip_centre) @ ANNY_TO_BODY.T

    faces = model.faces if model.faces.shape[1] == 3 else model.get_triangular_faces()
    weights = _dense_weights(
        _to_numpy(model.vertex_bone_weights).astype(np.float64),
        _to_numpy(model.vertex_bone_indices).astype(np.int64),
        len(names),
    )
    vertices, heads, tails = to_body(verts_a), to_body(heads_a), to_body(tails_a)
    segment, labels = vertex_labels(vertices, weights, names, heads, tails)
    return AnnyBody(
        phenotype=full,
        vertices=vertices,
        faces=_to_numpy(faces).astype(np.int64),
        bone_names=names,
        bone_parents=parents,
        bone_heads=heads,
        bone_tails=tails,
        skin_weights=weights,
        vertex_segment=segment,
        labels=labels,
        hip_centre_anny=hip_centre,
    )


# ---------------------------------------------------------------------------------------------
# Posing


@dataclasses.dataclass(frozen=True)
class PosedBody:
    """Output of ``pose_body``; ``...`` are the broadcast batch dimensions of its inputs.

    Attributes:
        vertices: (..., V, 3) posed vertices.
        bone_heads: (..., n_bones, 3) posed bone heads.
        bone_tails: (..., n_bones, 3) posed bone tails.
    """

    vertices: np.ndarray
    bone_heads: np.ndarray
    bone_tails: np.ndarray


@functools.lru_cache(maxsize=8)
def _chain_matrices(parents: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Tree structure for the closed-form posed heads.

    Returns:
        lever_bone (n,): the bone whose rotation carries each bone's head offset (its parent;
            the root's own for the root, whose offset is measured from the origin), and
        path (n, n): path[b, a] = 1 when a is b or one of its ancestors.
    """
    n = len(parents)
    lever_bone = np.array([0] + list(parents[1:]), dtype=np.int64)
    path = np.zeros((n, n))
    for b in range(n):
        a = b
        while a >= 0:
            path[b, a] = 1.0
            a = parents[a]
    return lever_bone, path


def _pose_arrays(body: AnnyBody, dtype: np.dtype) -> tuple[np.ndarray, ...]:
    """Rest arrays in ``dtype`` (cached on the body, conversions would cost per call)."""
    key = ("pose", np.dtype(dtype).str)
    if key not in body._cache:
        lever_bone, path = _chain_matrices(tuple(int(p) for p in body.bone_parents))
        offsets = body.bone_heads - np.where(
            body.bone_parents[:, None] >= 0, body.bone_heads[body.bone_parents], 0.0
        )
        body._cache[key] = tuple(
            np.ascontiguousarray(a, dtype=dtype)
            for a in (body.skin_weights, body.vertices, body.bone_heads,
                      body.bone_tails - body.bone_heads, offsets, path)
        ) + (lever_bone,)  # fmt: skip
    return body._cache[key]


def pose_body(body: AnnyBody, global_rotations: np.ndarray, root_position: np.ndarray) -> PosedBody:
    """Pose the body by linear blend skinning with per-bone global rotations.

    Convention (module docstring): ``global_rotations[..., b]`` = G_b = R_out_bone_posed @
    R_body_bone_rest^T; a point x on bone b maps to G_b (x - h_b) + p_b; the body-frame origin
    (hip centre) rides on the root bone and maps to ``root_position``. Computation follows the
    rotations' floating dtype (float32 is about twice as fast as float64).

    Args:
        body: the rest body.
        global_rotations: (..., n_bones, 3, 3) rotation matrices.
        root_position: (..., 3) where the hip centre goes.
    Returns:
        ``PosedBody`` with (..., V, 3) vertices and (..., n_bones, 3) bone heads/tails.
    """
    rot = np.asarray(global_rotations)
    n = body.num_bones
    if rot.shape[-3:] != (n, 3, 3):
        raise ValueError(f"global_rotations must be (..., {n}, 3, 3), got {rot.shape}")
    dtype = np.result_type(rot.dtype, np.float32)
    root = np.asarray(root_position, dtype=dtype)
    if root.shape[-1:] != (3,):
        raise ValueError(f"root_position must be (..., 3), got {root.shape}")
    batch = np.broadcast_shapes(rot.shape[:-3], root.shape[:-1])
    rot = np.broadcast_to(rot.astype(dtype, copy=False), batch + (n, 3, 3))
    root = np.broadcast_to(root, batch + (3,))
    weights, rest, heads, bone_vec, offsets, path, lever_bone = _pose_arrays(body, dtype)

    # p_b = root + sum over the path root..b of G_lever(a) offset_a (closed-form chain).
    levers = np.einsum("...bij,bj->...bi", rot[..., lever_bone, :, :], offsets)
    posed_heads = root[..., None, :] + path @ levers
    posed_tails = posed_heads + np.einsum("...bij,bj->...bi", rot, bone_vec)
    # Per-bone affine maps x -> G_b x + t_b, t_b = p_b - G_b h_b, stored as the three columns
    # of G_b followed by t_b so that one matrix product blends them all.
    trans = posed_heads - np.einsum("...bij,bj->...bi", rot, heads)
    affine = np.concatenate([np.swapaxes(rot, -1, -2).reshape(batch + (n, 9)), trans], -1)
    blended = weights @ affine  # (..., V, 12)
    verts = (
        blended[..., 0:3] * rest[:, 0:1]
        + blended[..., 3:6] * rest[:, 1:2]
        + blended[..., 6:9] * rest[:, 2:3]
        + blended[..., 9:12]
    )
    return PosedBody(vertices=verts, bone_heads=posed_heads, bone_tails=posed_tails)


def segment_to_bone_rotations(body: AnnyBody, segment_rotations: np.ndarray) -> np.ndarray:
    """Give every bone the global rotation of the segment it belongs to (``BONE_SEGMENT``).

    Args:
        body: the body (for its bone names).
        segment_rotations: (..., 15, 3, 3) per-segment rotations in SEGMENT_NAMES order.
    Returns:
        (..., n_bones, 3, 3) rotations for ``pose_body``.
    """
    rot = np.asarray(segment_rotations)
    if rot.shape[-3:] != (NUM_SEGMENTS, 3, 3):
        raise ValueError(f"segment_rotations must be (..., {NUM_SEGMENTS}, 3, 3)")
    return rot[..., bone_segments(body.bone_names), :, :]


# ---------------------------------------------------------------------------------------------
# Joints and measurements


def _bone_end(body: AnnyBody, heads: np.ndarray, tails: np.ndarray, spec: str) -> np.ndarray:
    name, end = spec.split(".")
    return (heads if end == "head" else tails)[..., body.bone_index(name), :]


def anatomical_joints(body: AnnyBody, posed: PosedBody | None = None) -> np.ndarray:
    """The named joints of ``shared.skeleton.JOINT_NAMES`` from bone heads/tails.

    head = middle of the Head bone; neck = Neck head (base of the neck); spine = Spine head
    (top of the lumbar spine, where our chest segment starts); pelvis = midpoint of the hips;
    shoulder/elbow/wrist = Arm/ForeArm/Hand heads; hip/knee/ankle = UpLeg/Leg/Foot heads.

    Args:
        body: the body.
        posed: a ``pose_body`` result; None for the rest pose.
    Returns:
        (..., 16, 3) joint positions in JOINT_NAMES order.
    """
    heads = body.bone_heads if posed is None else posed.bone_heads
    tails = body.bone_tails if posed is None else posed.bone_tails
    key = ("joints",)
    if key not in body._cache:
        n = body.num_bones
        mix = np.zeros((len(JOINT_NAMES), 2 * n))
        for j, name in enumerate(JOINT_NAMES):
            for bone, end, w in _JOINT_RECIPES[name]:
                mix[j, body.bone_index(bone) + (n if end == "tail" else 0)] += w
        body._cache[key] = mix
    mix = body._cache[key]
    return (mix @ np.concatenate([heads, tails], axis=-2)).astype(heads.dtype, copy=False)


def segment_lengths(body: AnnyBody) -> np.ndarray:
    """(15,) rest joint-to-joint segment lengths in SEGMENT_NAMES order, defined as
    ``shared.body.DEFAULT_LENGTHS`` (e.g. thigh = hip->knee, clavicle = neck base->shoulder,
    head = Head bone length, i.e. top of the neck to about the crown)."""
    joints = dict(zip(JOINT_NAMES, anatomical_joints(body)))

    def point(spec: str) -> np.ndarray:
        return (
            joints[spec]
            if spec in joints
            else _bone_end(body, body.bone_heads, body.bone_tails, spec)
        )

    return np.array(
        [np.linalg.norm(point(b) - point(a)) for a, b in (_SEGMENT_ENDS[s] for s in SEGMENT_NAMES)]
    )


def body_measurements(body: AnnyBody) -> dict[str, float]:
    """Rest measurements for comparing with the cylinder model's defaults (metres).

    Returns:
        dict with every segment length (by segment name), ``stature`` (mesh height),
        ``hip_half_width`` (half the distance between the hip joints), ``shoulder_width``
        (between the shoulder joints), ``ankle_height`` (ankle above the sole), ``hand_length``
        (left wrist to the farthest hand/finger vertex, i.e. the fingertip).
    """
    joints = dict(zip(JOINT_NAMES, anatomical_joints(body)))
    out = {name: float(v) for name, v in zip(SEGMENT_NAMES, segment_lengths(body))}
    y = body.vertices[:, 1]
    # Hand = vertices whose dominant bone is the hand or a finger (not the forearm itself).
    dominant = np.array(body.bone_names)[np.argmax(body.skin_weights, axis=1)]
    hand = body.vertices[
        np.isin(dominant, ["LeftHand", "LThumb", "LeftFingerBase", "LeftHandFinger1"])
    ]
    out.update(
        stature=float(y.max() - y.min()),
        hip_half_width=float(0.5 * np.linalg.norm(joints["l_hip"] - joints["r_hip"])),
        shoulder_width=float(np.linalg.norm(joints["l_shoulder"] - joints["r_shoulder"])),
        ankle_height=float(0.5 * (joints["l_ankle"][1] + joints["r_ankle"][1]) - y.min()),
        hand_length=float(np.linalg.norm(hand - joints["l_wrist"], axis=1).max()),
    )
    return out
