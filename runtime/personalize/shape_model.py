"""The statistical body model of personalization (Helten et al. 2013, section III-A), on ``anny``.

Helten's model is a base mesh plus a linear basis of the 13 most significant eigenvectors of a
scanned population, rigged with a skeleton and posed by linear blend skinning (LBS). Here:

* **Shape** phi = (phenotype, local). ``phenotype`` are anny's six macro parameters (gender,
  age, muscle, weight, height, proportions in [0, 1]) that anny maps, piecewise-linearly, to
  coefficients of its phenotype blendshapes; ``local`` are coefficients of a small PCA basis of
  anny's *local changes* (MakeHuman's per-region sliders: limb lengths and girths, torso, hips,
  neck, feet...), the residual shape variation the phenotype does not explain. The PCA is built
  once from random slider settings (:func:`build_local_basis`, face sliders left out: the head
  is not evaluated) and stored as a small ``.npz`` under ``.cache/personalize/``; coefficients
  are in units of one population standard deviation.
* **Rest mesh** = anny template + phenotype blendshapes + local basis, in our body frame
  (x = the person's left, y = up, z = forward, origin at the hip centre; ``ANNY_TO_BODY``,
  with the other anny facts in :mod:`shared.anny_rig`).
  Bone heads and tails follow the same linear model, so the skeleton moves with the shape.
* **Pose**: the 34-DoF tracking skeleton q of :mod:`shared.skeleton` drives the mesh, as in
  ``train.bodies.posing.pose_anny``: every anny bone takes the world rotation of its skeleton
  segment; arm-chain bones first get a fixed rotation turning their A-pose rest direction onto
  the segment axis (so q = 0 means arms hanging down). Poses are then directly comparable
  with the ground truth of synthetic recordings and with the tracker's q.

Only this module touches ``anny`` (imported lazily: it is the optional ``personalize`` extra).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.anny_rig import (
    ANNY_TO_BODY,
    DEFAULT_RIG,
    HIP_BONES,
    PHENOTYPE_KEYS,
    SAFE_HEIGHT_RANGE,
    SEGMENT_BONES,
    export_cache_dir,
    is_forbidden_topology,
)
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics
from depthmocap.shared.resources import cache_root

__all__ = [
    "ANNY_TO_BODY",
    "PHENOTYPE_KEYS",
    "PHENOTYPE_BOUNDS",
    "SEGMENT_BONES",
    "AnnyUnavailableError",
    "RestShape",
    "ShapeModel",
    "build_local_basis",
    "default_basis_path",
    "load_shape_model",
    "vertex_normals",
]

# Search box of the fit: adults (anny age 2/3 = young adult, 1 = old) and the heights whose
# knee stays on the mesh.
PHENOTYPE_BOUNDS = np.array(
    [[0.0, 1.0], [0.6, 1.0], [0.0, 1.0], [0.0, 1.0], list(SAFE_HEIGHT_RANGE), [0.0, 1.0]]
)
_ARM_SEGMENTS = ("l_clavicle", "r_clavicle", "l_upper_arm", "r_upper_arm", "l_forearm", "r_forearm")
# Local-change sliders of the face and head: not part of the body basis.
_FACE_PREFIXES = (
    "l-cheek", "r-cheek", "chin", "l-ear", "r-ear", "eyebrows", "l-eye", "r-eye", "forehead",
    "head-", "mouth", "nose", "bulge",
)  # fmt: skip
BASIS_FORMAT = "depthmocap-anny-local-basis"
BASIS_VERSION = 1


class AnnyUnavailableError(ValueError):
    """The optional body model (``anny``) is not installed or cannot be built."""


@dataclass
class RestShape:
    """A rest (A-pose) body in the body frame, batch-first; metres.

    Attributes:
        vertices: (B, V, 3).
        heads: (B, n_bones, 3) bone heads (joints).
        tails: (B, n_bones, 3) bone tails.
    """

    vertices: torch.Tensor
    heads: torch.Tensor
    tails: torch.Tensor


def default_basis_path(topology: str = "anny") -> Path:
    """``<$DEPTHMOCAP_CACHE or <repo>/.cache>/personalize/local_basis_<topology>.npz``."""
    root = cache_root()
    return root / "personalize" / f"local_basis_{topology}.npz"


def _import_anny(cache_dir: Path | None) -> Any:
    cache = export_cache_dir(cache_dir)
    try:
        import anny
        import anny.paths
    except ImportError:
        raise AnnyUnavailableError(
            "the body model package 'anny' is not installed (pip install 'depthmocap[personalize]')"
        ) from None
    anny.paths.set_anny_cache_path(cache)
    return anny


def _anny_model(topology: str, local_changes: str, cache_dir: Path | None) -> Any:
    if is_forbidden_topology(topology):
        raise AnnyUnavailableError(f"topology {topology!r} downloads non-free data; use 'anny'")
    anny = _import_anny(cache_dir)
    kwargs = {"phenotype_blendshapes": "original"} if local_changes != "none" else {}
    model = anny.Anny(
        rig=DEFAULT_RIG,
        topology=topology,
        local_changes=local_changes,
        skinning_method="lbs",
        **kwargs,
    )
    return model.eval()


def build_local_basis(
    path: str | Path | None = None,
    topology: str = "anny",
    rank: int = 12,
    samples: int = 400,
    slider_range: float = 0.5,
    seed: int = 0,
    cache_dir: Path | None = None,
) -> Path:
    """Build and save the PCA basis of anny's body local changes (about 10 s, once).

    Every sample sets each body slider uniformly in ``[-slider_range, slider_range]``; its
    offset of vertices, bone heads and tails (relative to the hip centre, so pure shifts of
    the whole body do not count) is one row. The basis is the leading ``rank`` right singular
    vectors of the (uncentred, so that zero coefficients mean no local change) sample
    matrix, each scaled by its standard deviation.

    Returns:
        the path written (``default_basis_path(topology)`` when None).
    """
    model = _anny_model(topology, "default", cache_dir)
    labels = list(model.local_change_labels)
    n_lc = len(labels)
    body = np.array([not lb.startswith(_FACE_PREFIXES) for lb in labels])

    # Local-change blendshapes are the last 2 n_lc ones, (+, -) interleaved per slider.
    def block(x: torch.Tensor) -> np.ndarray:
        return x[-2 * n_lc :].detach().double().numpy()

    verts, heads, tails = (
        block(model.blendshapes),
        block(model.bone_heads_blendshapes),
        block(model.bone_tails_blendshapes),
    )
    targets = np.concatenate([verts, heads, tails], 1)  # (2 n_lc, V + 2 nb, 3)
    rng = np.random.default_rng(seed)
    value = rng.uniform(-slider_range, slider_range, (samples, n_lc)) * body
    weights = np.zeros((samples, 2 * n_lc))
    weights[:, 0::2], weights[:, 1::2] = np.maximum(value, 0), np.maximum(-value, 0)
    offsets = np.einsum("sk,kpc->spc", weights, targets)
    names = list(model.bone_labels)
    nv, nb = verts.shape[1], heads.shape[1]
    hips = [nv + names.index(b) for b in HIP_BONES]
    offsets = offsets - offsets[:, hips].mean(1, keepdims=True)
    flat = offsets.reshape(samples, -1)
    gram = flat @ flat.T
    eigval, eigvec = np.linalg.eigh(gram)
    order = np.argsort(eigval)[::-1][:rank]
    # Right singular vectors times their standard deviation: X^T v_k / sqrt(samples).
    basis = (eigvec[:, order].T @ flat) / np.sqrt(samples)
    basis = basis.reshape(rank, nv + 2 * nb, 3)
    explained = eigval[order] / eigval.sum()
    out = Path(path) if path is not None else default_basis_path(topology)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        out,
        format=np.array(BASIS_FORMAT),
        version=np.array(BASIS_VERSION),
        topology=np.array(topology),
        vertices=basis[:, :nv].astype(np.float32),  # anny frame, hip-centred offsets
        heads=basis[:, nv : nv + nb].astype(np.float32),
        tails=basis[:, nv + nb :].astype(np.float32),
        explained_variance=explained.astype(np.float32),
        labels=np.array([lb for lb, b in zip(labels, body) if b]),
        samples=np.array(samples),
        slider_range=np.array(slider_range),
        seed=np.array(seed),
    )
    return out


def _load_basis(path: Path, num_vertices: int) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as data:
            basis = {k: data[k] for k in data.files}
    except (OSError, ValueError) as err:
        raise AnnyUnavailableError(f"{path}: unreadable local-change basis ({err})") from None
    if str(basis.get("format")) != BASIS_FORMAT or int(basis.get("version", 0)) != BASIS_VERSION:
        raise AnnyUnavailableError(f"{path}: not a local-change basis (version {BASIS_VERSION})")
    if basis["vertices"].shape[1] != num_vertices:
        raise AnnyUnavailableError(f"{path}: basis is for another mesh topology")
    return basis


def vertex_normals(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Area-weighted unit vertex normals of (B, V, 3) vertices, (F, 3) CCW faces: (B, V, 3)."""
    a, b, c = (vertices[:, faces[:, i]] for i in range(3))
    face_n = torch.linalg.cross(b - a, c - a, dim=-1)  # (B, F, 3), length = 2 area
    normals = torch.zeros_like(vertices)
    for i in range(3):
        normals.index_add_(1, faces[:, i], face_n)
    return normals / normals.norm(dim=-1, keepdim=True).clamp_min(1e-12)


