"""The randomized-forest artifact ``forest.npz`` of DESIGN.md: what ``train-forest`` writes and
the runtime's per-pixel classifier reads.

A forest of T binary trees over depth-difference features (Wei 2012 section 4.1, Shotton 2011)::

    f(x) = D(x + u / D(x)) - D(x + v / D(x))      (metres)
    child = right if f > threshold else left

``D`` is the depth in metres with every pixel outside the person mask, without a reading
(0), or outside the image replaced by the constant ``background_m`` (10 m by default). Offsets
``u``, ``v`` are in pixel*metres for the camera the forest was trained for (``camera``): a probe
``u / D(x)`` pixels away is ``u / fx`` metres away in the scene at any depth. A runtime camera
with other focal lengths scales the offsets by ``(fx' / fx, fy' / fy)`` (see
:meth:`Forest.offset_scale`); that keeps the probe's metric displacement, so one forest serves any
resolution of the same kind of sensor (accuracy is best near the trained resolution).

All trees live in flat node arrays (N nodes in total; tree t starts at ``roots[t]``):

    u, v         (N, 2) float32  offsets (x = column, y = row), pixel*metres; 0 at leaves
    threshold    (N,)   float32  split threshold, metres; 0 at leaves
    left, right  (N,)   int32    child node indices, -1 at leaves
    leaf         (N,)   int32    row of ``leaf_dist`` for leaves, -1 for split nodes
    leaf_dist    (L, C) float16  class distribution at each leaf (rows sum to 1)
    roots        (T,)   int32    root node of each tree

Inside the npz, ``meta`` is a JSON string (format, version, class names, camera, background
constant, max depth, training config and statistics) and ``checksum`` the sha256 over every
other array (name, dtype, shape, bytes) and ``meta``. An optional ``onnx_graph`` (uint8) holds
the serialized ONNX traversal graph whose node and leaf tables are inputs (see
``train/forest/onnx_export.py``): the runtime runs it with onnxruntime without needing the
``onnx`` package. :func:`load_forest` rejects with :class:`ForestFormatError` (one clear line)
a missing file, a file that is not an npz or not a forest, a truncated or corrupt file, a
checksum mismatch, a version newer than this code reads, and a class set other than expected.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "FOREST_FORMAT",
    "FOREST_VERSION",
    "DEFAULT_BACKGROUND_M",
    "ForestFormatError",
    "Forest",
    "forest_checksum",
    "TABLE_COLUMNS",
    "traversal_table",
    "save_forest",
    "load_forest",
    "load_forest_shared",
]

FOREST_FORMAT = "depthmocap-forest"
FOREST_VERSION = 1
DEFAULT_BACKGROUND_M = 10.0
_CAMERA_KEYS = ("width", "height", "fx", "fy", "cx", "cy")
_ARRAYS = ("u", "v", "threshold", "left", "right", "leaf", "leaf_dist", "roots")


class ForestFormatError(ValueError):
    """A forest artifact that cannot be used: says which file and what is wrong."""


@dataclass
class Forest:
    """A trained randomized decision forest (flat node arrays for all trees; see module doc)."""

    u: np.ndarray
    v: np.ndarray
    threshold: np.ndarray
    left: np.ndarray
    right: np.ndarray
    leaf: np.ndarray
    leaf_dist: np.ndarray
    roots: np.ndarray
    class_names: tuple[str, ...]
    camera: dict
    background_m: float = DEFAULT_BACKGROUND_M
    config: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    onnx_graph: bytes | None = None

    def __post_init__(self) -> None:
        self.u = np.ascontiguousarray(self.u, dtype=np.float32)
        self.v = np.ascontiguousarray(self.v, dtype=np.float32)
        self.threshold = np.ascontiguousarray(self.threshold, dtype=np.float32)
        self.left = np.ascontiguousarray(self.left, dtype=np.int32)
        self.right = np.ascontiguousarray(self.right, dtype=np.int32)
        self.leaf = np.ascontiguousarray(self.leaf, dtype=np.int32)
        self.leaf_dist = np.ascontiguousarray(self.leaf_dist, dtype=np.float16)
        self.roots = np.ascontiguousarray(self.roots, dtype=np.int32)
        self.class_names = tuple(self.class_names)
        self.background_m = float(self.background_m)

    @property
    def num_trees(self) -> int:
        return int(self.roots.shape[0])

    @property
    def num_nodes(self) -> int:
        return int(self.left.shape[0])

    @property
    def num_leaves(self) -> int:
        return int(self.leaf_dist.shape[0])

    @property
    def num_classes(self) -> int:
        return len(self.class_names)

    def node_depths(self) -> np.ndarray:
        """(N,) int32 depth of every node (roots 0), level by level over all trees."""
        depth = np.full(self.num_nodes, -1, dtype=np.int32)
        frontier = self.roots.astype(np.int64)
        d = 0
        while frontier.size:
            depth[frontier] = d
            inner = frontier[self.left[frontier] >= 0]
            frontier = np.concatenate([self.left[inner], self.right[inner]]).astype(np.int64)
            d += 1
        return depth

    @property
    def max_depth(self) -> int:
        """Number of split levels on the longest root-to-leaf path (0 for single-leaf trees)."""
        return int(self.node_depths().max()) if self.num_nodes else 0

    def offset_scale(self, fx: float, fy: float) -> tuple[float, float]:
        """Factors on (x, y) offsets for a runtime camera with focal lengths ``fx``, ``fy``."""
        return float(fx) / float(self.camera["fx"]), float(fy) / float(self.camera["fy"])

    def validate(self, where: str = "forest") -> None:
        """Raise :class:`ForestFormatError` unless the arrays form valid trees."""
        n, c = self.num_nodes, self.num_classes
        shapes = {
            "u": (n, 2),
            "v": (n, 2),
            "threshold": (n,),
            "right": (n,),
            "leaf": (n,),
        }
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ForestFormatError(
                    f"{where}: {name} has shape {getattr(self, name).shape}, expected {shape}"
                )
        if self.left.ndim != 1 or self.roots.ndim != 1 or self.num_trees == 0:
            raise ForestFormatError(f"{where}: needs 1-D node arrays and at least one tree")
        if self.leaf_dist.ndim != 2 or self.leaf_dist.shape[1] != c:
            raise ForestFormatError(
                f"{where}: leaf_dist has shape {self.leaf_dist.shape}, expected (L, {c})"
            )
        is_leaf = self.left < 0
        if np.any(is_leaf != (self.right < 0)) or np.any(is_leaf != (self.leaf >= 0)):
            raise ForestFormatError(f"{where}: leaves must have left = right = -1 and a leaf row")
        for name in ("left", "right", "roots"):
            a = getattr(self, name)
            if a.size and (a.max() >= n or (name == "roots" and a.min() < 0)):
                raise ForestFormatError(f"{where}: {name} points outside the {n} nodes")
        if self.leaf.size and self.leaf.max() >= self.num_leaves:
            raise ForestFormatError(f"{where}: leaf rows point outside leaf_dist")
        missing = set(_CAMERA_KEYS) - set(self.camera)
        if missing:
            raise ForestFormatError(f"{where}: camera lacks {sorted(missing)}")
        if not (np.isfinite(self.u).all() and np.isfinite(self.v).all()):
            raise ForestFormatError(f"{where}: non-finite offsets")


TABLE_COLUMNS = ("ux", "uy", "vx", "vy", "threshold", "left", "right", "leaf")


def traversal_table(forest: Forest) -> np.ndarray:
    """(N, 8) float32 node table for level-synchronous traversal (torch and ONNX backends).

    Columns :data:`TABLE_COLUMNS`. A leaf points to itself on both sides with zero offsets
    (its feature is D(x) - D(x) = 0) and threshold +inf, so extra traversal steps keep a pixel
    on its leaf and every pixel can take ``max_depth`` steps without a test. Indices are stored
    as floats (exact below 2**24 nodes) so that one gather fetches a whole row.
    """
    n = forest.num_nodes
    if n >= 1 << 24:
        raise ForestFormatError(f"forest has {n} nodes; the traversal table holds < 2**24")
    is_leaf = forest.left < 0
    self_index = np.arange(n, dtype=np.float32)
    table = np.empty((n, 8), dtype=np.float32)
    table[:, 0:2] = np.where(is_leaf[:, None], 0.0, forest.u)
    table[:, 2:4] = np.where(is_leaf[:, None], 0.0, forest.v)
    table[:, 4] = np.where(is_leaf, np.inf, forest.threshold)
    table[:, 5] = np.where(is_leaf, self_index, forest.left)
    table[:, 6] = np.where(is_leaf, self_index, forest.right)
    table[:, 7] = np.where(is_leaf, forest.leaf, 0)
    return table


def _arrays(forest: Forest) -> dict[str, np.ndarray]:
    out = {name: getattr(forest, name) for name in _ARRAYS}
    if forest.onnx_graph is not None:
        out["onnx_graph"] = np.frombuffer(forest.onnx_graph, dtype=np.uint8)
    return out


def _meta(forest: Forest) -> dict:
    return {
        "format": FOREST_FORMAT,
        "version": FOREST_VERSION,
        "class_names": list(forest.class_names),
        "camera": {k: forest.camera[k] for k in _CAMERA_KEYS},
        "background_m": forest.background_m,
        "num_trees": forest.num_trees,
        "num_nodes": forest.num_nodes,
        "num_leaves": forest.num_leaves,
        "max_depth": forest.max_depth,
        "config": forest.config,
        "stats": forest.stats,
    }


def forest_checksum(arrays: dict[str, np.ndarray], meta_json: str) -> str:
    """sha256 over every array (sorted by name: name, dtype, shape, bytes) and the meta JSON."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    h.update(meta_json.encode())
    return h.hexdigest()


