"""Meshes whose labels render exactly: one label per face, no vertex shared across labels.

A face takes the majority label of its three vertices (the first vertex's label when all three
differ; :func:`face_labels_from_vertices`). Vertices shared by faces of different labels are
duplicated (:func:`split_by_label`), so every vertex of a face carries the face's label and a
colour interpolated over the face is constant: the renderer (:mod:`train.synth.render`) can
write labels as flat colours and read them back bit-exact.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["SplitMesh", "as_uint8_labels", "check_faces", "face_labels_from_vertices",
           "split_by_label"]  # fmt: skip


class SplitMesh(NamedTuple):
    """A mesh re-indexed so that no vertex is shared by faces of different labels.

    Attributes:
        source: (N,) int64 index into the original vertices of each new vertex.
        faces: (F, 3) uint32 faces over the new vertices (same order as the input faces).
        labels: (N,) uint8 label of each new vertex (= the label of every face using it).
    """

    source: np.ndarray
    faces: np.ndarray
    labels: np.ndarray


def face_labels_from_vertices(faces: np.ndarray, vertex_labels: np.ndarray) -> np.ndarray:
    """Majority label of each face's three vertices; the first vertex's when all differ.

    Args:
        faces: (F, 3) vertex indices.
        vertex_labels: (V,) labels.
    Returns:
        (F,) uint8.
    """
    l0, l1, l2 = (np.asarray(vertex_labels)[np.asarray(faces)[:, k]] for k in range(3))
    # l1 == l2 is a majority (or unanimity) without l0; otherwise l0 is the majority or, with
    # three different labels, the tie-break.
    return np.where(l1 == l2, l1, l0).astype(np.uint8)


def split_by_label(faces: np.ndarray, face_labels: np.ndarray) -> SplitMesh:
    """Duplicate vertices shared by faces of different labels (only those).

    With every vertex of a face carrying the face's label, per-vertex colours interpolate to a
    constant over each face, so a flat colour render reproduces face labels exactly.

    Args:
        faces: (F, 3) vertex indices.
        face_labels: (F,) labels in [0, 255].
    Returns:
        :class:`SplitMesh`; ``vertices[source]`` gives the new vertex positions.
    """
    faces = np.asarray(faces, dtype=np.int64)
    corner_label = np.repeat(np.asarray(face_labels, dtype=np.int64), 3)
    # One new vertex per distinct (vertex, label) pair among the face corners.
    key = faces.reshape(-1) * 256 + corner_label
    unique_key, inverse = np.unique(key, return_inverse=True)
    return SplitMesh(
        source=unique_key // 256,
        faces=inverse.reshape(-1, 3).astype(np.uint32),
        labels=(unique_key % 256).astype(np.uint8),
    )


def as_uint8_labels(labels: np.ndarray, n: int, what: str) -> np.ndarray:
    labels = np.asarray(labels)
    if labels.shape != (n,):
        raise ValueError(f"{what} must have shape ({n},), got {labels.shape}")
    if labels.dtype != np.uint8:
        if labels.size and (labels.min() < 0 or labels.max() > 255):
            raise ValueError(f"{what} must lie in [0, 255]")
        labels = labels.astype(np.uint8)
    return labels


def check_faces(faces: np.ndarray) -> np.ndarray:
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be an (F, 3) integer array, got {faces.shape} {faces.dtype}")
    if faces.size and faces.min() < 0:
        raise ValueError("faces contain negative vertex indices")
    return faces
