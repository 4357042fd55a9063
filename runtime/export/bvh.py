"""``motion.bvh``: the tracked motion as a Biovision hierarchy for animation tools.

Skeleton: one BVH joint per segment of :mod:`shared.skeleton`, named like the segment and
placed at its origin (the joint centre it turns about), plus an ``End Site`` at the far end of
each leaf segment (top of the head, wrists, ankles). The named output joints map onto it as:
pelvis = ``pelvis``, spine = ``chest``, neck = ``neck``, shoulder = ``*_upper_arm``, elbow =
``*_forearm``, wrist = end of ``*_forearm``, hip = ``*_thigh``, knee = ``*_shank``, ankle = end
of ``*_shank``; the head centre lies 0.45 of the head length along ``head``. OFFSETs come from
the :class:`~shared.body.BodyShape` in use, so bone lengths are the tracked person's.

World frame: y up, x the camera's right, z pointing from the scene towards the camera; the
origin is the camera centre. It is the camera frame (x right, y down, z forward) turned by
180 degrees about x (``CAMERA_TO_WORLD = diag(1, -1, -1)``), so a level camera gives an
upright character, and a person facing the camera faces +z, the default "front" of most
animation tools. The floor is not known to the tracker, so the character floats at the
camera's height: move the root in the tool if a floor at y = 0 is wanted.

Units: centimetres by default (``units="cm"``), the de-facto BVH unit (CMU, MotionBuilder,
this project's :func:`train.mocap.bvh.read_bvh` default). Blender's importer reads raw file
units as metres: import with *Scale* 0.01 (or write with ``units="m"``).

Rotations: every joint frame is the segment frame (rest pose = all angles zero: upright,
arms down, facing +z). A joint's local rotation ``R_parent^T R_segment`` is written as Euler
angles in degrees, with the channel order of that joint's own DoFs (shoulder ``Z X Y`` =
abduction, flexion, twist; hip ``X Z Y``; ...), so the curves are the anatomical angles of q
up to sign and unused axes stay at zero. The root has ``Xposition Yposition Zposition
Yrotation Xrotation Zrotation`` (yaw, pitch, roll: gimbal lock only when lying down). Each
joint's channel order is spelled out in the file; any reader honouring per-joint orders
(Blender, three.js, MotionBuilder, the project's reader) reproduces the positions exactly.

Streaming: the header holds a fixed-width ``Frames:`` field that is rewritten in place after
every appended frame line, each flushed, so the file parses at every moment between frames.
:meth:`BvhWriter.close` cuts off a half-written line (an interrupt inside a write) and
re-syncs the count.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import rest_pose

__all__ = [
    "CAMERA_TO_WORLD",
    "UNITS_PER_METRE",
    "BVH_JOINT_ORDER",
    "joint_channel_orders",
    "matrix_to_euler",
    "joint_rotations",
    "bvh_hierarchy",
    "bvh_frame_values",
    "BvhWriter",
    "write_bvh",
]

CAMERA_TO_WORLD = np.diag([1.0, -1.0, -1.0])
UNITS_PER_METRE = {"cm": 100.0, "m": 1.0, "mm": 1000.0}
_ROOT_ORDER = "yxz"
_FRAMES_WIDTH = 10  # digits reserved for the frame count in the header


def _depth_first(parent: np.ndarray) -> tuple[int, ...]:
    order, stack = [], [0]
    while stack:
        k = stack.pop()
        order.append(k)
        stack.extend(reversed([int(c) for c in np.flatnonzero(parent == k)]))
    return tuple(order)


# BVH lists joints depth-first; channel columns follow this order.
BVH_JOINT_ORDER: tuple[int, ...] = _depth_first(sk.SEGMENT_PARENT)


def joint_channel_orders() -> tuple[str, ...]:
    """Euler order (e.g. ``"zxy"`` = ``Rz @ Rx @ Ry``) of each segment, in segment order.

    A joint uses the axes of its DoFs in composition order, then the unused axes, so its
    angles are its q angles (up to the sign of mirrored axes). The root uses yaw-pitch-roll.
    """
    orders = [_ROOT_ORDER]
    for k in range(1, sk.NUM_SEGMENTS):
        dofs = [int(d) for d in sk.SEGMENT_DOF_SLOTS[k] if d >= 0]
        letters = "".join("xyz"[int(np.argmax(np.abs(sk.DOF_AXIS[d])))] for d in dofs)
        orders.append(letters + "".join(a for a in "zxy" if a not in letters))
    return tuple(orders)


_ORDERS = joint_channel_orders()
_SEGMENTS_BY_ORDER = {o: [k for k, ok in enumerate(_ORDERS) if ok == o] for o in set(_ORDERS)}


def matrix_to_euler(rot: np.ndarray, order: str) -> np.ndarray:
    """Angles (radians) with ``rot = R_order[0](a) @ R_order[1](b) @ R_order[2](c)``.

    Args:
        rot: (..., 3, 3) rotation matrices.
        order: three distinct axis letters (Tait-Bryan), e.g. ``"zxy"``.
    Returns:
        (..., 3) angles; the middle one in [-pi/2, pi/2]. At gimbal lock (middle angle at
        +-90 degrees) the last angle is set to zero and the first absorbs the rotation.
    """
    i, j, k = ("xyz".index(a) for a in order)
    sign = 1.0 if (i, j, k) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else -1.0
    cos_b = np.hypot(rot[..., i, i], rot[..., i, j])
    b = np.arctan2(sign * rot[..., i, k], cos_b)
    regular = cos_b > 1e-9
    a = np.where(
        regular,
        np.arctan2(-sign * rot[..., j, k], rot[..., k, k]),
        np.arctan2(sign * rot[..., k, j], rot[..., j, j]),
    )
    c = np.where(regular, np.arctan2(-sign * rot[..., i, j], rot[..., i, i]), 0.0)
    return np.stack([a, b, c], -1)


def _rodrigues(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotations about unit axes: axis (..., 3), angle (...) -> (..., 3, 3)."""
    k = np.zeros(axis.shape + (3,))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def joint_rotations(
    q: np.ndarray, chest_tilt: float = 0.0, clavicle_rest: tuple[float, float] = (0.0, 0.0)
) -> np.ndarray:
    """Local rotation of every segment relative to its parent, (F, 34) -> (F, 15, 3, 3).

    The chest's is the body's fixed ``chest_tilt`` about x (it has no DoFs); the clavicles turn
    by their angles plus the body's ``clavicle_rest`` (elevation, protraction), and the upper
    arms start from that rest rotation turned back.

    Segment 0 gets the root orientation (segment -> camera). Child joint offsets carry no
    rotation in this skeleton, so a segment's frame is ``R_parent @ local``, exactly what
    :func:`shared.kinematics.forward_kinematics` composes; here in numpy because one pose per
    frame through torch costs milliseconds of overhead.
    """
    rest = np.asarray(clavicle_rest, dtype=np.float64)
    q = np.array(q, dtype=np.float64)
    q[:, list(sk.CLAVICLE_DOFS)] += np.tile(rest, 2)
    angle = np.linalg.norm(q[:, 3:6], axis=1)
    axis = q[:, 3:6] / np.where(angle > 0, angle, 1.0)[:, None]
    dof = _rodrigues(np.broadcast_to(sk.DOF_AXIS[6:], (len(q), 28, 3)), q[:, 6:])
    dof = np.concatenate([dof, np.broadcast_to(np.eye(3), (len(q), 1, 3, 3))], 1)
    slots = np.where(sk.SEGMENT_DOF_SLOTS >= 6, sk.SEGMENT_DOF_SLOTS - 6, 28)  # 28: identity
    local = dof[:, slots[:, 0]] @ dof[:, slots[:, 1]] @ dof[:, slots[:, 2]]
    local[:, 0] = _rodrigues(axis, angle)
    local[:, sk.SEGMENT_NAMES.index("chest")] = _rodrigues(np.array([1.0, 0.0, 0.0]), chest_tilt)
    # Each upper arm hangs from its clavicle's rest rotation turned back (as in FK).
    for side, (elev, prot) in zip("lr", (sk.CLAVICLE_DOFS[0:2], sk.CLAVICLE_DOFS[2:4])):
        turn = _rodrigues(sk.DOF_AXIS[elev], rest[0]) @ _rodrigues(sk.DOF_AXIS[prot], rest[1])
        arm = sk.SEGMENT_NAMES.index(f"{side}_upper_arm")
        local[:, arm] = turn.T @ local[:, arm]
    return local


