"""Is the person holding the reference pose? The automatic check of ``runtime-calibrate``.

The check runs the detector on each frame and compares its pose with the reference pose. Three
things make that comparison hold for any body and any camera:

- **The detector fits a body of the person's size.** The template is scaled to the person's
  stature, measured directly from the frame: in the reference pose the head is the highest
  point, so the stature is the person's height above the floor (or their vertical extent when
  no floor is in view). A template 20 cm too tall for the person cannot be laid on their
  labels without bending the knees and leaning back, which no tolerance should excuse.
- **Limbs are compared by direction, not by joint angle.** The same arm direction comes from
  many combinations of clavicle, shoulder and twist angles; what the reference pose asks is
  that each upper arm, forearm, thigh and shank points where the reference's does, in the
  body's own frame (:func:`limb_directions`).
- **Facing is a turn about the body's own vertical axis.** A camera mounted high looks down
  on the person; the whole-body rotation then includes the camera's pitch, which says nothing
  about whether the person faces it. The facing angle is measured between the body's forward
  direction and the direction to the camera, both projected on the plane normal to the
  body's up axis. When the floor is known the body must also stand upright on it.
"""

from __future__ import annotations

import math

import torch
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics, depth_to_points
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
from depthmocap.shared.skeleton import JOINT_NAMES
from depthmocap.shared.so3 import rotvec_to_matrix

from .calibrate import CalibrationConfig, reference_pose

__all__ = [
    "LIMBS",
    "ReferencePoseWatcher",
    "facing_angle",
    "is_reference_pose",
    "limb_directions",
    "person_stature",
]

# The limbs whose directions the reference pose fixes: (from joint, to joint).
LIMBS: tuple[tuple[str, str], ...] = tuple(
    (f"{s}_{a}", f"{s}_{b}")
    for s in "lr"
    for a, b in (("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle"))
)
_LIMB_INDEX = torch.tensor([[JOINT_NAMES.index(a), JOINT_NAMES.index(b)] for a, b in LIMBS])


