"""The sharded training set of DESIGN.md: what ``train-synth`` writes and ``train-forest`` reads.

Layout of a training-set directory::

    manifest.json        format, version, width, height, intrinsics, class names, seed, config,
                         shards [{file, frames, sha256}], frames, class_pixel_counts,
                         content_hash (sha256 over the shards' hashes in order)
    shard_00000.npz      depth (N, H, W) uint16 mm, labels (N, H, W) uint8,
                         joints (N, J, 3) float32 camera metres, q (N, 34) float32 camera frame,
                         body (N,) int32 body index, intrinsics (4,) fx fy cx cy

Shards are written atomically (temporary name, then rename) and the manifest lists only
finished shards, so an interrupted run resumes by skipping shards whose file and hash check out.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.labels import CLUTTER_CLASSES, PART_NAMES

__all__ = [
    "TRAINSET_FORMAT",
    "TRAINSET_VERSION",
    "CLASS_SETS",
    "TrainSetError",
    "Shard",
    "write_shard",
    "read_shard",
    "file_sha256",
    "write_manifest",
    "TrainSet",
    "TrainSetUnion",
    "open_trainsets",
]

TRAINSET_FORMAT = "depthmocap-trainset"
TRAINSET_VERSION = 1
# What a set's labels can mean: body parts (the body-part forest) or person/clutter.
CLASS_SETS = (PART_NAMES, CLUTTER_CLASSES)
_SHARD_KEYS = ("depth", "labels", "joints", "q", "body", "intrinsics")


class TrainSetError(ValueError):
    """A training set that cannot be read: says which file and what is wrong."""


@dataclass
class Shard:
    """One shard in memory.

    Attributes:
        depth: (N, H, W) uint16 millimetres, 0 = no reading.
        labels: (N, H, W) uint8 part labels (shared.labels, 0 = background).
        joints: (N, J, 3) float32 named joints in camera metres.
        q: (N, 34) float32 skeleton pose (camera frame) that drove the mesh; the anatomical
            ``joints`` are the ground truth (the skeleton meets them only to a few cm).
        body: (N,) int32 index of the body shape the frame was rendered with.
        intrinsics: (4,) float64 fx, fy, cx, cy.
    """

    depth: np.ndarray
    labels: np.ndarray
    joints: np.ndarray
    q: np.ndarray
    body: np.ndarray
    intrinsics: np.ndarray

    def __len__(self) -> int:
        return int(self.depth.shape[0])


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_shard(path: Path, shard: Shard) -> str:
    """Write a shard atomically; returns its sha256."""
    path = Path(path)
    n = len(shard)
    if shard.labels.shape != shard.depth.shape or shard.q.shape[0] != n:
        raise ValueError("shard arrays disagree in frame count or image size")
    tmp = path.with_name(path.name + ".tmp.npz")
    arrays = {
        "depth": shard.depth.astype(np.uint16),
        "labels": shard.labels.astype(np.uint8),
        "joints": shard.joints.astype(np.float32),
        "q": shard.q.astype(np.float32),
        "body": shard.body.astype(np.int32),
        "intrinsics": np.asarray(shard.intrinsics, np.float64),
    }
    # An .npz that np.load reads, deflated at level 1: 4x faster than savez_compressed's
    # default level for about 10% more bytes (compression was a sixth of the frame time).
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for name, array in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, array, allow_pickle=False)
    os.replace(tmp, path)
    return file_sha256(path)


def read_shard(path: Path) -> Shard:
    """Read one shard, with a clear error for missing, truncated or foreign files."""
    path = Path(path)
    if not path.is_file():
        raise TrainSetError(f"{path}: shard file missing")
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in _SHARD_KEYS if k not in data.files]
            if missing:
                raise TrainSetError(f"{path}: not a training shard (missing {missing})")
            return Shard(**{k: data[k] for k in _SHARD_KEYS})
    except TrainSetError:
        raise
    except Exception as exc:  # zipfile/npz errors have many types
        raise TrainSetError(f"{path}: unreadable shard ({exc})") from exc


def _content_hash(shards: list[dict]) -> str:
    """sha256 over the shards' own hashes, in order: what a forest records it was grown on."""
    return hashlib.sha256("".join(s["sha256"] for s in shards).encode()).hexdigest()


def write_manifest(
    root: Path,
    intr: Intrinsics,
    shards: list[dict],
    class_pixel_counts: np.ndarray,
    seed: int,
    config: dict,
    extra: dict | None = None,
    class_names: tuple[str, ...] = PART_NAMES,
) -> dict:
    """Write ``manifest.json`` atomically for the finished shards (in order); ``class_names``:
    what the labels mean (:data:`CLASS_SETS`)."""
    content = _content_hash(shards)
    manifest = {
        "format": TRAINSET_FORMAT,
        "version": TRAINSET_VERSION,
        "width": intr.width,
        "height": intr.height,
        "intrinsics": {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy},
        "class_names": list(class_names),
        "seed": seed,
        "frames": int(sum(s["frames"] for s in shards)),
        "shards": shards,
        "class_pixel_counts": [int(c) for c in class_pixel_counts],
        "content_hash": content,
        "config": config,
        **(extra or {}),
    }
    tmp = Path(root) / "manifest.json.tmp"
    tmp.write_text(json.dumps(manifest, indent=1))
    os.replace(tmp, Path(root) / "manifest.json")
    return manifest