def _segment_offsets(body: BodyShape) -> np.ndarray:
    """(15, 3) origin of each segment in its parent's frame, metres (root: zero)."""
    lengths = body.lengths.detach().cpu().double().numpy()
    hip = float(body.hip_half_width)
    par = sk.SEGMENT_PARENT.clip(min=0)
    off = (sk.SEGMENT_ATTACH_END * lengths[par])[:, None] * sk.SEGMENT_AXIS[par]
    off[:, 0] += sk.SEGMENT_LATERAL * hip
    off[0] = 0.0
    return off


def _check_body(body: BodyShape) -> None:
    if body.lengths.dim() != 1:
        raise ValueError("BVH export needs a single (unbatched) body")
    body.validate()


def bvh_hierarchy(body: BodyShape, units: str = "cm") -> str:
    """The ``HIERARCHY`` section (ends with a newline) for ``body``."""
    _check_body(body)
    scale = UNITS_PER_METRE[units]
    offsets = _segment_offsets(body) * scale
    lengths = body.lengths.detach().cpu().double().numpy() * scale
    children = {
        k: [int(c) for c in np.flatnonzero(sk.SEGMENT_PARENT == k)] for k in range(sk.NUM_SEGMENTS)
    }
    out = ["HIERARCHY"]

    def num(v: float) -> str:
        return f"{v + 0.0:.6f}"  # + 0.0 turns -0.0 into 0.0

    def emit(k: int, depth: int) -> None:
        pad = "\t" * depth
        keyword = "ROOT" if k == 0 else "JOINT"
        out.append(f"{pad}{keyword} {sk.SEGMENT_NAMES[k]}")
        out.append(pad + "{")
        out.append(f"{pad}\tOFFSET {' '.join(num(v) for v in offsets[k])}")
        rot = " ".join(f"{a.upper()}rotation" for a in _ORDERS[k])
        if k == 0:
            out.append(f"{pad}\tCHANNELS 6 Xposition Yposition Zposition {rot}")
        else:
            out.append(f"{pad}\tCHANNELS 3 {rot}")
        for c in children[k]:
            emit(c, depth + 1)
        if not children[k]:
            end = lengths[k] * sk.SEGMENT_AXIS[k]
            out.append(f"{pad}\tEnd Site")
            out.append(pad + "\t{")
            out.append(f"{pad}\t\tOFFSET {' '.join(num(v) for v in end)}")
            out.append(pad + "\t}")
        out.append(pad + "}")

    emit(0, 0)
    return "\n".join(out) + "\n"


