"""The hidden-arm search: refit a suspect frame from a few arm poses, keep the best fit.

In profile the tracker can slip the far arm behind the torso while the camera sees it, or lay
a lost arm on a leg or the torso; either fits the depth well enough to pass the failure tests.
The model's rendering says which arm it hides (``TrackResult.limb_visibility``) and the
forest's labels say whether the camera sees that arm anyway
(:mod:`runtime.hybrid.arm_labels`). When both hold on a suspect fit, :class:`ArmSearch`
refits the frame from each start of :func:`~runtime.hybrid.arm_labels.arm_candidates` and
keeps the refit with the smallest badness, if it beats the track's and keeps the forest's
pixels of that arm near it.

The search remembers, per arm, the frame of its last fruitless misplaced-arm search (the
cooldown); nothing else carries over between frames.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from depthmocap.runtime.frame import Frame
from depthmocap.runtime.raycast import segment_distances, segment_geometry
from depthmocap.runtime.tracker.signals import FitSignals
from depthmocap.runtime.tracker.tracker import TrackResult
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import masked_points
from depthmocap.shared.kinematics import Kinematics, forward_kinematics

from .arm_labels import (
    AGREEMENT_MARGIN_M,
    CONFLICT_MARGIN_M,
    agreement_from_distances,
    arm_candidates,
    arm_label_agreement,
    arm_label_conflict,
    arm_pixel_fraction,
    arm_pixels,
    label_conflict_from_distances,
    near_other_arm_from_distances,
)
from .config import ArmSearchConfig

__all__ = [
    "HIDDEN_VISIBILITY",
    "MISPLACED_MIN_POINTS",
    "OTHER_ARM_COUNTS",
    "PARTIAL_AGREEMENT",
    "PARTIAL_VISIBILITY",
    "SEEN_FRACTION",
    "ArmSearch",
    "SearchResult",
]

# When an arm is suspect (module docstring). Read at call time, so tests can vary them.
# The model hides an arm it shows less than this fraction of (TrackResult.limb_visibility) ...
HIDDEN_VISIBILITY = 0.3
# ... and shows it partly below this fraction: a partly shown arm is searched too when under
# PARTIAL_AGREEMENT of the forest's pixels of it lie within 5 cm of the model's arm (jog: a
# far forearm folded back while the camera sees it reach forward).
PARTIAL_VISIBILITY = 0.6
PARTIAL_AGREEMENT = 0.5
# The camera sees an arm when the forest labels it on this share of the person's pixels.
SEEN_FRACTION = 0.02
# A shown arm counts as misplaced only when it explains at least this many of the person's
# points (fewer say too little about where it lies) ...
MISPLACED_MIN_POINTS = 20
# ... and points the forest labels as the other arm count against it (the forest swaps arms
# in profile, but a lost arm laid on the other one is misplaced all the same).
OTHER_ARM_COUNTS = True

# Start poses (K, 34) -> the tracker's refit of the frame from each, in order (one batched
# fit: ``Tracker.fit_starts``).
Refit = Callable[[torch.Tensor], list[TrackResult]]


@dataclass
class SearchResult:
    """The best refit (None if none beat the track) with its badness, and how many arms'
    refits were tried (what the search cost)."""

    best: TrackResult | None
    badness: float
    arms_searched: int


@dataclass
class _Suspect:
    """One arm to search and what its refits must respect."""

    side: str
    arm_points: torch.Tensor  # (N, 3) the forest's pixels of the arm not near the other arm
    agreement_floor: float | None  # a refit keeps at least this share of them near the arm
    conflicts: float | None  # the track's labelled-otherwise points (misplaced arms), or None
    points: torch.Tensor  # (M, 3) all the person's points, for the conflict of a refit
    point_labels: torch.Tensor  # (M,) their part labels


class ArmSearch:
    """The search of one stream (module docstring)."""

    def __init__(self, cfg: ArmSearchConfig, body: BodyShape) -> None:
        self.cfg, self.body = cfg, body
        self.geometry = segment_geometry(body, body.lengths)  # the capsules, made once
        self.misplaced_failed_at: dict[str, int] = {}
        self.failed_at: dict[str, int] = {}

    def with_body(self, body: BodyShape) -> ArmSearch:
        """The same search for ``body`` (the person's size found): the cooldowns carry over,
        as they are about the arms' recent searches, not the body's shape."""
        search = ArmSearch(self.cfg, body)
        search.misplaced_failed_at = dict(self.misplaced_failed_at)
        search.failed_at = dict(self.failed_at)
        return search

    def reset(self) -> None:
        """Forget the cooldowns (a new track)."""
        self.misplaced_failed_at = {}
        self.failed_at = {}

    def wanted(self, badness: float) -> bool:
        """Whether a fit this bad is suspect enough to search."""
        return badness > self.cfg.badness

    def _kinematics(self, q: torch.Tensor) -> Kinematics:
        return forward_kinematics(q[None].to(self.body.lengths), self.body)

    def search(
        self,
        frame: Frame,
        labels: torch.Tensor,
        track: TrackResult,
        badness: float,
        refit: Refit,
        badness_of: Callable[[FitSignals], float],
    ) -> SearchResult:
        """Search every suspect arm of ``track`` (whose badness is ``badness``) on ``frame``
        with its part ``labels`` (H, W); ``refit`` fits the frame from each of K start poses
        (one batched fit per arm)."""
        best, searched = None, 0
        for suspect in self._suspects(frame, labels, track):
            searched += 1
            found = None
            for r in refit(arm_candidates(track.q, suspect.side)):
                b = badness_of(r.signals)
                if b < badness and self._accepts(suspect, r.q):
                    found, badness = r, b
            if found is not None:
                best = found
                continue
            self.failed_at[suspect.side] = frame.index
            if suspect.conflicts is not None:
                self.misplaced_failed_at[suspect.side] = frame.index
        return SearchResult(best, badness, searched)

    def _suspects(self, frame: Frame, labels: torch.Tensor, track: TrackResult):
        """The arms to search, in order (left, right), lazily: most suspect frames have none."""
        cfg, vis = self.cfg, track.limb_visibility
        if vis is None:
            return
        mask = frame.mask
        misplaced = cfg.misplaced
        points = kin = signed = nearest = None
        for limb, side in ((0, "l"), (1, "r")):
            last = self.failed_at.get(side)
            if last is not None and frame.index - last <= cfg.cooldown_frames:
                continue
            shown = float(vis[limb])
            hidden = shown < max(HIDDEN_VISIBILITY, PARTIAL_VISIBILITY)
            if not (hidden or misplaced is not None):
                continue
            if points is None:
                points = masked_points(frame.depth_m, mask, frame.intrinsics)
                kin = self._kinematics(track.q)
                point_labels = labels[mask]
                # Every test below reads the points' distances to the model's parts: one
                # evaluation serves both arms.
                signed = segment_distances(
                    points[None].to(kin.origins), kin, self.body, self.geometry
                )
                nearest = signed.min(-1)
            conflicts = None
            last = self.misplaced_failed_at.get(side)
            if misplaced is not None and (
                last is None or frame.index - last > misplaced.cooldown_frames
            ):
                share, count = label_conflict_from_distances(
                    signed, point_labels, side, CONFLICT_MARGIN_M, OTHER_ARM_COUNTS, nearest
                )
                share, count = float(share[0]), int(count[0])
                if count >= MISPLACED_MIN_POINTS and share > misplaced.conflict:
                    conflicts = share * count
            if not hidden and conflicts is None:
                continue
            explained = torch.zeros_like(mask)
            if cfg.other_arm_margin_m > 0:
                explained[mask] = near_other_arm_from_distances(
                    signed[0], side, cfg.other_arm_margin_m
                )
            seen = arm_pixel_fraction(labels, mask, side, explained) >= SEEN_FRACTION
            if not seen and conflicts is None:
                continue
            chosen = (arm_pixels(labels, mask, side) & ~explained)[mask]
            arm_points = points[chosen]
            mine = float(agreement_from_distances(signed[:, chosen], side, AGREEMENT_MARGIN_M)[0])
            partly = shown >= HIDDEN_VISIBILITY
            if conflicts is None and partly and not mine < PARTIAL_AGREEMENT:
                continue  # shown partly, where the forest sees it: no search
            # No forest pixels of the arm (NaN agreement): nothing to keep the refit near.
            check = cfg.agreement_slack is not None and math.isfinite(mine)
            floor = mine - cfg.agreement_slack if check else None
            yield _Suspect(side, arm_points, floor, conflicts, points, point_labels)

    def _accepts(self, suspect: _Suspect, q: torch.Tensor) -> bool:
        """Whether a refit's pose ``q`` keeps the arm's labelled pixels near it and, for a
        misplaced arm, leaves enough fewer of its points labelled otherwise."""
        pose = self._kinematics(q)
        side = suspect.side
        if suspect.agreement_floor is not None:
            agree = arm_label_agreement(
                suspect.arm_points, pose, self.body, side, AGREEMENT_MARGIN_M, self.geometry
            )
            if not float(agree[0]) >= suspect.agreement_floor:
                return False
        if suspect.conflicts is None:
            return True
        share, count = arm_label_conflict(
            suspect.points, suspect.point_labels, pose, self.body, side, CONFLICT_MARGIN_M,
            OTHER_ARM_COUNTS, self.geometry,
        )  # fmt: skip
        theirs = float(share[0]) * int(count[0]) if int(count[0]) else 0.0
        return theirs <= self.cfg.misplaced.relief * suspect.conflicts
