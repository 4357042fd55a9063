"""Depth recordings on disk (DESIGN.md): what a camera or the synthesizer writes, what the
runtime reads.

Layout of a recording directory::

    meta.json            format, version, width, height, fx, fy, cx, cy, fps, depth_unit,
                         frame_count, source
    depth/000000.png     16-bit PNG, millimetres, 0 = no reading
    labels/000000.png    optional uint8 part labels (shared.labels)
    groundtruth.npz      optional: joints (F, J, 3) camera metres, joint_names (J,),
                         q (F, 34), body parameters, anything else per frame
    reference.npz        optional: another tracker's skeleton, kept apart from ground truth
                         because it is not one: joints (F, K, 3) camera metres (the same
                         frame as the depth: x right, y down, z forward), joint_names (K,),
                         source (text naming the tracker), joint_map (M, 2) pairs
                         (our joint name, its joint name) for the joints that correspond

The writer keeps ``meta.json`` current after every frame (atomic replace), so a recording
cut off by Ctrl-C or a dropped camera is complete and readable up to its last frame.
"""

from __future__ import annotations

import json
import os
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .camera import Intrinsics

__all__ = [
    "RecordingError",
    "RecordingWriter",
    "Recording",
    "RECORDING_FORMAT",
    "RECORDING_VERSION",
    "write_png16",
    "read_png",
    "png_problem",
    "mapped_reference",
]

RECORDING_FORMAT = "depthmocap-recording"
RECORDING_VERSION = 1
_REQUIRED = {
    "format": str,
    "version": int,
    "width": int,
    "height": int,
    "fx": (int, float),
    "fy": (int, float),
    "cx": (int, float),
    "cy": (int, float),
    "fps": (int, float),
    "depth_unit": (int, float),
    "frame_count": int,
    "source": str,
}


class RecordingError(ValueError):
    """A recording that cannot be read: says which file and what is wrong."""


def _cv2():
    import cv2  # lazy: only recordings need image codecs

    return cv2


def write_png16(path: Path, image: np.ndarray) -> None:
    """Write a uint16 or uint8 single-channel PNG."""
    if image.ndim != 2 or image.dtype not in (np.uint16, np.uint8):
        raise ValueError(f"expected a 2-D uint16/uint8 image, got {image.dtype} {image.shape}")
    if not _cv2().imwrite(str(path), image):
        raise OSError(f"could not write {path}")


def read_png(path: Path, dtype: np.dtype) -> np.ndarray:
    """Read a single-channel PNG of exactly ``dtype``; ``RecordingError`` otherwise."""
    cv2 = _cv2()
    if not path.is_file():
        raise RecordingError(f"{path}: missing frame file")
    try:
        data = path.read_bytes()
    except OSError as err:
        raise RecordingError(f"{path}: cannot be read ({err.strerror or err})") from None
    problem = png_problem(data)
    if problem is not None:  # say so ourselves: libpng would print its own line on stderr
        raise RecordingError(f"{path}: not a readable PNG image ({problem})")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise RecordingError(f"{path}: not a readable PNG image")
    if image.ndim != 2 or image.dtype != dtype:
        raise RecordingError(
            f"{path}: expected a single-channel {np.dtype(dtype).name} image, "
            f"got {image.dtype.name} with shape {image.shape}"
        )
    return image


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_problem(data: bytes) -> str | None:
    """What is wrong with the PNG file ``data`` at the chunk level (signature, truncation, a
    chunk whose CRC does not match, no IHDR / IDAT / IEND), or None: the checks a decoder
    would fail on, made before decoding so that corrupt frames give one clean error."""
    if not data.startswith(_PNG_SIGNATURE):
        return "no PNG signature"
    pos, seen = len(_PNG_SIGNATURE), []
    while pos + 12 <= len(data):
        length = int.from_bytes(data[pos : pos + 4], "big")
        kind = data[pos + 4 : pos + 8]
        end = pos + 12 + length
        if end > len(data):
            return f"chunk {kind!r} is cut off"
        crc = int.from_bytes(data[end - 4 : end], "big")
        if zlib.crc32(data[pos + 4 : end - 4]) != crc:
            return f"chunk {kind!r} is corrupt (CRC mismatch)"
        seen.append(kind)
        pos = end
        if kind == b"IEND":
            break
    missing = [k.decode() for k in (b"IHDR", b"IDAT", b"IEND") if k not in seen]
    if missing:
        return f"no {', '.join(missing)} chunk (the file is cut off)"
    if seen[0] != b"IHDR":
        return "IHDR is not the first chunk"
    return None


def _atomic_write_json(path: Path, data: dict) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=2))
    os.replace(tmp, path)