def save_forest(path: str | Path, forest: Forest) -> None:
    """Write ``forest`` to ``path`` (compressed npz, atomically via a temporary file)."""
    forest.validate()
    path = Path(path)
    arrays = _arrays(forest)
    meta_json = json.dumps(_meta(forest), sort_keys=True)
    checksum = forest_checksum(arrays, meta_json)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, meta=np.array(meta_json), checksum=np.array(checksum), **arrays)
    os.replace(tmp, path)


def load_forest(path: str | Path, expected_classes: list[str] | tuple[str, ...] | None = None):
    """Read and validate a forest artifact.

    Args:
        path: the ``forest.npz`` file.
        expected_classes: class names the caller needs, in order (e.g.
            ``shared.labels.PART_NAMES``); ``None`` accepts any.
    Returns:
        the :class:`Forest`.
    Raises:
        ForestFormatError: missing file, not an npz or not a forest, truncated or corrupt file,
            checksum mismatch, version newer than :data:`FOREST_VERSION`, class set mismatch.
    """
    path = Path(path)
    if not path.is_file():
        raise ForestFormatError(f"{path}: forest file not found")
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic != b"PK\x03\x04":
        raise ForestFormatError(f"{path}: not a forest artifact (not an .npz file)")
    try:
        with np.load(path, allow_pickle=False) as data:
            files = set(data.files)
            if "meta" not in files or "checksum" not in files:
                raise ForestFormatError(f"{path}: not a forest artifact (no forest metadata)")
            meta_json = str(data["meta"])
            checksum = str(data["checksum"])
            arrays = {k: data[k] for k in files - {"meta", "checksum"}}
    except ForestFormatError:
        raise
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as exc:
        raise ForestFormatError(f"{path}: truncated or corrupt forest file ({exc})") from exc
    except Exception as exc:  # zlib and zipfile raise assorted types on damaged members
        raise ForestFormatError(f"{path}: truncated or corrupt forest file ({exc})") from exc
    try:
        meta = json.loads(meta_json)
    except json.JSONDecodeError as exc:
        raise ForestFormatError(f"{path}: corrupt forest metadata ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FOREST_FORMAT:
        raise ForestFormatError(f"{path}: not a forest artifact (format is not {FOREST_FORMAT})")
    version = meta.get("version")
    if not isinstance(version, int):
        raise ForestFormatError(f"{path}: forest metadata has no integer version")
    if version > FOREST_VERSION:
        raise ForestFormatError(
            f"{path}: forest format version {version} is newer than this code reads "
            f"({FOREST_VERSION}); update depthmocap"
        )
    if forest_checksum(arrays, meta_json) != checksum:
        raise ForestFormatError(f"{path}: checksum mismatch (file corrupt or edited)")
    missing = [k for k in _ARRAYS if k not in arrays]
    if missing:
        raise ForestFormatError(f"{path}: forest lacks arrays {missing}")
    try:
        names = tuple(meta.get("class_names", ()))
        if expected_classes is not None and tuple(expected_classes) != names:
            want, have = list(expected_classes), list(names)
            extra = sorted(set(have) - set(want))
            lacking = sorted(set(want) - set(have))
            detail = (
                f"extra {extra}, missing {lacking}"
                if extra or lacking
                else "same names in another order"
            )
            raise ForestFormatError(
                f"{path}: forest classes differ from the expected {len(want)} classes ({detail})"
            )
        onnx = arrays.get("onnx_graph")
        forest = Forest(
            **{k: arrays[k] for k in _ARRAYS},
            class_names=names,
            camera=dict(meta.get("camera", {})),
            background_m=float(meta.get("background_m", DEFAULT_BACKGROUND_M)),
            config=dict(meta.get("config", {})),
            stats=dict(meta.get("stats", {})),
            onnx_graph=None if onnx is None else onnx.tobytes(),
        )
        forest.validate(str(path))
        return forest
    except ForestFormatError:
        raise
    except (TypeError, ValueError, AttributeError) as exc:  # fields of the wrong kind
        raise ForestFormatError(f"{path}: malformed forest metadata ({exc})") from None


# Forests read by load_forest_shared: (resolved path, size, mtime_ns, classes) -> Forest.
_SHARED: dict[tuple, Forest] = {}
_SHARED_MAX = 4


def load_forest_shared(
    path: str | Path, expected_classes: list[str] | tuple[str, ...] | None = None
) -> Forest:
    """:func:`load_forest`, read once per file version and shared: the runtime checks the model
    before it opens a camera and then builds its classifier from it, and every
    ``depthmocap.Tracker`` does both, so each read (decompressing and hashing ~20 MB, 0.5-0.8 s
    on a 2-core CPU) would otherwise happen twice per tracker. A file replaced or edited since
    (another size or modification time) is read and validated again. The shared forest's
    arrays are read-only; callers that change a forest load their own with :func:`load_forest`.
    """
    path = Path(path)
    try:
        st = path.stat()
    except OSError:
        return load_forest(path, expected_classes)  # its clear error for a missing file
    key = (
        str(path.resolve()), st.st_size, st.st_mtime_ns,
        None if expected_classes is None else tuple(expected_classes),
    )  # fmt: skip
    forest = _SHARED.get(key)
    if forest is None:
        forest = load_forest(path, expected_classes)
        for name in _ARRAYS:
            getattr(forest, name).setflags(write=False)
        if len(_SHARED) >= _SHARED_MAX:
            _SHARED.pop(next(iter(_SHARED)))
        _SHARED[key] = forest
    return forest
