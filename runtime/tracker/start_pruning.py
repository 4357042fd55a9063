"""Early rejection of a batched refit's starts (issue 38: recovery that costs little).

The hybrid's recoveries refit one frame from K starts in one batched fit (the detector's
refinement: 8 starts of 3 Gauss-Newton iterations; the arm search: 8 of 5), and a batched fit
costs about 0.55 ms per start and iteration on the CPU, so these are the slowest frames.
Most starts are out of the running after an iteration or two: on the broad protocol's
recordings the detector's final pick (the smallest depth error after three iterations) was
among the 3 best by depth error after one iteration in 97% of 720 refinements, a few
hundredths of a centimetre off the pick on average when it was not
(``docs/experiments.md``, twenty-eighth session).

:class:`StartPruning` says when to cut and how many go on: after ``after`` iterations every
start has run, the ``keep`` starts whose rendering then fits best (the smallest
``depth_error_cm + overlap_weight_cm * (1 - overlap)``, the failure signals of that
iteration's rendering) go on alone. The kept starts' fits are those of the whole batch: each
start is fitted as it would be alone, and the cut only stops fitting the others. The arm
search's pick (the smallest badness after five iterations) is harder to foresee: among the 4
best by badness after two iterations in 88% of 163 searches (0.009 badness off the pick on
average).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from depthmocap.runtime.raycast import BodyRender
from depthmocap.shared.body import BodyShape

from .depth_term import depth_error_sum
from .extra_depth_term import ExtraResult, ObservedCandidates
from .observation import Observation
from .regions import Regions
from .signals import MAX_SURFACE_POINTS, overlap, surface_error_quantile

__all__ = ["StartPruning", "pruning_scores", "starts_to_keep", "subset_candidates",
           "subset_observation"]  # fmt: skip


@dataclass(frozen=True)
class StartPruning:
    """When a batched refit stops fitting its worse starts.

    Attributes:
        after: Gauss-Newton iterations every start runs before the cut (>= 1: the cut reads
            the rendering of the poses these iterations reached).
        keep: starts that go on after it (>= 1).
        overlap_weight_cm: the score's weight of ``1 - overlap`` in centimetres of depth error
            (0: the depth error alone, as the detector picks its refinement).
        surface_weight: the score's weight of the surface error's 97% quantile, cm of depth
            error per mm (0: not computed). With ``epsilon1 / (1 - epsilon2)`` and
            ``epsilon1 / epsilon3`` the score is the hybrid's badness times ``epsilon1``.
    """

    after: int
    keep: int
    overlap_weight_cm: float = 0.0
    surface_weight: float = 0.0

    def __post_init__(self) -> None:
        weights = (self.overlap_weight_cm, self.surface_weight)
        if self.after < 1 or self.keep < 1 or not all(w >= 0.0 for w in weights):
            raise ValueError(f"StartPruning needs after >= 1, keep >= 1, weights >= 0: {self}")


def pruning_scores(
    render: BodyRender,
    obs: Observation,
    regions: Regions,
    extra: ExtraResult,
    body: BodyShape,
    depth_gate_m: float,
    prune: StartPruning,
) -> torch.Tensor:
    """(B,) float64 score of each pose of one iteration's rendering (lower is better): its
    depth error in cm (the ``depth_error_cm`` failure signal), plus ``overlap_weight_cm``
    times one minus its silhouette overlap, plus ``surface_weight`` times its surface error
    (mm), as :func:`~runtime.tracker.signals.frame_signals` computes them."""
    err, n = depth_error_sum(regions)
    total = err.double() + extra.error_sum.double()
    count = n.double() + extra.count.double()
    gate = torch.full_like(total, depth_gate_m)
    score = torch.where(count > 0, total / count.clamp_min(1e-9), gate) * 100.0
    score = score + prune.overlap_weight_cm * (1.0 - overlap(render.mask, obs.silhouette))
    if prune.surface_weight > 0.0:
        surface = surface_error_quantile(obs, render, body, MAX_SURFACE_POINTS)
        score = score + prune.surface_weight * surface
    return score


def starts_to_keep(scores: torch.Tensor, keep: int) -> torch.Tensor:
    """Indices (k,) of the ``keep`` lowest of ``scores`` (B,), in increasing index order
    (ties to the lower index; NaN scores last)."""
    finite = torch.nan_to_num(scores, nan=float("inf"))
    order = torch.argsort(finite, stable=True)[:keep]
    return order.sort().values


def subset_observation(obs: Observation, idx: torch.Tensor) -> Observation:
    """The views ``idx`` (k,) of a batched observation; the views of one frame's batch
    (:func:`~runtime.tracker.tracker.expand_observation`) stay views without copies."""
    out = {}
    for f in fields(obs):
        v = getattr(obs, f.name)
        if f.name == "intr" or v is None:
            out[f.name] = v
        elif v.stride(0) == 0:
            out[f.name] = v[:1].expand(idx.shape[0], *v.shape[1:])
        else:
            out[f.name] = v[idx]
    return Observation(**out)


def subset_candidates(cands: ObservedCandidates, idx: torch.Tensor) -> ObservedCandidates:
    """The candidates of the poses ``idx`` (k,), renumbered 0..k-1 in that order (the
    candidates stay in their order: by pose, then by height)."""
    B = int(cands.batch.max()) + 1 if cands.batch.numel() else 0
    new = torch.full((max(B, int(idx.max()) + 1),), -1, dtype=torch.long, device=idx.device)
    new[idx] = torch.arange(idx.shape[0], device=idx.device)
    batch = new[cands.batch] if cands.batch.numel() else cands.batch
    keep = batch >= 0
    return ObservedCandidates(batch[keep], cands.points[keep])