def _joint_map_problem(pairs: np.ndarray, names: np.ndarray) -> str | None:
    """What is wrong with a reference's ``joint_map`` (M, 2) against its K ``names``, or None."""
    if pairs.ndim != 2 or pairs.shape[1] != 2 or len(pairs) == 0:
        return f"joint_map must be a non-empty (M, 2) list of name pairs, got {pairs.shape}"
    ours, theirs = list(pairs[:, 0]), list(pairs[:, 1])
    if len(set(ours)) != len(ours):
        return "joint_map names one of our joints twice"
    unknown = sorted(set(theirs) - set(names.tolist()))
    if unknown:
        return f"joint_map names joints the reference does not have: {', '.join(unknown)}"
    return None


def mapped_reference(reference: dict[str, np.ndarray]) -> tuple[np.ndarray, tuple[str, ...]]:
    """A reference's joints under our names, through its ``joint_map``.

    Args:
        reference: the contents of ``reference.npz`` (:meth:`Recording.reference`).
    Returns:
        (F, M, 3) float64 camera metres and the M names of ours, in ``joint_map`` order.
    """
    names = [str(n) for n in reference["joint_names"]]
    pairs = np.asarray(reference["joint_map"]).reshape(-1, 2)
    index = [names.index(str(theirs)) for theirs in pairs[:, 1]]
    joints = np.asarray(reference["joints"], dtype=np.float64)[:, index]
    return joints, tuple(str(ours) for ours in pairs[:, 0])