def bvh_frame_values(q: np.ndarray, body: BodyShape, units: str = "cm") -> np.ndarray:
    """Channel values of poses ``q`` in file column order.

    Args:
        q: (F, 34) poses in the camera frame.
    Returns:
        (F, 6 + 3 * 14) root position (file units, BVH world frame), then Euler angles in
        degrees per joint, joints in :data:`BVH_JOINT_ORDER`.
    """
    _check_body(body)
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != sk.NUM_DOFS:
        raise ValueError(f"q must have shape (F, {sk.NUM_DOFS}), got {q.shape}")
    if not np.isfinite(q).all():
        raise ValueError("q has non-finite values")
    rest = tuple(float(a) for a in body.clavicle_rest)
    local = joint_rotations(q, float(body.chest_tilt), rest)
    local[:, 0] = CAMERA_TO_WORLD @ local[:, 0]
    root = q[:, 0:3] @ CAMERA_TO_WORLD.T * UNITS_PER_METRE[units]
    angles = np.empty((len(q), sk.NUM_SEGMENTS, 3))
    for order, segments in _SEGMENTS_BY_ORDER.items():  # one batched call per Euler order
        angles[:, segments] = matrix_to_euler(local[:, segments], order)
    angles = np.degrees(angles[:, list(BVH_JOINT_ORDER)]).reshape(len(q), -1)
    return np.concatenate([root, angles], 1)


def _format_rows(values: np.ndarray) -> bytes:
    # 4 decimals of a centimetre (1 um) and 1e-5 degrees: far below tracking accuracy.
    values = values + 0.0
    rows = [
        " ".join([f"{v:.4f}" for v in row[:3]] + [f"{v:.5f}" for v in row[3:]]) for row in values
    ]
    return ("\n".join(rows) + "\n").encode("ascii") if rows else b""


