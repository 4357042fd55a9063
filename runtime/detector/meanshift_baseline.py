"""Baseline: Shotton et al. 2011 joint proposals from the same forest (mode "shotton").

Shotton estimates each joint as the strongest mode of a weighted Gaussian density over the
back-projected pixels,

    f_j(x) ~ sum_i w_ij exp(-||(x - x_i) / b||^2),   w_ij = P(j | pixel i) * z_i^2,

found by mean shift from the pixels whose score is above a threshold; the z^2 factor makes
the weights proportional to the surface area each pixel sees. The mode lies on the visible
surface, so it is pushed back along its viewing ray by an offset (Shotton learns zeta_c per part;
here it is ``z_offset`` times the segment radius, as for the detector's centroids).

Shotton's body parts are centred on joints; ours are skeleton segments (Wei), so each named
joint gets a score map from the parts:

- a joint between two parts (neck, spine, shoulders, elbows, hips, knees) scores the parts'
  boundary: the geometric mean of both parts' posteriors, each box-filtered over a small
  window, times the pixel's probability of being either part;
- head and pelvis are the modes of their part;
- wrists and ankles, at the free ends of their segments, come from the mode of the forearm
  (with hand) / lower shank part, extrapolated from the elbow / knee to the fraction of the
  segment the joint sits at (the mode marks the middle of the part's axial span).

A joint without any score mass falls back to its parent joint (e.g. an occluded wrist to the
elbow); no joint at all means the frame is lost.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics, depth_to_points
from depthmocap.shared.labels import NUM_CLASSES, PART_NAMES
from depthmocap.shared.skeleton import JOINT_NAMES, JOINT_SEGMENT

from .centroids import part_markers
from .config import MeanShiftConfig

__all__ = [
    "JointProposals",
    "joint_score_maps",
    "propose_joints",
    "ShottonEstimator",
    "create_estimator",
]

_P = {n: i for i, n in enumerate(PART_NAMES)}
# Named joint -> ("part", p) mode of one part; ("pair", a, b) boundary of two parts;
# ("end", p, base_joint) free end extrapolated from a base joint through the part's mode.
_RULES: dict[str, tuple] = {
    "head": ("part", _P["head"]),
    "neck": ("pair", _P["neck"], _P["chest"]),
    "spine": ("pair", _P["abdomen"], _P["chest"]),
    "pelvis": ("part", _P["pelvis"]),
}
for _s in ("l", "r"):
    _RULES.update(
        {
            f"{_s}_shoulder": ("pair", _P[f"{_s}_clavicle"], _P[f"{_s}_upper_arm"]),
            f"{_s}_elbow": ("pair", _P[f"{_s}_upper_arm"], _P[f"{_s}_forearm"]),
            f"{_s}_wrist": ("end", _P[f"{_s}_forearm"], f"{_s}_elbow"),
            f"{_s}_hip": ("pair", _P["pelvis"], _P[f"{_s}_thigh_upper"]),
            f"{_s}_knee": ("pair", _P[f"{_s}_thigh_lower"], _P[f"{_s}_shank_upper"]),
            f"{_s}_ankle": ("end", _P[f"{_s}_shank_lower"], f"{_s}_knee"),
        }
    )
_PARENT = {
    "head": "neck", "neck": "spine", "spine": "pelvis", "pelvis": "pelvis",
    **{f"{s}_{j}": f"{s}_{p}" for s in "lr" for j, p in (
        ("elbow", "shoulder"), ("wrist", "elbow"), ("knee", "hip"), ("ankle", "knee"))},
    **{f"{s}_shoulder": "neck" for s in "lr"},
    **{f"{s}_hip": "pelvis" for s in "lr"},
}  # fmt: skip


def _posteriors(x: torch.Tensor) -> torch.Tensor:
    """(C, H, W) posteriors from posteriors (C, H, W) / (H, W, C) or int labels (one-hot)."""
    if x.dim() == 2:
        return F.one_hot(x.long().clamp(0, NUM_CLASSES - 1), NUM_CLASSES).permute(2, 0, 1).float()
    if x.dim() == 3 and x.shape[0] == NUM_CLASSES:
        return x.float()
    if x.dim() == 3 and x.shape[-1] == NUM_CLASSES:
        return x.permute(2, 0, 1).float()
    raise ValueError(f"expected labels (H, W) or posteriors ({NUM_CLASSES}, H, W), got {x.shape}")


def joint_score_maps(post: torch.Tensor, window: int) -> torch.Tensor:
    """Per named joint score of each pixel (module docstring): (C, H, W) -> (J, H, W)."""
    k = max(1, window | 1)
    smooth = F.avg_pool2d(post[None], k, 1, k // 2, count_include_pad=False)[0]
    maps = []
    for name in JOINT_NAMES:
        rule = _RULES[name]
        if rule[0] == "pair":
            a, b = rule[1], rule[2]
            maps.append(torch.sqrt(smooth[a] * smooth[b]) * (post[a] + post[b]))
        else:
            maps.append(post[rule[1]])
    return torch.stack(maps)


@dataclass
class JointProposals:
    """Joint positions (J = 16 named joints).

    Attributes:
        joints: (16, 3) camera metres; missing joints filled from their parent joint.
        found: (16,) bool, the joint had its own mode.
        strength: (16,) density mass at the chosen mode.
    """

    joints: torch.Tensor
    found: torch.Tensor
    strength: torch.Tensor


def _mean_shift(points, weights, seeds, bandwidth, iterations):
    """Modes from seeds (J, S, 3) over points (N, 3) with weights (J, N)."""
    inv = 1.0 / (bandwidth * bandwidth)
    p2 = (points * points).sum(-1)

    def kernel(x):  # (J, S, N); squared distances by expansion (no (J, S, N, 3) temporary)
        d2 = (x * x).sum(-1, keepdim=True) + p2 - 2.0 * x @ points.T
        return torch.exp(-d2.clamp_min(0.0) * inv) * weights[:, None, :]

    x = seeds
    for _ in range(iterations):
        k = kernel(x)
        x = (k @ points) / k.sum(-1, keepdim=True).clamp_min(1e-12)
    return x, kernel(x).sum(-1)


def propose_joints(
    depth_m: torch.Tensor,
    posteriors: torch.Tensor,
    intr: Intrinsics,
    body: BodyShape,
    cfg: MeanShiftConfig | None = None,
    mask: torch.Tensor | None = None,
    generator: torch.Generator | None = None,
) -> JointProposals:
    """Shotton joint proposals for one frame (module docstring).

    Args:
        depth_m: (H, W) metres; posteriors: (C, H, W) / (H, W, C) or (H, W) int labels.
        intr: intrinsics; body: for the surface offsets and the free-end fractions.
        mask: (H, W) bool person mask (optional).
    """
    cfg = cfg or MeanShiftConfig()
    dev = depth_m.device
    dt = depth_m.dtype if depth_m.is_floating_point() else torch.float32
    depth = depth_m.to(dt)
    post = _posteriors(torch.as_tensor(posteriors).to(dev)).to(dt)
    body_px = post[1:].sum(0) > 0
    if mask is not None:
        body_px = body_px & mask.to(device=dev, dtype=torch.bool)
    body_px = body_px & torch.isfinite(depth) & (depth > 0)
    J = len(JOINT_NAMES)
    # Work inside the person's bounding box (plus the filter window): the rest scores zero.
    rows, cols = body_px.any(1).nonzero()[:, 0], body_px.any(0).nonzero()[:, 0]
    pad = cfg.boundary_window_px
    if rows.numel() == 0:
        nan = depth.new_full((J, 3), float("nan"))
        return JointProposals(nan, torch.zeros(J, dtype=torch.bool), depth.new_zeros(J))
    r0, r1 = max(int(rows[0]) - pad, 0), int(rows[-1]) + pad + 1
    c0, c1 = max(int(cols[0]) - pad, 0), int(cols[-1]) + pad + 1
    scores = joint_score_maps(post[:, r0:r1, c0:c1], cfg.boundary_window_px)  # (J, h, w)
    use = body_px[r0:r1, c0:c1] & (scores.amax(0) > 0)
    pix = use.nonzero(as_tuple=True)
    n = pix[0].shape[0]
    if n == 0:
        nan = depth.new_full((J, 3), float("nan"))
        return JointProposals(nan, torch.zeros(J, dtype=torch.bool), depth.new_zeros(J))
    if n > cfg.max_points:
        gen = generator or torch.Generator().manual_seed(0)
        keep = torch.randperm(n, generator=gen)[: cfg.max_points].to(dev)
        pix = (pix[0][keep], pix[1][keep])
    score = scores[:, pix[0], pix[1]]  # (J, N)
    pix = (pix[0] + r0, pix[1] + c0)
    pts = depth_to_points(depth[None], intr)[0][pix]  # (N, 3)
    weights = score * pts[:, 2] ** 2
    S = min(cfg.max_seeds, pts.shape[0])
    top, seed_idx = score.topk(S, dim=1)
    seeds = pts[seed_idx]  # (J, S, 3)
    modes, strength = _mean_shift(pts, weights, seeds, cfg.bandwidth_m, cfg.iterations)
    strength = torch.where(top > cfg.probability_threshold, strength, torch.zeros_like(strength))
    best = strength.argmax(1)
    ar = torch.arange(J, device=dev)
    mode, mass = modes[ar, best], strength[ar, best]
    found = mass > cfg.min_weight

    # Push back behind the surface by a fraction of the joint's segment radius.
    b = body.to(dtype=dt, device=dev)
    seg = torch.as_tensor(JOINT_SEGMENT, device=dev)
    radius = torch.sqrt(b.radii[seg, 0] * b.radii[seg, 1])
    ray = mode / mode.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    joints = mode + cfg.z_offset * radius[:, None] * ray

    # Free ends (wrists, ankles): base + (mode - base) / fraction of the part's mode.
    markers = part_markers(b)
    idx = {n: i for i, n in enumerate(JOINT_NAMES)}
    out = [None] * J
    for name in JOINT_NAMES:
        i, rule = idx[name], _RULES[name]
        if rule[0] == "end":
            base = idx[rule[2]]
            frac = markers.fraction[rule[1] - 1]
            ext = joints[base] + (joints[i] - joints[base]) / frac
            ok = found[i] & found[base]
            out[i] = torch.where(ok, ext, joints[i])
            found[i] = ok
        else:
            out[i] = joints[i]
    joints = torch.stack(out)
    if bool(found.any()):
        fallback = joints[found].mean(0)
        order = ("pelvis", "spine", "neck", "head") + tuple(
            f"{s}_{j}" for j in ("shoulder", "hip", "elbow", "knee", "wrist", "ankle") for s in "lr"
        )
        filled = found.clone()
        for name in order:  # parents come first, so fills propagate down the chains
            i, p = idx[name], idx[_PARENT[name]]
            if not bool(filled[i]):
                joints[i] = joints[p] if bool(filled[p]) else fallback
                filled[i] = True
    return JointProposals(joints, found, mass)


class ShottonEstimator:
    """Mode "shotton": joint proposals every frame, no pose q (status "detected" / "lost")."""

    def __init__(self, labeler, body: BodyShape, intr: Intrinsics, cfg: MeanShiftConfig,
                 device="cpu") -> None:  # fmt: skip
        self.labeler, self.body, self.intr, self.cfg = labeler, body, intr, cfg
        self.device = torch.device(device)

    def reset(self) -> None:
        """Nothing to forget."""

    def estimate(self, frame):
        from depthmocap.runtime.estimator import PoseEstimate, lost

        depth, m = frame.depth_m, frame.mask
        post = self.labeler(depth, m)
        prop = propose_joints(depth, post, self.intr, self.body, self.cfg, m)
        if not bool(prop.found.any()):
            return lost()
        labels = torch.as_tensor(post).argmax(0) if post.dim() == 3 else post
        return PoseEstimate(
            None,
            prop.joints.detach().cpu().double().numpy(),
            "detected",
            {"joints_found": float(prop.found.sum())},
            labels.cpu().numpy().astype(np.uint8),
        )


def create_estimator(
    *,
    model_path: Path | None,
    body: BodyShape,
    intrinsics: Intrinsics,
    device: str = "cpu",
    config: Mapping[str, Any] | MeanShiftConfig | None = None,
) -> ShottonEstimator:
    """Mode "shotton" for ``make_estimator`` (``config``: MeanShiftConfig keys)."""
    from depthmocap.shared.config import as_config

    from . import DetectorError, load_forest_labeler

    cfg = as_config(MeanShiftConfig, config, "shotton config", DetectorError)
    labeler = load_forest_labeler(model_path, device, intrinsics, posteriors=True)
    return ShottonEstimator(labeler, body, intrinsics, cfg, device)