def limb_directions(q: torch.Tensor, body: BodyShape) -> torch.Tensor:
    """Unit directions of the :data:`LIMBS` in the body's root frame.

    Args:
        q: (B, 34) poses.
        body: the body they are posed with.
    Returns:
        (B, 8, 3) unit vectors (root frame: independent of where the body stands and faces).
    """
    joints = named_joint_positions(forward_kinematics(q, body.to(dtype=q.dtype, device=q.device)))
    vec = joints[:, _LIMB_INDEX[:, 1]] - joints[:, _LIMB_INDEX[:, 0]]  # (B, 8, 3) camera frame
    rot = rotvec_to_matrix(q[:, 3:6])  # body -> camera
    local = torch.einsum("bji,bkj->bki", rot, vec)  # R^T v
    return local / local.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def _angle(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Angle (rad) between (..., 3) vectors."""
    cos = (a * b).sum(-1) / (a.norm(dim=-1) * b.norm(dim=-1)).clamp_min(1e-12)
    return torch.arccos(cos.clamp(-1.0, 1.0))


def facing_angle(q: torch.Tensor) -> torch.Tensor:
    """(B,) angle (rad) between the body's forward direction and the direction from the body
    to the camera, turned about the body's up axis only (a camera's pitch does not count).

    The body frame's +y is up and +z forward (the reference pose, facing the camera, has the
    root rotation pi about x).
    """
    rot = rotvec_to_matrix(q[:, 3:6])
    up, forward = rot[..., 1], rot[..., 2]  # (B, 3) in the camera frame
    to_camera = -q[:, :3]
    flat = to_camera - (to_camera * up).sum(-1, keepdim=True) * up
    return _angle(forward, flat)


def is_reference_pose(
    q: torch.Tensor,
    cfg: CalibrationConfig | None = None,
    up: torch.Tensor | None = None,
    body: BodyShape | None = None,
) -> bool:
    """Whether pose ``q`` (34,) is the reference pose (module docstring).

    Args:
        q: (34,) the detected pose.
        cfg: the tolerances (``pose_tolerance_deg`` per limb direction, ``facing_tolerance_deg``
            for facing and, with ``up``, for standing upright).
        up: (3,) the world's up direction in the camera frame (the floor's normal), or None.
        body: the body the pose was fitted with (default: the average adult).
    """
    cfg = cfg or CalibrationConfig()
    body = (body or BodyShape.default()).to(dtype=torch.float64, device="cpu")
    q = q.detach().double().cpu()[None]
    ref = reference_pose(cfg, tuple(q[0, :3].tolist()), dtype=torch.float64)[None]
    limbs = _angle(limb_directions(q, body), limb_directions(ref, body))
    ok = bool((limbs <= math.radians(cfg.pose_tolerance_deg)).all())
    ok &= float(facing_angle(q)[0]) <= math.radians(cfg.facing_tolerance_deg)
    if up is not None:
        body_up = rotvec_to_matrix(q[:, 3:6])[0, :, 1]
        tilt = _angle(body_up, up.detach().double().cpu())
        ok &= float(tilt) <= math.radians(cfg.facing_tolerance_deg)
    return ok


def person_stature(
    depth_m: torch.Tensor,
    mask: torch.Tensor,
    intr: Intrinsics,
    floor: tuple[torch.Tensor, torch.Tensor] | None,
    floor_band_m: float = 0.05,
) -> float | None:
    """The height of a person standing upright (the reference pose), from one frame.

    Args:
        depth_m: (H, W) metres; mask: (H, W) bool, the person.
        floor: the floor plane (unit up normal (3,), a point on it (3,)) in the camera frame,
            or None: then the person's extent along the camera's up axis (-y), plus the band
            the floor removal took off the feet.
        floor_band_m: that band, metres.
    Returns:
        metres (the 99.9th percentile, so a few stray pixels do not count), or None when the
        mask has too few points.
    """
    points = depth_to_points(depth_m[None].double(), intr)[0][mask & (depth_m > 0)]
    if points.shape[0] < 50:
        return None
    if floor is not None:
        normal, centre = (t.to(points) for t in floor)
        return float(torch.quantile((points - centre) @ normal, 0.999))
    up = -points[:, 1]
    return float(torch.quantile(up, 0.999) - torch.quantile(up, 0.001)) + floor_band_m


class ReferencePoseWatcher:
    """Automatic mode: collects frames while the reference pose is held.

    Feed every frame's detected pose with :meth:`update`; once the pose was held for
    ``cfg.hold_frames`` frames, :attr:`ready` is True and :attr:`frames` holds them (depth,
    labels). More than ``cfg.hold_misses`` frames in a row out of the pose start the count
    again; fewer are skipped (one frame's detection can miss a pose the person holds).
    """

    def __init__(self, cfg: CalibrationConfig | None = None) -> None:
        self.cfg = cfg or CalibrationConfig()
        self.frames: list[tuple[torch.Tensor, torch.Tensor]] = []
        self._misses = 0

    @property
    def ready(self) -> bool:
        return len(self.frames) >= self.cfg.hold_frames

    def update(
        self,
        q: torch.Tensor | None,
        depth_m: torch.Tensor,
        labels: torch.Tensor,
        up: torch.Tensor | None = None,
        body: BodyShape | None = None,
    ) -> bool:
        """Add one frame (``q``: its detected pose, None if none; ``up``, ``body``: as for
        :func:`is_reference_pose`); returns :attr:`ready`."""
        if q is not None and is_reference_pose(q, self.cfg, up, body):
            self.frames.append((depth_m, labels))
            self._misses = 0
        else:
            self._misses += 1
            if self._misses > self.cfg.hold_misses:
                self.frames.clear()
        return self.ready