class BvhWriter:
    """Streams poses into a BVH file that stays valid between frames.

    Args:
        path: file to (over)write.
        body: the body in use (OFFSETs).
        fps: stream frame rate (``Frame Time = 1 / fps``).
        units: ``"cm"`` (default), ``"m"`` or ``"mm"``.
        fsync: ``os.fsync`` after every frame as well as flushing.
        keep_poses: keep every frame's pose so that :meth:`set_body` can rewrite the file
            (272 bytes a frame, 29 MB for an hour at 30 frames/s; only when the body may
            change during the run).
    """

    def __init__(
        self,
        path: str | Path,
        body: BodyShape,
        fps: float,
        units: str = "cm",
        fsync: bool = False,
        keep_poses: bool = False,
    ) -> None:
        if units not in UNITS_PER_METRE:
            raise ValueError(f"units must be one of {sorted(UNITS_PER_METRE)}, got {units!r}")
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be positive, got {fps}")
        _check_body(body)
        self.path = Path(path)
        self.body = body.to(torch.float64)
        self.units = units
        self.fsync = fsync
        self.fps = float(fps)
        self.frames = 0
        self._last: np.ndarray | None = None
        self.keep_poses = keep_poses
        self._poses: list[np.ndarray] = []  # with keep_poses: every frame's pose
        self._last_q: np.ndarray | None = None
        self._file = open(self.path, "w+b")  # noqa: SIM115 (lives until close)
        self._write_head()

    def _write_head(self) -> None:
        head = bvh_hierarchy(self.body, self.units) + "MOTION\n"
        self._count_pos = len(head.encode("ascii")) + len("Frames: ")
        head += f"Frames: {self.frames:<{_FRAMES_WIDTH}d}\nFrame Time: {1.0 / self.fps:.8f}\n"
        self._file.write(head.encode("ascii"))
        self._end = self._file.tell()
        self._sync()

    def set_body(self, body: BodyShape, path: str | Path | None = None) -> None:
        """Use ``body`` from now on and rewrite the frames written so far with it (the
        offsets and the root's values depend on the body): the file then reads as if the
        body had been known from the first frame. Written to a new file and renamed over
        the old one, so a reader sees one or the other, never a mix; on an error the old
        file and state stay. ``path``: where the file is now, if it was moved."""
        if self._file is None:
            raise ValueError(f"{self.path}: writer is closed")
        if self.frames and not self.keep_poses:
            raise ValueError(f"{self.path}: set_body after frames needs keep_poses=True")
        _check_body(body)
        path = self.path if path is None else Path(path)
        tmp = path.with_name(path.name + ".tmp")
        new = open(tmp, "w+b")  # noqa: SIM115 (lives until close); raises with nothing changed
        saved = (self._file, self.body, self.frames, self._end, self._count_pos, self._last)
        try:
            self._file, self.body, self.frames = new, body.to(torch.float64), 0
            self._write_head()
            if self._poses:
                rows = bvh_frame_values(np.stack(self._poses), self.body, self.units)
                self._append(rows, None)
                self._last = rows[-1:]
            os.replace(tmp, path)
        except BaseException:
            new.close()
            tmp.unlink(missing_ok=True)
            self._file, self.body, self.frames, self._end, self._count_pos, self._last = saved
            raise
        saved[0].close()
        self.path = path

    def _sync(self) -> None:
        self._file.flush()
        if self.fsync:
            os.fsync(self._file.fileno())

    def _append(self, values: np.ndarray, poses: list[np.ndarray] | None) -> None:
        """Write ``values`` (F, C) rows; ``poses``: the F poses they came from, kept for
        :meth:`set_body` (None when rewriting the kept ones)."""
        if self._file is None:
            raise ValueError(f"{self.path}: writer is closed")
        if poses is not None and self.keep_poses:
            self._poses.extend(poses)
        data = _format_rows(values)
        # Line first, then the count: an interrupt in between leaves one extra line that
        # close() cuts off; a reader never sees a count larger than the lines present.
        self._file.seek(self._end)
        self._file.write(data)
        self._sync()
        self._end += len(data)
        self.frames += len(values)
        self._write_count()

    def _write_count(self) -> None:
        self._file.seek(self._count_pos)
        self._file.write(f"{self.frames:<{_FRAMES_WIDTH}d}".encode("ascii"))
        self._sync()

    def write_pose(self, q: np.ndarray | None, repeat: int = 1) -> None:
        """Append ``repeat`` frames of pose ``q`` (34,) in the camera frame.

        ``q`` None repeats the last written pose, or the rest pose facing the camera at
        2.5 m (:func:`shared.kinematics.rest_pose`) before any pose was written.
        """
        if repeat < 1:
            return
        if q is None:
            if self._last is None:
                self._last_q = rest_pose(1, dtype=torch.float64).numpy()[0]
                self._last = bvh_frame_values(self._last_q[None], self.body, self.units)
            values = self._last
        else:
            self._last_q = np.asarray(q, dtype=np.float64)
            values = bvh_frame_values(self._last_q[None], self.body, self.units)
            self._last = values
        self._append(np.repeat(values, repeat, 0), [self._last_q] * repeat)

    def write_poses(self, q: np.ndarray) -> None:
        """Append poses ``q`` (F, 34) in one batch."""
        values = bvh_frame_values(q, self.body, self.units)
        if len(values):
            self._last = values[-1:]
            self._last_q = np.asarray(q[-1], dtype=np.float64)
            self._append(values, list(np.asarray(q, dtype=np.float64)))

    def close(self) -> None:
        """Drop any half-written tail, make ``Frames:`` match the lines, close. Idempotent."""
        if self._file is None:
            return
        self._file.truncate(self._end)
        self._write_count()
        self._file.close()
        self._file = None

    def __enter__(self) -> BvhWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_bvh(
    path: str | Path, q: np.ndarray, body: BodyShape, fps: float, units: str = "cm"
) -> None:
    """Write poses ``q`` (F, 34, camera frame) as a complete BVH file."""
    with BvhWriter(path, body, fps, units) as writer:
        writer.write_poses(np.asarray(q, dtype=np.float64).reshape(-1, sk.NUM_DOFS))
