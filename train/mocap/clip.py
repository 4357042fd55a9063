"""A skeleton animation sampled at a fixed frame rate, plus the numpy helpers the readers share.

Conventions used by every reader in this package:

* Rotation matrices act on column vectors: ``v_world = R @ v_local``.
* ``rotations[f, j]`` is the global orientation of joint ``j`` (joint frame -> world).
* ``positions[f, j]`` is the global position of joint ``j`` in metres.
* ``offsets[j]`` is the rest offset of joint ``j`` from its parent, expressed in the parent's
  joint frame, in metres, so that for every joint whose translation is not animated
  ``positions[f, j] == positions[f, p] + rotations[f, p] @ offsets[j]`` with ``p = parents[j]``.
* Joints are ordered so that parents come before their children (``parents[j] < j``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


def axis_rotation(axis: str, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about one coordinate axis.

    Args:
        axis: ``"x"``, ``"y"`` or ``"z"`` (case-insensitive).
        angle: (...) angles in radians, right-handed (counter-clockwise looking down the axis).

    Returns:
        (..., 3, 3) rotation matrices.
    """
    key = axis.lower()
    if key not in _AXIS_INDEX:
        raise ValueError(f"unknown rotation axis {axis!r}; expected one of x, y, z")
    angle = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    i = _AXIS_INDEX[key]
    # The two axes that span the rotation plane, in cyclic order so the sign pattern is shared.
    a, b = (i + 1) % 3, (i + 2) % 3
    out[..., i, i] = 1.0
    out[..., a, a] = c
    out[..., b, b] = c
    out[..., a, b] = -s
    out[..., b, a] = s
    return out


def euler_to_matrix(angles: np.ndarray, axes: str) -> np.ndarray:
    """Compose elementary rotations left to right: ``R_axes[0] @ R_axes[1] @ ...``.

    With column vectors this means the LAST listed axis is applied first. This is the BVH
    convention (channels ``Zrotation Yrotation Xrotation`` give ``Rz @ Ry @ Rx``). For the ASF
    convention, where the listed order is the application order, pass both reversed.

    Args:
        angles: (..., K) angles in radians, one per axis.
        axes: K axis letters, e.g. ``"zyx"`` (case-insensitive).

    Returns:
        (..., 3, 3) rotation matrices; the identity when ``axes`` is empty.
    """
    angles = np.asarray(angles, dtype=np.float64)
    if angles.shape[-1] != len(axes):
        raise ValueError(f"got {angles.shape[-1]} angles for {len(axes)} axes {axes!r}")
    out = np.broadcast_to(np.eye(3), angles.shape[:-1] + (3, 3)).copy()
    for k, axis in enumerate(axes):
        out = out @ axis_rotation(axis, angles[..., k])
    return out


