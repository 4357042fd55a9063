"""3D pose detection from classified depth pixels (Wei section 4.2).

labels (forest argmax, or ground truth) -> 3D points -> RANSAC bone fitting drops misclassified
pixels (:mod:`.bone_ransac`) -> per-class centroids as markers (:mod:`.centroids`) -> inverse
kinematics in joint-angle space with joint limits (``shared.ik.fit_pose``, Levenberg-Marquardt)
-> a few iterations of the MAP tracker from the IK pose as refinement (Wei: three), from its
limb swaps and limb resets too (:func:`limb_swaps`, :func:`limb_resets`), the best fit kept.

The IK is local, so it runs from several root orientations at once (one batch) and keeps the
best fit: the torso frame measured from the centroids (up: pelvis -> chest; left: right-side
minus left-side centroids of hips, clavicles, upper arms), the same frame turned by 180 degrees
about its up axis (left/right labels swapped by the forest), and upright facing the camera or
with the back to it. All starts have every joint angle at zero; a pose hint (e.g. the last
tracked pose) is one more start.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics, depth_to_points
from depthmocap.shared.ik import fit_pose
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
from depthmocap.shared.labels import NUM_CLASSES, PART_NAMES
from depthmocap.shared.so3 import matrix_to_rotvec

from .bone_ransac import fit_bones
from .centroids import class_centroids, part_markers
from .config import DetectorConfig

if TYPE_CHECKING:
    from depthmocap.runtime.tracker import TrackResult

# The detector's fixed choices (formerly DetectorConfig fields; values unchanged).
# RANSAC (Wei 4.2): of the pairs that pass the length test, at most this many are scored by
# their inlier count (the rest are redundant; keeps the cost bounded) ...
RANSAC_SCORED = 128
# ... on at most this many points per bone (a random subset).
RANSAC_POINTS = 400
# Pairs closer than this fraction of the bone's reach are discarded (Wei: 1/5).
MIN_PAIR_FRACTION = 0.2
# Slack added to the bone's diameter when testing whether a point lies on or within the
# sampled bone (sensor noise, model error), metres.
INLIER_MARGIN_M = 0.03
# A class centroid lies on the visible surface; it is pushed away from the camera by this
# fraction of the segment's radius (pi/4: the mean depth of a cylinder's visible half).
SURFACE_OFFSET = 0.785
# A class with fewer surviving pixels gives no centroid (missing or occluded).
MIN_CLASS_PIXELS = 12
# Marker confidence n / (n + this) for a class with n surviving pixels: small visible parts
# count less in the IK.
WEIGHT_PIXELS = 30.0
# Levenberg-Marquardt iterations of the IK, and its prior weight towards the start pose (per
# squared radian, against squared metres of marker error).
IK_ITERATIONS = 15
IK_PRIOR = 1e-3
# IK starts: the torso frame from the centroids, the same turned by 180 degrees, upright
# facing and with the back to the camera (this many of them, in that order) ...
ORIENTATION_STARTS = 4
# ... times this many arm configurations: hanging, raised sideways (raised overhead is a
# third, unused), every start with its own prior reference.
ARM_STARTS = 2

# Start poses (K, 34) -> the tracker's few-iteration refinement of the frame from each, in
# order (one batched fit: ``Tracker.fit_starts``).
Refine = Callable[[torch.Tensor], "list[TrackResult]"]
# The IK pose (34,) -> whether it agrees with what the caller already has (the hybrid's track):
# then the refinement is not run (``DetectionResult.confirmed``).
Confirm = Callable[[torch.Tensor], bool]

__all__ = [
    "Confirm",
    "DetectionResult",
    "DetectorError",
    "Refine",
    "detect_pose",
    "labels_from",
    "limb_resets",
    "limb_swaps",
    "Detector",
]


class DetectorError(ValueError):
    """Input the detector cannot work with (shapes, label values)."""


@dataclass
class DetectionResult:
    """What the detector found in one frame.

    Attributes:
        found: enough labelled body pixels for a pose (otherwise q is the hint or None).
        q: (34,) final pose (refined when a tracker was given), or None if not found.
        q_ik: (34,) the IK pose before refinement, or None.
        joints: (16, 3) named joints of q, or None.
        targets: (19, 3) class-centroid targets (NaN for missing classes).
        weights: (19,) their IK weights (0 = missing).
        counts: (19,) surviving pixels per class.
        ik_rms: weighted RMS marker error of the IK, metres (inf if not found).
        labels: (H, W) uint8 part labels after outlier removal (rejected pixels set to 0).
        labelled_pixels: body pixels with a label before outlier removal.
        refined: the tracker's result of the refinement, or None.
        confirmed: the IK pose agreed with the caller's pose (``confirm``), so the
            refinement was not run: q is the IK pose, refined None.
    """

    found: bool
    q: torch.Tensor | None
    q_ik: torch.Tensor | None
    joints: torch.Tensor | None
    targets: torch.Tensor
    weights: torch.Tensor
    counts: torch.Tensor
    ik_rms: float
    labels: torch.Tensor
    labelled_pixels: int
    refined: TrackResult | None = None
    confirmed: bool = False


def labels_from(labels_or_posteriors: torch.Tensor | np.ndarray) -> torch.Tensor:
    """(H, W) int labels from labels, or from posteriors (C, H, W) / (H, W, C) by argmax."""
    x = torch.as_tensor(labels_or_posteriors)
    if x.dim() == 2:
        if x.is_floating_point():
            raise DetectorError("2-D label images must be integer part labels")
        if x.numel() and (int(x.min()) < 0 or int(x.max()) >= NUM_CLASSES):
            raise DetectorError(f"labels must be in [0, {NUM_CLASSES - 1}]")
        return x.long()
    if x.dim() == 3 and x.shape[0] == NUM_CLASSES:
        return x.argmax(0)
    if x.dim() == 3 and x.shape[-1] == NUM_CLASSES:
        return x.argmax(-1)
    raise DetectorError(
        f"expected (H, W) labels or ({NUM_CLASSES}, H, W) posteriors, got {tuple(x.shape)}"
    )


_SIDE_PAIRS = tuple(
    (PART_NAMES.index("l_" + n) - 1, PART_NAMES.index("r_" + n) - 1)
    for n in ("thigh_upper", "clavicle", "upper_arm")
)
_PELVIS, _ABDOMEN, _CHEST = (PART_NAMES.index(n) - 1 for n in ("pelvis", "abdomen", "chest"))


def _normalize(v: torch.Tensor) -> torch.Tensor:
    return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def start_orientations(targets: torch.Tensor, weights: torch.Tensor, count: int) -> torch.Tensor:
    """Root rotation vectors of the IK starts (module docstring): (count, 3), count <= 4."""
    dev, dt = targets.device, targets.dtype
    t = torch.nan_to_num(targets)
    present = weights > 0

    def centre(ids):
        m = present[list(ids)].to(dt)
        return (t[list(ids)] * m[:, None]).sum(0) / m.sum().clamp_min(1.0), bool(m.sum() > 0)

    low, has_low = centre((_PELVIS, _ABDOMEN))
    high, has_high = centre((_CHEST,))
    up = _normalize(high - low) if has_low and has_high else t.new_tensor([0.0, -1.0, 0.0])
    left = t.new_zeros(3)
    for li, ri in _SIDE_PAIRS:
        if bool(present[li] & present[ri]):
            left = left + _normalize(t[li] - t[ri])
    if float(left.norm()) < 1e-6:
        left = t.new_tensor([-1.0, 0.0, 0.0])  # facing the camera: the person's left is -x
    left = _normalize(left - (left @ up) * up)
    forward = torch.linalg.cross(left, up)
    measured = torch.stack([left, up, forward], 1)  # columns: body axes in camera frame
    turn = torch.diag(t.new_tensor([-1.0, 1.0, -1.0]))
    facing = torch.diag(t.new_tensor([1.0, -1.0, -1.0]))
    rots = torch.stack([measured, measured @ turn, facing, facing @ turn])[: max(1, count)]
    return matrix_to_rotvec(rots.to(device=dev, dtype=dt))


_ARM_ABDUCTION_DEG = (0.0, 90.0, 160.0)


def _arm_presets(count: int, like: torch.Tensor) -> torch.Tensor:
    """Joint-angle starts (count, 34): both arms hanging, raised sideways, raised overhead.

    The arm's IK has a local minimum between abduction and flexion for raised arms; starting
    from each of these (in that order, ``count`` of them) lets the batch find the right branch.
    """
    out = like.new_zeros(max(1, min(count, len(_ARM_ABDUCTION_DEG))), sk.NUM_DOFS)
    for i in range(out.shape[0]):
        for side in ("l", "r"):
            out[i, sk.DOF_NAMES.index(f"{side}_humerus_abd")] = math.radians(_ARM_ABDUCTION_DEG[i])
    return out


def detect_pose(
    depth_m: torch.Tensor,
    labels: torch.Tensor | np.ndarray,
    intr: Intrinsics,
    body: BodyShape,
    cfg: DetectorConfig | None = None,
    q_hint: torch.Tensor | None = None,
    mask: torch.Tensor | None = None,
    refine: Refine | None = None,
    generator: torch.Generator | None = None,
    confirm: Confirm | None = None,
) -> DetectionResult:
    """Pose from one depth frame and its part labels (module docstring).

    Args:
        depth_m: (H, W) metric depth, 0 = no reading.
        labels: (H, W) int part labels (0 = background), or posteriors (C, H, W) / (H, W, C).
        intr: intrinsics of the image.
        body: body model (unbatched).
        cfg: settings (defaults when None).
        q_hint: (34,) an extra IK start (e.g. the last good pose), optional.
        mask: (H, W) bool person mask; labels outside it are ignored.
        refine: the tracker's refinement of this frame from K poses (Wei: three
            iterations), applied to the IK pose and its limb swaps at once when given; the
            caller binds it to the frame (its observation, labels and iteration count).
        generator: random source of the RANSAC (default: seeded from ``cfg.seed``).
        confirm: asked with the IK pose before the refinement; True skips the refinement
            (the caller's own pose stands: ``DetectionResult.confirmed``).
    Returns:
        :class:`DetectionResult`.
    """
    cfg = cfg or DetectorConfig()
    if depth_m.dim() != 2 or tuple(depth_m.shape) != (intr.height, intr.width):
        raise DetectorError(
            f"depth must be (H, W) = ({intr.height}, {intr.width}), got {tuple(depth_m.shape)}"
        )
    lab = labels_from(labels).to(depth_m.device)
    if lab.shape != depth_m.shape:
        raise DetectorError(f"labels {tuple(lab.shape)} do not match depth {tuple(depth_m.shape)}")
    dev = depth_m.device
    dt = depth_m.dtype if depth_m.is_floating_point() else torch.float32
    depth = depth_m.to(dt)
    body = body.to(dtype=dt, device=dev)
    gen = generator or torch.Generator().manual_seed(cfg.seed)
    use = (lab > 0) & torch.isfinite(depth) & (depth > 0)
    if mask is not None:
        use = use & mask.to(device=dev, dtype=torch.bool)
    n_lab = int(use.sum())
    pts_img = depth_to_points(torch.where(use, depth, torch.zeros_like(depth))[None], intr)[0]
    C = NUM_CLASSES - 1
    empty = DetectionResult(
        False, None, None, None, depth.new_full((C, 3), math.nan), depth.new_zeros(C),
        depth.new_zeros(C), math.inf, torch.zeros_like(lab, dtype=torch.uint8), n_lab,
    )  # fmt: skip
    if n_lab < cfg.min_person_pixels:
        return empty

    pix = use.nonzero(as_tuple=True)
    points, plabels = pts_img[pix], lab[pix]
    fit = fit_bones(
        points, plabels, body, cfg.ransac_samples, RANSAC_SCORED, RANSAC_POINTS,
        MIN_PAIR_FRACTION, INLIER_MARGIN_M, gen,
    )  # fmt: skip
    cen = class_centroids(
        points, plabels, fit.inlier, body, SURFACE_OFFSET, MIN_CLASS_PIXELS, WEIGHT_PIXELS,
    )  # fmt: skip
    kept = torch.zeros_like(lab, dtype=torch.uint8)
    kept[pix] = torch.where(fit.inlier, plabels, torch.zeros_like(plabels)).to(torch.uint8)
    if int((cen.weights > 0).sum()) < 3:
        empty.labels, empty.targets, empty.weights, empty.counts = (
            kept, cen.targets, cen.weights, cen.counts,
        )  # fmt: skip
        return empty

    # IK from several root orientations in one batch; the root starts at the pelvis centroid.
    rotvecs = start_orientations(cen.targets, cen.weights, ORIENTATION_STARTS)
    present = cen.weights > 0
    t0 = torch.nan_to_num(cen.targets)
    root = t0[_PELVIS] if bool(present[_PELVIS]) else t0[present].mean(0)
    arms = _arm_presets(ARM_STARTS, depth)  # (A, 34) joint angles only
    q0 = arms.repeat(rotvecs.shape[0], 1)
    q0[:, 0:3], q0[:, 3:6] = root, rotvecs.repeat_interleave(arms.shape[0], 0)
    if q_hint is not None:
        q0 = torch.cat([q0, q_hint.to(q0).reshape(1, sk.NUM_DOFS)], 0)
    q_ref = q0.clone()
    markers = part_markers(body)
    ik = fit_pose(
        cen.targets[None].expand(q0.shape[0], -1, -1), q0, body,
        cen.weights[None].expand(q0.shape[0], -1), markers, q_ref=q_ref, prior=IK_PRIOR,
        iterations=IK_ITERATIONS,
    )  # fmt: skip
    best = int(torch.argmin(ik.rms))
    q_ik = ik.q[best]
    q, refined = q_ik, None
    confirmed = refine is not None and confirm is not None and bool(confirm(q_ik))
    if refine is not None and not confirmed:
        # The forest confuses left and right limbs (about a fifth of forearm and shank pixels),
        # which IK turns into crossed legs or arms; refine the pose with each pair of limbs
        # swapped too and keep the one that explains the depth best. It also labels other
        # parts as a limb it cannot see (a forearm as the far shank in a side view), and the
        # IK bends that limb out to them; the same pose with one limb at rest is a start too.
        starts = limb_swaps(q_ik) + limb_resets(q_ik, cfg.reset_limbs)
        for res in refine(torch.stack(starts)):
            if refined is None or (res.depth_error_cm, -res.overlap) < (
                refined.depth_error_cm,
                -refined.overlap,
            ):
                refined = res
        q = refined.q.to(q_ik)
    joints = named_joint_positions(forward_kinematics(q[None], body))[0]
    return DetectionResult(
        True, q, q_ik, joints, cen.targets, cen.weights, cen.counts, float(ik.rms[best]),
        kept, n_lab, refined, confirmed,
    )  # fmt: skip


# Left/right DoF slots of each limb pair (right-side axes mirror the left ones, so equal
# angles are mirror motions and swapping the slots swaps the limbs).
_LEG_SLOTS = ([26, 27, 28, 32], [29, 30, 31, 33])
_ARM_SLOTS = ([14, 15, 18, 19, 20, 24], [16, 17, 21, 22, 23, 25])


def limb_swaps(q: torch.Tensor) -> list[torch.Tensor]:
    """``q`` (34,) and its variants with the legs, the arms, or both swapped left/right."""
    out = [q]
    for slots in (_LEG_SLOTS, _ARM_SLOTS, None):
        swapped = q.clone()
        for left, right in (_LEG_SLOTS, _ARM_SLOTS) if slots is None else (slots,):
            swapped[left], swapped[right] = q[right], q[left]
        out.append(swapped)
    return out


def limb_resets(q: torch.Tensor, which: str) -> list[torch.Tensor]:
    """``q`` (34,) with one limb at a time set back to its rest angles: each leg for
    ``which="legs"``, each leg and arm for ``"limbs"``, nothing for ``"none"``."""
    groups = {"none": (), "legs": _LEG_SLOTS, "limbs": _LEG_SLOTS + _ARM_SLOTS}[which]
    out = []
    for slots in groups:
        reset = q.clone()
        reset[slots] = 0.0
        out.append(reset)
    return out


class Detector:
    """The detector of one stream: settings, body and the RANSAC's random state (which runs on
    from frame to frame). Its refinement is the caller's tracker, passed per frame.

    Args:
        body: body model; intr: stream intrinsics; cfg: detector settings.
        device, dtype: where and in which float type to compute.
    """

    def __init__(
        self,
        body: BodyShape,
        intr: Intrinsics,
        cfg: DetectorConfig | None = None,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        self.cfg = cfg or DetectorConfig()
        self.intr = intr
        self.device = torch.device("cpu") if device is None else torch.device(device)
        self.dtype = dtype
        self.body = body.to(dtype=dtype, device=self.device)
        self.generator = torch.Generator().manual_seed(self.cfg.seed)

    def reset(self) -> None:
        """Restart the RANSAC's random sequence: after a reset the detector samples as a new
        one would, so a person's return is estimated the same however long the run was."""
        self.generator.manual_seed(self.cfg.seed)

    def detect(
        self,
        depth_m: torch.Tensor,
        labels: torch.Tensor | np.ndarray,
        mask: torch.Tensor | None = None,
        q_hint: torch.Tensor | None = None,
        refine: Refine | None = None,
        confirm: Confirm | None = None,
    ) -> DetectionResult:
        """:func:`detect_pose` on one frame with this detector's settings."""
        return detect_pose(
            depth_m.to(device=self.device, dtype=self.dtype),
            torch.as_tensor(labels).to(self.device),
            self.intr, self.body, self.cfg, q_hint,
            None if mask is None else torch.as_tensor(mask).to(self.device),
            refine, self.generator, confirm,
        )  # fmt: skip
