"""UTD-MHAD (Chen, Jafari, Kehtarnavaz, ICIP 2015): Kinect v1 depth sequences with the Kinect
SDK v1's skeletons, converted into the project's recordings.

Input layout: ``DIR/Depth/aA_sS_tT_depth.mat`` (``d_depth``: uint16 (240, 320, T) mm,
background removed, **mirrored** as the SDK delivers it) and
``DIR/Skeleton/aA_sS_tT_skeleton.mat`` (``d_skel``: float (20, 3, T) metres in Kinect skeleton
space: x right in the mirrored image, y up, z away from the camera), MATLAB v5 files.

Geometry. The SDK maps skeleton space to its mirrored depth image with
``u_m = W/2 + f x / z``, ``v = H/2 - f y / z`` (``NuiTransformSkeletonToDepthImage``:
``(LONG)(160 + x * 285.63 / z + 0.5)`` rounds to the nearest pixel, so integers are pixel
centres, the convention of :mod:`shared.camera`). Un-mirroring flips the columns,
``u = (W - 1) - u_m``, so ``u = (W - 1 - W/2) + f (-x) / z``: with the camera-frame
``x_cv = -x`` the principal point becomes ``cx = W/2 - 1 = 159``, not 160 (the flip maps
column 0 to 319, not to 320). Rows are not flipped: ``cy = H/2 = 120`` and ``y_cv = -y`` (OpenCV
y points down). ``z`` stays.

The SDK's skeleton is stored as a *reference* (``reference.npz``), never as ground truth: it is
another tracker's estimate (Helten et al. 2013 measured it at about 96 mm mean error against
Vicon), with its own idea of where joints are (3-12 cm behind the visible surface).

Time. The dataset stores the two streams index by index, but they are not in step: the
skeleton at index ``k`` shows the body as the depth frame at index ``k + 2`` does (the depth
stream runs about 55 ms late). The depth image alone shows it, without any tracker: over all
192 takes of the shared copy, the SDK's joints lie off the person or in the seen-empty space
in front of it (:mod:`train.evaluation.depth_refutation`) 4,280 times when paired index by
index, 1,780 at one frame, 1,367 at two and 3,493 at three (a parabola through these puts the
lag at 1.7 frames; ``python -m depthmocap.train.evaluation.reference_lag`` measures it).
Helten et al. (section IV) calibrate each sequence in time before comparing trackers for the
same reason. :func:`align_streams` pairs them, dropping the first ``lag`` depth frames (no
skeleton of theirs was kept) and the last ``lag`` skeletons (no depth frame).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depthmocap.shared.camera import Intrinsics

__all__ = [
    "KINECT_JOINTS",
    "ACTION_NAMES",
    "JOINT_MAP",
    "FOCAL_PX",
    "FPS",
    "REFERENCE_SOURCE",
    "UtdError",
    "Sequence",
    "find_sequences",
    "read_sequence",
    "utd_intrinsics",
    "unmirror_depth",
    "kinect_to_camera",
    "SKELETON_LAG_FRAMES",
    "align_streams",
    "reference_source",
]

# Skeleton_joint_order.txt of the dataset; "left" is the person's left.
KINECT_JOINTS: tuple[str, ...] = (
    "head", "shoulder_center", "spine", "hip_center",
    "left_shoulder", "left_elbow", "left_wrist", "left_hand",
    "right_shoulder", "right_elbow", "right_wrist", "right_hand",
    "left_hip", "left_knee", "left_ankle", "left_foot",
    "right_hip", "right_knee", "right_ankle", "right_foot",
)  # fmt: skip

# Our joint (shared.skeleton.JOINT_NAMES) -> the SDK joint at the same anatomical place. Every
# one of ours has a counterpart; the SDK's hands and feet have none (our chain ends at the
# wrists and ankles), so they are left out rather than matched to the wrist/ankle, which the
# SDK also gives. Where the two skeletons put "the same" joint at different points, the
# difference is a near-constant offset in the segment's frame, which offset normalization
# (Helten IV-C) removes:
# - shoulder_center is the SDK's point between the shoulders at the base of the neck: our
#   ``neck`` (base of the neck, the lower neck joint).
# - spine is the SDK's point a few cm above hip_center; our ``spine`` is the top of the lumbar
#   spine, higher up the back: the same segment, a fixed offset along it.
# - hip_center is the SDK's root between the hips: our ``pelvis`` (the root, hip centre).
JOINT_MAP: tuple[tuple[str, str], ...] = (
    ("head", "head"),
    ("neck", "shoulder_center"),
    ("spine", "spine"),
    ("pelvis", "hip_center"),
    ("l_shoulder", "left_shoulder"),
    ("r_shoulder", "right_shoulder"),
    ("l_elbow", "left_elbow"),
    ("r_elbow", "right_elbow"),
    ("l_wrist", "left_wrist"),
    ("r_wrist", "right_wrist"),
    ("l_hip", "left_hip"),
    ("r_hip", "right_hip"),
    ("l_knee", "left_knee"),
    ("r_knee", "right_knee"),
    ("l_ankle", "left_ankle"),
    ("r_ankle", "right_ankle"),
)

# The whole-body actions of the shared copy (its README); the dataset has 27 actions.
ACTION_NAMES: dict[int, str] = {
    5: "throw", 7: "basketball shoot", 12: "bowling", 14: "baseball swing",
    17: "tennis serve", 21: "pick up and throw", 22: "jog in place", 23: "walk in place",
    24: "sit to stand", 25: "stand to sit", 26: "lunge", 27: "squat",
}  # fmt: skip

FOCAL_PX = 285.63  # NUI_CAMERA_SKELETON_TO_DEPTH_IMAGE_MULTIPLIER_320x240 of the SDK
FPS = 30.0
REFERENCE_SOURCE = "Kinect SDK v1 skeleton (another tracker)"
# Depth frames by which the dataset's depth stream runs behind its skeleton stream (module
# docstring): measured from the depth alone over all 192 takes, not fitted to any tracker.
SKELETON_LAG_FRAMES = 2
WIDTH, HEIGHT = 320, 240
_NAME = re.compile(r"^a(\d+)_s(\d+)_t(\d+)_depth\.mat$")


class UtdError(ValueError):
    """A UTD-MHAD folder or file that cannot be imported; names the file and the problem."""


@dataclass(frozen=True)
class Sequence:
    """One take: action, subject, trial and its two files."""

    action: int
    subject: int
    trial: int
    depth_file: Path
    skeleton_file: Path

    @property
    def name(self) -> str:
        """Recording name, e.g. ``a05_s1_t1`` (actions padded so that names sort by action)."""
        return f"a{self.action:02d}_s{self.subject}_t{self.trial}"

    @property
    def source(self) -> str:
        """The recording's ``source`` text: the dataset and the take's own name."""
        take = f"a{self.action}_s{self.subject}_t{self.trial}"
        return f"UTD-MHAD {take} (Kinect v1 depth, un-mirrored on import)"


def find_sequences(root: str | Path) -> list[Sequence]:
    """Every take under ``root`` (``Depth/`` and ``Skeleton/``), sorted by action, subject,
    trial. Only the names are looked at here; a depth file without its skeleton file is an
    error.

    Raises:
        UtdError: no ``Depth`` folder, or a skeleton file missing.
    """
    root = Path(root)
    depth_dir, skel_dir = root / "Depth", root / "Skeleton"
    if not depth_dir.is_dir():
        raise UtdError(f"{root}: not a UTD-MHAD folder (no Depth/ subfolder)")
    out = []
    for path in depth_dir.iterdir():
        match = _NAME.match(path.name)
        if not match:
            continue
        a, s, t = (int(g) for g in match.groups())
        skel = skel_dir / f"a{a}_s{s}_t{t}_skeleton.mat"
        if not skel.is_file():
            raise UtdError(f"{skel}: missing (the skeleton of {path.name})")
        out.append(Sequence(a, s, t, path, skel))
    return sorted(out, key=lambda q: (q.action, q.subject, q.trial))


def _load_variable(path: Path, name: str) -> np.ndarray:
    """One variable of a MATLAB v5 file, as an array."""
    import scipy.io  # lazy: only the importer needs scipy

    if not path.is_file():
        raise UtdError(f"{path}: missing")
    try:
        data = scipy.io.loadmat(str(path), variable_names=[name])
    # scipy raises a zoo of types on damaged files (scipy 1.17: MatReadError for an empty
    # file, ValueError for an unknown header, OSError for a truncated one, TypeError for a
    # garbled body, NotImplementedError for v7.3 HDF5): all mean "not a readable v5 file".
    except Exception as err:
        raise UtdError(
            f"{path}: not a readable MATLAB v5 file ({type(err).__name__}: {err})"
        ) from None
    if name not in data:
        raise UtdError(f"{path}: no variable '{name}'")
    return np.asarray(data[name])


def read_sequence(seq: Sequence, max_frames: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Both files of a take, checked, as the SDK stored them (mirrored, skeleton space).

    Args:
        max_frames: keep only the first this many frames (None: all).
    Returns:
        depth (T, 240, 320) uint16 mm, mirrored; skeleton (T, 20, 3) float64 metres.
    Raises:
        UtdError: unreadable file, missing variable, wrong type or shape, frame counts that
            differ, non-finite joints or joints not in front of the camera.
    """
    depth = _load_variable(seq.depth_file, "d_depth")
    skel = _load_variable(seq.skeleton_file, "d_skel")
    if depth.dtype != np.uint16 or depth.ndim != 3 or depth.shape[:2] != (HEIGHT, WIDTH):
        raise UtdError(
            f"{seq.depth_file}: d_depth must be uint16 ({HEIGHT}, {WIDTH}, T), "
            f"got {depth.dtype} {depth.shape}"
        )
    if skel.dtype.kind != "f" or skel.ndim != 3 or skel.shape[:2] != (len(KINECT_JOINTS), 3):
        raise UtdError(
            f"{seq.skeleton_file}: d_skel must be float ({len(KINECT_JOINTS)}, 3, T), "
            f"got {skel.dtype} {skel.shape}"
        )
    if depth.shape[2] != skel.shape[2] or depth.shape[2] == 0:
        raise UtdError(
            f"{seq.name}: {depth.shape[2]} depth frames but {skel.shape[2]} skeleton frames"
        )
    depth = np.moveaxis(depth, 2, 0)[:max_frames]
    skel = np.moveaxis(skel, 2, 0).astype(np.float64)[:max_frames]
    if not np.isfinite(skel).all() or (skel[..., 2] <= 0).any():
        raise UtdError(f"{seq.skeleton_file}: joints must be finite with z > 0")
    return depth, skel