class ShapeModel:
    """anny phenotype + local PCA basis -> rest mesh; 34-DoF skeleton pose -> posed mesh.

    All arrays are float64 torch tensors on the CPU in the body frame's axes. Build with
    :func:`load_shape_model`.
    """

    def __init__(self, anny_model: Any, basis: dict[str, np.ndarray]) -> None:
        m = anny_model
        to_body = torch.as_tensor(ANNY_TO_BODY, dtype=torch.float64)

        def rot(x: Any) -> torch.Tensor:
            return torch.as_tensor(np.asarray(x), dtype=torch.float64) @ to_body.T

        self._anny = m
        self.bone_names: tuple[str, ...] = tuple(m.bone_labels)
        nb = len(self.bone_names)
        self.bone_parents = torch.as_tensor(np.array(m.bone_parents), dtype=torch.long)
        self.template = rot(m.template_vertices.detach())  # (V, 3)
        self.template_heads = rot(m.template_bone_heads.detach())  # (nb, 3)
        self.template_tails = rot(m.template_bone_tails.detach())
        self.blendshapes = rot(m.blendshapes.detach())  # (C, V, 3)
        self.heads_blendshapes = rot(m.bone_heads_blendshapes.detach())  # (C, nb, 3)
        self.tails_blendshapes = rot(m.bone_tails_blendshapes.detach())
        self.local_vertices = rot(basis["vertices"])  # (K, V, 3)
        self.local_heads = rot(basis["heads"])
        self.local_tails = rot(basis["tails"])
        faces = m.faces if m.faces.shape[1] == 3 else m.get_triangular_faces()
        self.faces = torch.as_tensor(np.asarray(faces), dtype=torch.long)
        self.skin_bones = m.vertex_bone_indices.detach().long()  # (V, k)
        w = m.vertex_bone_weights.detach().double()
        self.skin_weights = w / w.sum(1, keepdim=True)  # (V, k)
        self.dense_weights = torch.zeros(len(w), nb, dtype=torch.float64).scatter_add_(
            1, self.skin_bones, self.skin_weights
        )  # (V, nb)
        self._hips = tuple(self.bone_names.index(b) for b in HIP_BONES)
        seg_of_bone = {b: s for s, bones in SEGMENT_BONES.items() for b in bones}
        self.bone_segment = torch.tensor(
            [sk.SEGMENT_NAMES.index(seg_of_bone[n]) for n in self.bone_names], dtype=torch.long
        )
        dominant = self.skin_bones.gather(1, self.skin_weights.argmax(1, keepdim=True))[:, 0]
        self.vertex_segment = self.bone_segment[dominant]  # (V,)
        # Closed-form chain: lever bone of each bone's head offset and root-to-bone paths.
        parents = self.bone_parents.tolist()
        self._lever = torch.tensor([0] + parents[1:], dtype=torch.long)
        path = torch.zeros(nb, nb, dtype=torch.float64)
        for b in range(nb):
            a = b
            while a >= 0:
                path[b, a] = 1.0
                a = parents[a]
        self._path = path
        self.explained_variance = basis.get("explained_variance")

    @property
    def num_vertices(self) -> int:
        return int(self.template.shape[0])

    @property
    def num_local(self) -> int:
        return int(self.local_vertices.shape[0])

    def phenotype_coefficients(self, phenotype: torch.Tensor) -> torch.Tensor:
        """anny's blendshape coefficients (B, C) of phenotypes (B, 6) (differentiable)."""
        empty = phenotype.new_zeros(phenotype.shape[0], 0)
        return self._anny._get_phenotype_blendshape_coefficients(phenotype, empty, empty)

    def rest_from_coefficients(self, coeffs: torch.Tensor, local: torch.Tensor) -> RestShape:
        """Rest body of blendshape coefficients (B, C) and local coefficients (B, K)."""

        def blend(template, phen_bs, local_bs):
            return (
                template
                + torch.einsum("bc,cpi->bpi", coeffs, phen_bs)
                + torch.einsum("bk,kpi->bpi", local, local_bs)
            )

        verts = blend(self.template, self.blendshapes, self.local_vertices)
        heads = blend(self.template_heads, self.heads_blendshapes, self.local_heads)
        tails = blend(self.template_tails, self.tails_blendshapes, self.local_tails)
        hip = heads[:, self._hips, :].mean(1, keepdim=True)
        return RestShape(verts - hip, heads - hip, tails - hip)

    def rest(self, phenotype: torch.Tensor, local: torch.Tensor | None = None) -> RestShape:
        """Rest body of phenotypes (B, 6) in [0, 1] and local coefficients (B, K) (0: none)."""
        phenotype = torch.as_tensor(phenotype, dtype=torch.float64).reshape(-1, 6)
        if local is None:
            local = phenotype.new_zeros(phenotype.shape[0], self.num_local)
        return self.rest_from_coefficients(self.phenotype_coefficients(phenotype), local)

    def rest_corrections(self, heads: torch.Tensor, tails: torch.Tensor) -> torch.Tensor:
        """Per-bone rotations (B, nb, 3, 3) turning each arm segment's A-pose rest direction
        (its first bone, head to tail) onto the segment axis; identity elsewhere."""
        B, nb = heads.shape[:2]
        out = torch.eye(3, dtype=heads.dtype).expand(B, nb, 3, 3).clone()
        for seg in _ARM_SEGMENTS:
            k = sk.SEGMENT_NAMES.index(seg)
            bones = [self.bone_names.index(n) for n in SEGMENT_BONES[seg]]
            d = tails[:, bones[0]] - heads[:, bones[0]]
            d = d / d.norm(dim=-1, keepdim=True)
            axis = torch.as_tensor(sk.SEGMENT_AXIS[k], dtype=heads.dtype).expand_as(d)
            v = torch.linalg.cross(d, axis, dim=-1)
            c = (d * axis).sum(-1)
            z = torch.zeros_like(c)
            kx = torch.stack(
                [z, -v[:, 2], v[:, 1], v[:, 2], z, -v[:, 0], -v[:, 1], v[:, 0], z], -1
            ).reshape(B, 3, 3)
            corr = torch.eye(3, dtype=heads.dtype) + kx + kx @ kx / (1.0 + c)[:, None, None]
            out[:, bones] = corr[:, None]
        return out

    def bone_rotations(self, q: torch.Tensor, corrections: torch.Tensor) -> torch.Tensor:
        """Global bone rotations (B, nb, 3, 3) for poses q (B, 34) (camera frame when q is)."""
        seg_rot = forward_kinematics(q, BodyShape.default(q.dtype)).rotations  # (B, 15, 3, 3)
        return seg_rot[:, self.bone_segment] @ corrections

    def pose(
        self,
        rest: RestShape,
        rotations: torch.Tensor,
        root: torch.Tensor,
        vertex_index: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Linear blend skinning: the hip centre goes to ``root``.

        Args:
            rest: rest body with batch B (or 1).
            rotations: (B, nb, 3, 3) global bone rotations; root: (B, 3).
            vertex_index: (N,) vertices to pose (all when None); ``rest.vertices`` holds either
                all V vertices or just these N.
        Returns:
            posed vertices (B, N, 3) and bone heads (B, nb, 3).
        """
        offsets = rest.heads - torch.cat(
            [torch.zeros_like(rest.heads[:, :1]), rest.heads[:, self.bone_parents[1:]]], 1
        )
        levers = (rotations[:, self._lever] @ offsets[..., None])[..., 0]
        heads = root[:, None] + self._path.to(levers) @ levers
        shift = heads - (rotations @ rest.heads[..., None])[..., 0]  # (B, nb, 3)
        idx = slice(None) if vertex_index is None else vertex_index
        selected = vertex_index is not None and rest.vertices.shape[1] != self.num_vertices
        x = rest.vertices if selected else rest.vertices[:, idx]  # (B, N, 3)
        # Blend the per-bone affine maps [G_b | shift_b] with one matrix product.
        B, nb = rotations.shape[:2]
        affine = torch.cat([rotations.reshape(B, nb, 9), shift], -1)  # (B, nb, 12)
        blended = self.dense_weights[idx].to(affine) @ affine  # (B, N, 12)
        verts = (blended[..., :9].reshape(*blended.shape[:2], 3, 3) @ x[..., None])[..., 0]
        return verts + blended[..., 9:], heads


_MODELS: dict[tuple[str, str], ShapeModel] = {}


def load_shape_model(
    topology: str = "anny", basis_path: str | Path | None = None, cache_dir: Path | None = None
) -> ShapeModel:
    """The shape model, built once per process (about 2-3 s from the anny cache).

    The local basis is built on first use when ``basis_path`` (default
    :func:`default_basis_path`) does not exist. Raises :class:`AnnyUnavailableError` when
    anny is missing.
    """
    path = Path(basis_path) if basis_path is not None else default_basis_path(topology)
    key = (topology, str(path))
    if key in _MODELS:
        return _MODELS[key]
    if not path.is_file():
        build_local_basis(path, topology=topology, cache_dir=cache_dir)
    model = _anny_model(topology, "none", cache_dir)
    shape_model = ShapeModel(model, _load_basis(path, int(model.template_vertices.shape[0])))
    _MODELS[key] = shape_model
    return shape_model