def forward_kinematics(
    parents: np.ndarray, local_rotations: np.ndarray, local_translations: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Global joint orientations and positions from per-joint local transforms.

    Vectorised over frames; the loop runs over joints only. Requires ``parents[j] < j``.

    Args:
        parents: (J,) parent index per joint, -1 for a root.
        local_rotations: (F, J, 3, 3) rotation of each joint frame relative to its parent's frame
            (relative to world for a root).
        local_translations: (F, J, 3) or (J, 3) origin of each joint frame in its parent's frame
            (in world for a root).

    Returns:
        (rotations (F, J, 3, 3), positions (F, J, 3)) in world coordinates.
    """
    num_frames, num_joints = local_rotations.shape[:2]
    trans = np.broadcast_to(local_translations, (num_frames, num_joints, 3))
    rotations = np.empty_like(local_rotations)
    positions = np.empty((num_frames, num_joints, 3))
    for j in range(num_joints):
        p = int(parents[j])
        if p < 0:
            rotations[:, j] = local_rotations[:, j]
            positions[:, j] = trans[:, j]
        else:
            rotations[:, j] = rotations[:, p] @ local_rotations[:, j]
            positions[:, j] = positions[:, p] + np.einsum(
                "fab,fb->fa", rotations[:, p], trans[:, j]
            )
    return rotations, positions


@dataclass(frozen=True, eq=False)
class MotionClip:
    """Global joint orientations and positions of one skeleton over F frames.

    Attributes:
        joint_names: J unique joint names.
        parents: (J,) int parent index per joint, -1 for the root; ``parents[j] < j``.
        rotations: (F, J, 3, 3) global joint orientations (joint frame -> world).
        positions: (F, J, 3) global joint positions in metres.
        fps: frames per second (> 0).
        source: the file the clip was read from.
        offsets: (J, 3) rest offset of each joint from its parent in the parent's joint frame,
            in metres (for a root: its rest position in world, usually zero).
    """

    joint_names: tuple[str, ...]
    parents: np.ndarray
    rotations: np.ndarray
    positions: np.ndarray
    fps: float
    source: str
    offsets: np.ndarray

    def __post_init__(self) -> None:
        names = tuple(self.joint_names)
        object.__setattr__(self, "joint_names", names)
        num_joints = len(names)
        if num_joints == 0:
            raise ValueError(f"{self.source}: a MotionClip needs at least one joint")
        if len(set(names)) != num_joints:
            dupes = sorted({n for n in names if names.count(n) > 1})
            raise ValueError(f"{self.source}: duplicate joint names {dupes}")

        parents = np.asarray(self.parents)
        if parents.shape != (num_joints,) or not np.issubdtype(parents.dtype, np.integer):
            raise ValueError(
                f"{self.source}: parents must be an int array of shape ({num_joints},), "
                f"got {parents.dtype} {parents.shape}"
            )
        # Parents before children lets every consumer run FK in one pass over the joints.
        bad = np.flatnonzero((parents < -1) | (parents >= np.arange(num_joints)))
        if bad.size:
            j = int(bad[0])
            raise ValueError(
                f"{self.source}: parents[{j}] = {int(parents[j])} for joint {names[j]!r}; "
                "each parent must be -1 or an earlier joint"
            )

        rotations = np.asarray(self.rotations, dtype=np.float64)
        positions = np.asarray(self.positions, dtype=np.float64)
        offsets = np.asarray(self.offsets, dtype=np.float64)
        if rotations.ndim != 4 or rotations.shape[1:] != (num_joints, 3, 3):
            raise ValueError(
                f"{self.source}: rotations must have shape (F, {num_joints}, 3, 3), "
                f"got {rotations.shape}"
            )
        num_frames = rotations.shape[0]
        if positions.shape != (num_frames, num_joints, 3):
            raise ValueError(
                f"{self.source}: positions must have shape ({num_frames}, {num_joints}, 3), "
                f"got {positions.shape}"
            )
        if offsets.shape != (num_joints, 3):
            raise ValueError(
                f"{self.source}: offsets must have shape ({num_joints}, 3), got {offsets.shape}"
            )
        for label, array in (("rotations", rotations), ("positions", positions)):
            if not np.all(np.isfinite(array)):
                raise ValueError(f"{self.source}: {label} contain NaN or infinite values")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"{self.source}: fps must be a positive number, got {self.fps}")

        object.__setattr__(self, "parents", parents.astype(np.int64))
        object.__setattr__(self, "rotations", rotations)
        object.__setattr__(self, "positions", positions)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "fps", float(self.fps))
        object.__setattr__(self, "source", str(self.source))

    @property
    def num_frames(self) -> int:
        """F, the number of frames."""
        return int(self.rotations.shape[0])

    @property
    def num_joints(self) -> int:
        """J, the number of joints."""
        return len(self.joint_names)

    def index(self, name: str) -> int:
        """Index of the joint called ``name``; ValueError listing the names when absent."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise ValueError(
                f"{self.source}: no joint named {name!r}; joints are {list(self.joint_names)}"
            ) from None

    def subsample(self, step: int) -> MotionClip:
        """Every ``step``-th frame starting at frame 0, with ``fps`` divided by ``step``."""
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 1:
            raise ValueError(f"subsample step must be a positive integer, got {step!r}")
        return self._with_frames(slice(None, None, int(step)), self.fps / int(step))

    def slice(self, start: int, stop: int) -> MotionClip:
        """Frames ``start`` (inclusive) to ``stop`` (exclusive); negative indices as in Python."""
        begin, end, _ = slice(start, stop).indices(self.num_frames)
        if end <= begin:
            raise ValueError(
                f"slice({start}, {stop}) of a {self.num_frames}-frame clip selects no frames"
            )
        return self._with_frames(slice(begin, end), self.fps)

    def _with_frames(self, frames: slice, fps: float) -> MotionClip:
        return MotionClip(
            joint_names=self.joint_names,
            parents=self.parents,
            rotations=self.rotations[frames],
            positions=self.positions[frames],
            fps=fps,
            source=self.source,
            offsets=self.offsets,
        )
