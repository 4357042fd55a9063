"""Anny bodies in our body frame: rest shape, skinning weights, part labels.

This module turns one anny phenotype into plain numpy arrays in the project's body frame (an
:class:`AnnyBody`), so that posing (:mod:`train.bodies.skinning`: our own linear blend
skinning, identical to anny's forward pass and about 50 times faster), measuring
(:mod:`train.bodies.measurements`) and rendering never touch anny or torch again. What anny is,
its frame and its bones: :mod:`shared.anny_rig` (shared with personalization).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from depthmocap.shared.anny_rig import (
    ANNY_TO_BODY,
    BONE_SEGMENT,
    DEFAULT_RIG,
    DEFAULT_TOPOLOGY,
    HIP_BONES,
    PHENOTYPE_KEYS,
    SAFE_HEIGHT_RANGE,
    default_cache_dir,
    export_cache_dir,
    is_forbidden_topology,
)
from depthmocap.shared.labels import segment_to_part
from depthmocap.shared.skeleton import SEGMENT_NAMES

if TYPE_CHECKING:  # anny imports torch and builds large data: import it lazily.
    import anny

__all__ = [
    "ANNY_TO_BODY",
    "BONE_SEGMENT",
    "DEFAULT_TOPOLOGY",
    "PHENOTYPE_KEYS",
    "SAFE_HEIGHT_RANGE",
    "AnnyBody",
    "bone_segments",
    "default_cache_dir",
    "load_anny_model",
    "make_body",
    "sample_phenotype",
    "vertex_labels",
]

# Bone whose head->tail segment measures the upper/lower split of each split segment.
_SPLIT_BONE = {"l_thigh": "LeftUpLeg", "r_thigh": "RightUpLeg", "l_shank": "LeftLeg",
               "r_shank": "RightLeg"}  # fmt: skip

_MODELS: dict[tuple[str, str], Any] = {}  # (rig, topology) -> anny.Anny, one build per process


# ---------------------------------------------------------------------------------------------
# Model loading


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
    if is_forbidden_topology(topology):
        raise ValueError(f"topology {topology!r} downloads non-free data; use 'anny'")
    key = (rig, topology)
    if key in _MODELS:
        return _MODELS[key]
    # anny reads ANNY_CACHE_DIR once at import: set it before, and set it explicitly in case
    # anny was imported earlier by someone else.
    cache = export_cache_dir(cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
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

    left_hip, right_hip = (names.index(b) for b in HIP_BONES)
    hip_centre = 0.5 * (heads_a[left_hip] + heads_a[right_hip])

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