class RecordingWriter:
    """Streams frames into a new recording directory.

    Args:
        path: directory to create (must not hold a recording already unless ``overwrite``).
        intrinsics: camera of the depth frames.
        fps: nominal frame rate.
        source: free text (camera serial, ``synthetic:<clip>``...).
        overwrite: replace an existing recording.
    """

    def __init__(
        self,
        path: str | Path,
        intrinsics: Intrinsics,
        fps: float = 30.0,
        source: str = "unknown",
        overwrite: bool = False,
    ) -> None:
        intrinsics.validate()
        self.path = Path(path)
        if (self.path / "meta.json").exists() and not overwrite:
            raise FileExistsError(f"{self.path} already holds a recording")
        (self.path / "depth").mkdir(parents=True, exist_ok=True)
        self.intrinsics = intrinsics
        self.meta = {
            "format": RECORDING_FORMAT,
            "version": RECORDING_VERSION,
            **intrinsics.as_dict(),
            "fps": float(fps),
            "depth_unit": 0.001,
            "frame_count": 0,
            "source": source,
        }
        self._has_labels = False
        _atomic_write_json(self.path / "meta.json", self.meta)

    @property
    def frame_count(self) -> int:
        return self.meta["frame_count"]

    def write_frame(self, depth_mm: np.ndarray, labels: np.ndarray | None = None) -> int:
        """Append one frame; returns its index.

        Args:
            depth_mm: (H, W) uint16 millimetres, 0 = no reading.
            labels: optional (H, W) uint8 part labels; give them for every frame or none.
        """
        h, w = self.intrinsics.height, self.intrinsics.width
        if depth_mm.shape != (h, w) or depth_mm.dtype != np.uint16:
            raise ValueError(
                f"depth frame must be uint16 {(h, w)}, got {depth_mm.dtype} {depth_mm.shape}"
            )
        i = self.frame_count
        if labels is not None:
            if labels.shape != (h, w) or labels.dtype != np.uint8:
                raise ValueError(
                    f"labels must be uint8 {(h, w)}, got {labels.dtype} {labels.shape}"
                )
            if i > 0 and not self._has_labels:
                raise ValueError("labels must be given for every frame or for none")
            (self.path / "labels").mkdir(exist_ok=True)
            write_png16(self.path / "labels" / f"{i:06d}.png", labels)
            self._has_labels = True
        elif self._has_labels:
            raise ValueError("labels must be given for every frame or for none")
        write_png16(self.path / "depth" / f"{i:06d}.png", depth_mm)
        self.meta["frame_count"] = i + 1
        _atomic_write_json(self.path / "meta.json", self.meta)
        return i

    def write_groundtruth(self, joints: np.ndarray, joint_names, **per_frame: np.ndarray) -> None:
        """Write ``groundtruth.npz`` for the frames written so far.

        Args:
            joints: (F, J, 3) named joints in camera metres, F = frames written.
            joint_names: J names.
            per_frame: further arrays (``q`` (F, 34), body parameters, ...).
        """
        joints = np.asarray(joints, dtype=np.float32)
        names = np.asarray(list(joint_names), dtype=str)
        if joints.ndim != 3 or joints.shape[2] != 3 or joints.shape[1] != len(names):
            raise ValueError(f"joints must be (F, {len(names)}, 3), got {joints.shape}")
        if joints.shape[0] != self.frame_count:
            raise ValueError(
                f"ground truth has {joints.shape[0]} frames, recording has {self.frame_count}"
            )
        np.savez_compressed(
            self.path / "groundtruth.npz",
            joints=joints,
            joint_names=names,
            **{k: np.asarray(v) for k, v in per_frame.items()},
        )

    def write_reference(self, joints: np.ndarray, joint_names, source: str, joint_map) -> None:
        """Write ``reference.npz``: another tracker's skeleton for the frames written so far.

        Kept out of ``groundtruth.npz`` on purpose: a reference is only another estimate, so
        evaluations against it measure agreement, not accuracy, and nothing treats it as truth.

        Args:
            joints: (F, K, 3) the tracker's joints in camera metres (our frame: x right, y down,
                z forward), F = frames written.
            joint_names: K names, the tracker's own.
            source: what produced them, e.g. ``"Kinect SDK v1 skeleton (another tracker)"``.
            joint_map: (our joint name, its joint name) pairs of the joints that correspond.
        """
        joints = np.asarray(joints, dtype=np.float32)
        names = np.asarray(list(joint_names), dtype=str)
        pairs = np.asarray([list(p) for p in joint_map], dtype=str).reshape(-1, 2)
        if joints.ndim != 3 or joints.shape[2] != 3 or joints.shape[1] != len(names):
            raise ValueError(f"joints must be (F, {len(names)}, 3), got {joints.shape}")
        if joints.shape[0] != self.frame_count:
            raise ValueError(
                f"reference has {joints.shape[0]} frames, recording has {self.frame_count}"
            )
        problem = _joint_map_problem(pairs, names)
        if problem:
            raise ValueError(problem)
        np.savez_compressed(
            self.path / "reference.npz",
            joints=joints,
            joint_names=names,
            source=np.asarray(source, dtype=str),
            joint_map=pairs,
        )

    def close(self) -> None:
        _atomic_write_json(self.path / "meta.json", self.meta)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Recording:
    """A recording directory opened for reading; validates ``meta.json`` up front.

    Frames are read lazily; each frame is checked against the size in ``meta.json``.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise RecordingError(f"{self.path}: no such recording directory")
        meta_path = self.path / "meta.json"
        if meta_path.is_symlink() and not meta_path.is_file():
            raise RecordingError(f"{meta_path}: a symbolic link that leads to no file (broken, "
                                 "or a loop)")  # fmt: skip
        if not meta_path.is_file():
            raise RecordingError(f"{self.path}: not a recording (no meta.json)")
        try:
            meta = json.loads(meta_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise RecordingError(f"{meta_path}: not valid JSON ({err})") from None
        if not isinstance(meta, dict) or meta.get("format") != RECORDING_FORMAT:
            raise RecordingError(
                f"{meta_path}: not a recording (format is not '{RECORDING_FORMAT}')"
            )
        for key, tp in _REQUIRED.items():
            if key not in meta:
                raise RecordingError(f"{meta_path}: missing key '{key}'")
            if not isinstance(meta[key], tp) or isinstance(meta[key], bool):
                raise RecordingError(
                    f"{meta_path}: '{key}' has the wrong type ({type(meta[key]).__name__})"
                )
        if meta["version"] > RECORDING_VERSION or meta["version"] < 1:
            raise RecordingError(
                f"{meta_path}: recording version {meta['version']} is not "
                f"supported (this build reads up to {RECORDING_VERSION})"
            )
        if meta["frame_count"] < 0 or meta["fps"] <= 0 or meta["depth_unit"] <= 0:
            raise RecordingError(f"{meta_path}: frame_count, fps and depth_unit must be positive")
        self.meta = meta
        try:
            self.intrinsics = Intrinsics(
                meta["width"],
                meta["height"],
                float(meta["fx"]),
                float(meta["fy"]),
                float(meta["cx"]),
                float(meta["cy"]),
            )
            self.intrinsics.validate()
        except ValueError as err:
            raise RecordingError(f"{meta_path}: {err}") from None
        missing = [
            i
            for i in (0, meta["frame_count"] - 1)
            if meta["frame_count"] and not self._depth_path(i).is_file()
        ]
        if missing:
            raise RecordingError(
                f"{self.path}: meta.json lists {meta['frame_count']} frames but "
                f"{self._depth_path(missing[0]).name} is missing"
            )
        self._gt = None
        self._ref = None

    def _depth_path(self, i: int) -> Path:
        return self.path / "depth" / f"{i:06d}.png"

    def __len__(self) -> int:
        return self.meta["frame_count"]

    @property
    def fps(self) -> float:
        return float(self.meta["fps"])

    @property
    def has_labels(self) -> bool:
        return (self.path / "labels").is_dir()

    def _check_index(self, i: int) -> None:
        if not 0 <= i < len(self):
            raise IndexError(f"frame {i} out of range (recording has {len(self)} frames)")

    def _check_size(self, image: np.ndarray, path: Path) -> np.ndarray:
        h, w = self.intrinsics.height, self.intrinsics.width
        if image.shape != (h, w):
            raise RecordingError(
                f"{path}: frame is {image.shape[1]}x{image.shape[0]} but meta.json says {w}x{h}"
            )
        return image

    def read_depth_mm(self, i: int) -> np.ndarray:
        """Frame ``i`` as (H, W) uint16 depth units (millimetres by default)."""
        self._check_index(i)
        path = self._depth_path(i)
        return self._check_size(read_png(path, np.uint16), path)

    def read_depth(self, i: int) -> np.ndarray:
        """Frame ``i`` as (H, W) float32 metres, 0 = no reading."""
        return self.read_depth_mm(i).astype(np.float32) * np.float32(self.meta["depth_unit"])

    def read_labels(self, i: int) -> np.ndarray:
        """Part labels of frame ``i``: (H, W) uint8."""
        self._check_index(i)
        path = self.path / "labels" / f"{i:06d}.png"
        return self._check_size(read_png(path, np.uint8), path)

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self)):
            yield self.read_depth(i)

    def _load_npz(self, path: Path, what: str) -> dict[str, np.ndarray]:
        """Every array of the ``.npz`` at ``path`` (no pickles); a missing or unreadable file
        is a :class:`RecordingError` naming ``what`` it should have held."""
        if not path.is_file():
            raise RecordingError(f"{self.path}: recording has no {what} ({path.name})")
        try:
            with np.load(path, allow_pickle=False) as data:
                return {k: data[k] for k in data.files}
        except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as err:
            raise RecordingError(f"{path}: unreadable ({err})") from None

    @property
    def has_groundtruth(self) -> bool:
        return (self.path / "groundtruth.npz").is_file()

    def groundtruth(self) -> dict[str, np.ndarray]:
        """Contents of ``groundtruth.npz``, validated against the frame count."""
        if self._gt is not None:
            return self._gt
        path = self.path / "groundtruth.npz"
        gt = self._load_npz(path, "ground truth")
        if "joints" not in gt or "joint_names" not in gt:
            raise RecordingError(f"{path}: needs 'joints' and 'joint_names'")
        j = gt["joints"]
        if (
            j.ndim != 3
            or j.shape[0] != len(self)
            or j.shape[2] != 3
            or j.shape[1] != len(gt["joint_names"])
        ):
            raise RecordingError(
                f"{path}: joints have shape {j.shape}, expected "
                f"({len(self)}, {len(gt['joint_names'])}, 3)"
            )
        if "q" in gt and gt["q"].shape != (len(self), 34):
            raise RecordingError(f"{path}: q has shape {gt['q'].shape}, expected ({len(self)}, 34)")
        self._gt = gt
        return gt

    @property
    def has_reference(self) -> bool:
        return (self.path / "reference.npz").is_file()

    def reference(self) -> dict[str, np.ndarray]:
        """Contents of ``reference.npz`` (another tracker's skeleton, not ground truth),
        validated against the frame count: ``joints`` (F, K, 3), ``joint_names`` (K,),
        ``source`` (a 0-d text array), ``joint_map`` (M, 2)."""
        if self._ref is not None:
            return self._ref
        path = self.path / "reference.npz"
        ref = self._load_npz(path, "reference")
        missing = [k for k in ("joints", "joint_names", "source", "joint_map") if k not in ref]
        if missing:
            raise RecordingError(f"{path}: needs {', '.join(repr(k) for k in missing)}")
        j, names = ref["joints"], ref["joint_names"]
        if names.ndim != 1 or names.dtype.kind != "U" or ref["source"].dtype.kind != "U":
            raise RecordingError(f"{path}: joint_names and source must be text")
        if j.ndim != 3 or j.shape != (len(self), len(names), 3) or j.dtype.kind != "f":
            raise RecordingError(
                f"{path}: joints have shape {j.shape}, expected ({len(self)}, {len(names)}, 3)"
            )
        problem = _joint_map_problem(np.asarray(ref["joint_map"]), names)
        if problem or ref["joint_map"].dtype.kind != "U":
            raise RecordingError(f"{path}: {problem or 'joint_map must be text'}")
        self._ref = ref
        return ref