def align_streams(
    depth: np.ndarray, skeleton: np.ndarray, lag: int = SKELETON_LAG_FRAMES
) -> tuple[np.ndarray, np.ndarray]:
    """Pair each skeleton with the depth frame that shows the same moment.

    Args:
        depth: (T, H, W) frames; skeleton: (T, K, 3) joints, index by index as stored.
        lag: depth frames by which the depth stream runs late (0: as stored).
    Returns:
        depth[lag:] and skeleton[:T - lag], (T - lag, ...) each.
    Raises:
        UtdError: a negative lag, or a take no longer than the lag.
    """
    if lag < 0:
        raise UtdError(f"the skeleton lag must be 0 or more frames, got {lag}")
    if len(depth) != len(skeleton):
        raise UtdError(f"{len(depth)} depth frames but {len(skeleton)} skeletons")
    if len(depth) <= lag:
        raise UtdError(f"a take of {len(depth)} frames has none left after a lag of {lag}")
    return depth[lag:], skeleton[: len(skeleton) - lag]


def reference_source(lag: int) -> str:
    """The reference's ``source`` text, saying how it was put in step with the depth."""
    if lag == 0:
        return f"{REFERENCE_SOURCE}; paired with the depth index by index, as stored"
    return (
        f"{REFERENCE_SOURCE}; each skeleton paired with the depth frame {lag} later in the "
        "stored stream (the stored depth runs late)"
    )


def utd_intrinsics() -> Intrinsics:
    """The un-mirrored 320x240 image's camera: fx = fy = 285.63, cx = 159, cy = 120 (module
    docstring for why cx is W/2 - 1)."""
    return Intrinsics(WIDTH, HEIGHT, FOCAL_PX, FOCAL_PX, WIDTH / 2 - 1, HEIGHT / 2)


def unmirror_depth(depth: np.ndarray) -> np.ndarray:
    """The true camera view of mirrored frames: (..., H, W) -> (..., H, W), columns flipped."""
    return np.ascontiguousarray(depth[..., ::-1])


def kinect_to_camera(joints: np.ndarray) -> np.ndarray:
    """Kinect skeleton space (mirrored x, y up) -> our camera frame (x right in the
    un-mirrored image, y down, z forward): (..., 3) -> (..., 3), negating x and y."""
    return np.asarray(joints, dtype=np.float64) * np.array([-1.0, -1.0, 1.0])