class TrainSet:
    """Reader of a training-set directory (validates the manifest; shards load lazily)."""

    def __init__(self, root: str | Path, verify: bool = False):
        self.root = Path(root)
        path = self.root / "manifest.json"
        if not path.is_file():
            raise TrainSetError(f"{self.root}: no manifest.json (not a training set?)")
        try:
            m = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise TrainSetError(f"{path}: unreadable manifest ({exc})") from exc
        if not isinstance(m, dict) or m.get("format") != TRAINSET_FORMAT:
            raise TrainSetError(f"{path}: not a {TRAINSET_FORMAT} manifest")
        if not isinstance(m.get("version"), int) or m["version"] > TRAINSET_VERSION:
            raise TrainSetError(
                f"{path}: version {m.get('version')} is newer than supported ({TRAINSET_VERSION})"
            )
        if tuple(m.get("class_names", ())) not in CLASS_SETS:
            raise TrainSetError(
                f"{path}: class names are neither this version's part set nor the "
                "person/clutter classes"
            )
        self.manifest = m
        self.intrinsics = Intrinsics(
            width=int(m["width"]), height=int(m["height"]), **m["intrinsics"]
        )
        if verify:
            for s in m["shards"]:
                if file_sha256(self.root / s["file"]) != s["sha256"]:
                    raise TrainSetError(f"{self.root / s['file']}: checksum mismatch")

    @property
    def frames(self) -> int:
        return int(self.manifest["frames"])

    @property
    def num_shards(self) -> int:
        return len(self.manifest["shards"])

    @property
    def class_names(self) -> list[str]:
        return list(self.manifest["class_names"])

    def shard(self, i: int) -> Shard:
        return read_shard(self.root / self.manifest["shards"][i]["file"])

    def __iter__(self):
        for i in range(self.num_shards):
            yield self.shard(i)

    def load_frames(self, indices: np.ndarray | None = None) -> Shard:
        """Concatenate the given global frame indices (all when None) into one Shard."""
        counts = np.array([s["frames"] for s in self.manifest["shards"]])
        starts = np.concatenate([[0], np.cumsum(counts)])
        idx = np.arange(self.frames) if indices is None else np.sort(np.asarray(indices))
        parts = []
        for i in range(self.num_shards):
            sel = idx[(idx >= starts[i]) & (idx < starts[i + 1])] - starts[i]
            if sel.size:
                s = self.shard(i)
                parts.append(
                    Shard(
                        s.depth[sel],
                        s.labels[sel],
                        s.joints[sel],
                        s.q[sel],
                        s.body[sel],
                        s.intrinsics,
                    )
                )
        if not parts:
            raise TrainSetError(f"{self.root}: no frames selected")
        return Shard(
            depth=np.concatenate([p.depth for p in parts]),
            labels=np.concatenate([p.labels for p in parts]),
            joints=np.concatenate([p.joints for p in parts]),
            q=np.concatenate([p.q for p in parts]),
            body=np.concatenate([p.body for p in parts]),
            intrinsics=parts[0].intrinsics,
        )


class TrainSetUnion(TrainSet):
    """Several training sets read as one, in the order given (``train-forest --data A B``).

    Lets a set rendered with other scene settings (clothed bodies, another seed) be added to
    the main one without re-rendering or copying either. The sets must share the intrinsics
    (image size included) and the part set; the union's content hash covers every shard in
    order, so a forest records exactly what it saw.
    """

    def __init__(self, roots: list[str | Path], verify: bool = False):
        if not roots:
            raise TrainSetError("no training sets given")
        parts = [TrainSet(r, verify=verify) for r in roots]
        first = parts[0]
        for p in parts[1:]:
            if p.intrinsics != first.intrinsics:
                raise TrainSetError(
                    f"{p.root}: intrinsics {p.intrinsics} differ from {first.root}'s "
                    f"{first.intrinsics}"
                )
        # Each shard's file as an absolute path: Path(root) / file then keeps it as it is.
        shards = [
            {**s, "file": str(p.root.resolve() / s["file"])}
            for p in parts
            for s in p.manifest["shards"]
        ]
        counts = [p.manifest.get("class_pixel_counts") for p in parts]
        self.root = Path("/")
        self.intrinsics = first.intrinsics
        self.manifest = {
            **first.manifest,
            "seed": [p.manifest.get("seed") for p in parts],
            "frames": int(sum(p.frames for p in parts)),
            "shards": shards,
            "class_pixel_counts": (
                [int(c) for c in np.sum(np.asarray(counts, np.int64), axis=0)]
                if all(c is not None for c in counts)
                else None
            ),
            "content_hash": _content_hash(shards),
            "config": [p.manifest.get("config") for p in parts],
            "sets": [
                {
                    "root": str(p.root),
                    "frames": p.frames,
                    "content_hash": p.manifest.get("content_hash"),
                }
                for p in parts
            ],
        }


def open_trainsets(roots: list[str | Path], verify: bool = False) -> TrainSet:
    """One training set, or the union of several (one root reads exactly as :class:`TrainSet`)."""
    roots = list(roots)
    return TrainSet(roots[0], verify) if len(roots) == 1 else TrainSetUnion(roots, verify)
