"""Hybrid tracking and detection (Wei section 5): mode "hybrid" of ``runtime-track``.

The tracker reconstructs every frame from the two previous poses, except the first frame and
the frames where it fails; those are (re)initialized by the detector (forest labels -> RANSAC
-> centroids -> IK -> a few tracker iterations, :mod:`runtime.detector`). A tracked frame
fails when

- the mean depth / extra-depth residual exceeds ``epsilon1_cm`` (Wei: 2.5 cm), or
- the silhouette overlap |R and O| / |R or O| is below ``epsilon2`` (Wei: 90%), or
- (not in Wei, off by default) the 97% quantile of the observed points' distances to the
  model exceeds ``epsilon3_mm``: a limb left behind.

Statuses per frame: "tracked" (the tracker's pose passed the tests, or was kept over the
detector's), "detected" (the detector gave the pose: first frame, after a failure, after a lost
frame), "lost" (no person: empty mask, or too few labelled body pixels for the detector).
After a lost frame the estimator forgets its past, so the person is picked up by the detector
when they return.

Wei accepts the detector's pose as it is and re-initializes the tracker from it; so does this
estimator by default. With ``keep_better`` (the shipped preset) the tracker's pose stays when
the detector's does not explain the observed points better (smaller 97% surface error), or
when it turns the person round by more than ``max_turn_rad`` in one frame (a profile view fits
facing either way), unless that has gone on for ``max_turn_frames`` failed frames in a row.
``compare_all_tests`` makes "better" the smaller sum of all three failure signals (each in
units of its threshold, :func:`fit_badness`). A track that is wrong yet fits well enough to
pass (a hidden limb on the wrong side after a bad first detection) is questioned too when
``recheck_badness`` is set (the detector also runs on passed frames whose badness exceeds it)
or ``recheck_every`` (on every n-th passed frame). With ``arm_search_badness`` set, a suspect
fit whose model hides an arm the forest sees is refined from a few arm poses first, and the
best-fitting result is kept (:mod:`runtime.hidden_arm_search`); with ``misplaced_arm_conflict``
set, so is an arm the model shows on pixels the forest labels as something else.

``labels_from_recording`` replaces the forest's part labels by a synthetic recording's own
(ground truth) everywhere the hybrid uses labels: a diagnostic of what the forest's label
errors cost, not a way to run on real data.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from runtime.detector import (
    DetectionResult,
    Detector,
    DetectorConfig,
    Labeler,
    depth_frame_to_metres,
    labels_from,
    load_forest_labeler,
)
from runtime.estimator import PoseEstimate, lost, observed_of
from runtime.hidden_arm_search import (
    AGREEMENT_MARGIN_M,
    CONFLICT_MARGIN_M,
    arm_candidates,
    arm_label_agreement,
    arm_label_conflict,
    arm_pixel_fraction,
    arm_pixels,
    label_conflict_from_distances,
    near_other_arm,
)
from runtime.raycast import segment_distances
from shared.body import BodyShape
from shared.camera import Intrinsics, depth_to_points
from shared.config import ConfigError, config_from_dict, field_doc
from shared.kinematics import forward_kinematics, named_joint_positions
from shared.so3 import rotvec_to_matrix

__all__ = [
    "HybridConfig",
    "HybridError",
    "HybridEstimator",
    "root_turn",
    "tracking_failed",
    "create_estimator",
    "fit_badness",
]


class HybridError(ValueError):
    """Bad settings or inputs of the hybrid estimator."""


def _tracker_config_type():
    from runtime.tracker import TrackerConfig

    return TrackerConfig


@dataclass
class HybridConfig:
    """Switching thresholds of Wei section 5 and the settings of both estimators."""

    epsilon1_cm: float = field_doc(
        2.5, help="tracking fails above this mean depth / extra-depth error, cm (Wei: 2.5)"
    )
    epsilon2: float = field_doc(
        0.9, help="tracking fails below this silhouette overlap |R and O| / |R or O| (Wei: 0.9)"
    )
    epsilon3_mm: float = field_doc(
        float("inf"),
        help="tracking also fails when the 97% quantile of observed points' distances to the "
        "model exceeds this, mm: a limb left behind leaves observed points far from the model "
        "while the mean residual and the overlap hardly move (not in Wei; inf: off)",
    )
    keep_better: bool = field_doc(
        False,
        help="after a failure, keep the tracker's pose when the detector's refined pose has no "
        "smaller 97% surface error (not in Wei: his switch always takes the detector's)",
    )
    compare_all_tests: bool = field_doc(
        False,
        "with keep_better, compare the two poses by the sum of their three failure signals, "
        "each divided by its threshold (depth error / epsilon1, (1 - overlap) / (1 - "
        "epsilon2), surface error / epsilon3) instead of the surface error alone: a detector "
        "pose that explains the far points slightly better but leaves more of the silhouette "
        "unexplained is not taken",
    )
    max_turn_rad: float = field_doc(
        float("inf"),
        help="with keep_better, a detector pose whose root turns more than this from the last "
        "pose is not taken (rad): a person does not turn round in one frame, but a profile "
        "view fits facing either way (inf: off)",
    )
    max_turn_frames: int = field_doc(
        15,
        help="... unless the tracker has failed and the detector turned it round this many "
        "frames in a row: then the track itself is taken to face the wrong way",
    )
    recheck_every: int = field_doc(
        0,
        "with keep_better, also run the detector on every this-many-th frame the tracker "
        "passed, and take its pose when it is better by the same rule: a wrong track whose "
        "fit is good enough to pass the tests (a hidden limb on the wrong side, a bad start) "
        "is otherwise never questioned (not in Wei; 0: off)",
    )
    recheck_badness: float = field_doc(
        float("inf"),
        help="with keep_better, also run the detector on a frame the tracker passed when the "
        "tracker's fit_badness (its three signals over their thresholds, summed; 3 = on all "
        "three thresholds) exceeds this: a suspect fit is questioned before it fails (inf: off)",
    )
    arm_search_badness: float = field_doc(
        float("inf"),
        help="when the tracker's fit_badness exceeds this and its model hides an arm "
        "(visible fraction below hidden_arm_visibility) that the forest labels on at least "
        "seen_arm_fraction of the person's pixels, refine the frame from each start pose of "
        "runtime.hidden_arm_search and keep the best fit (not in Wei; inf: off)",
    )
    hidden_arm_visibility: float = field_doc(
        0.3, help="an arm counts as hidden by the model below this visible fraction (0-1)"
    )
    seen_arm_fraction: float = field_doc(
        0.02, help="the camera counts as seeing an arm from this share of the person's pixels"
    )
    other_arm_margin_m: float = field_doc(
        0.05,
        help="forest arm pixels within this distance (m) of the model's other arm do not count "
        "towards seen_arm_fraction: in profile the far arm's labels land on the near arm, and "
        "the search would put both arms on it (0: every labelled pixel counts)",
    )
    partial_arm_visibility: float = field_doc(
        0.6,
        help="an arm the model shows partly (visible fraction below this, at or above "
        "hidden_arm_visibility) is searched too when the forest's pixels of it mostly lie off "
        "the model's arm (agreement below partial_arm_agreement): such an arm can be as wrong "
        "as a hidden one (jog: a far forearm folded back while the camera sees it reach "
        "forward)",
    )
    partial_arm_agreement: float = field_doc(
        0.5,
        help="the share of the forest's pixels of a partly shown arm (those not near the other "
        "arm) within 5 cm of the model's arm under which that arm is searched",
    )
    arm_agreement_slack: float = field_doc(
        0.1,
        help="an arm search's refit is taken only if the share of the forest's pixels of that "
        "arm (those not near the other arm) lying within 5 cm of the refit's arm is at least "
        "the track's share minus this: the signals hardly tell a hidden arm's places apart, "
        "and a refit that fits as well may have moved the arm away from its labels (inf: off)",
    )
    misplaced_arm_conflict: float = field_doc(
        float("inf"),
        help="with arm_search_badness, an arm the model shows is searched too when the forest "
        "labels more than this share of the person's points it explains (nearest to it, "
        "within 3 cm) as something else: a lost arm laid on a leg or the torso fits the depth "
        "data and passes every test (runtime.hidden_arm_search.arm_label_conflict; inf: off)",
    )
    misplaced_arm_points: int = field_doc(
        20, help="... and it explains at least this many of the person's points"
    )
    misplaced_arm_other_arm: bool = field_doc(
        True,
        help="points the forest labels as the other arm count as something else for "
        "misplaced_arm_conflict; false: only torso, head and leg labels do (the forest swaps "
        "left and right arms in profile, so such labels say little about where the arm is)",
    )
    misplaced_arm_cooldown: int = field_doc(
        0,
        help="after a misplaced arm's search finds no refit to take, that arm is not searched "
        "as misplaced again for this many frames: a wrong arm stays wrong for a while, and "
        "each search costs 8 tracker steps (0: search on every suspect frame)",
    )
    misplaced_arm_relief: float = field_doc(
        0.5,
        help="a misplaced arm's refit is taken only if the number of its points the forest "
        "labels as something else is at most this fraction of the track's (0-1)",
    )
    labels_from_recording: str = field_doc(
        "",
        help="directory of a synthetic recording (shared.recording) whose ground-truth part "
        "labels (labels/) stand in for the forest's, frame by frame, in the detector, the "
        "label term and the arm search: what the forest's label errors cost (diagnostics; the "
        "forest is then not loaded). Empty: the forest",
    )
    hint_from_tracker: bool = field_doc(
        True,
        help="give the detector's IK the last pose as one more start (it is used only if it "
        "fits the class centroids best)",
    )
    detector: DetectorConfig = field_doc(help="detector settings", default_factory=DetectorConfig)
    tracker: dict = field_doc(
        {}, help="tracker settings (runtime.tracker.TrackerConfig keys); defaults when empty"
    )

    def __post_init__(self) -> None:
        # fit_badness divides by the thresholds; a NaN would silently switch tests off.
        if not (self.epsilon1_cm > 0 and 0 <= self.epsilon2 < 1 and self.epsilon3_mm > 0):
            raise HybridError(
                "hybrid thresholds need epsilon1_cm > 0, 0 <= epsilon2 < 1 and epsilon3_mm > 0 "
                f"(inf: off), got {self.epsilon1_cm}, {self.epsilon2}, {self.epsilon3_mm}"
            )
        if self.recheck_every < 0 or math.isnan(self.recheck_badness):
            raise HybridError(
                f"recheck_every must be >= 0 (0: off) and recheck_badness a number (inf: off), "
                f"got {self.recheck_every}, {self.recheck_badness}"
            )
        if math.isnan(self.arm_search_badness) or not (
            0 <= self.hidden_arm_visibility
            and 0 <= self.seen_arm_fraction <= 1
            and self.other_arm_margin_m >= 0
            and self.arm_agreement_slack >= 0
            and 0 <= self.partial_arm_visibility
            and 0 <= self.partial_arm_agreement <= 1
            and not math.isnan(self.misplaced_arm_conflict)
            and self.misplaced_arm_points >= 1
            and self.misplaced_arm_cooldown >= 0
            and 0 <= self.misplaced_arm_relief <= 1
        ):
            raise HybridError(
                "arm_search_badness must be a number (inf: off), hidden_arm_visibility >= 0, "
                "0 <= seen_arm_fraction <= 1, other_arm_margin_m >= 0, arm_agreement_slack "
                ">= 0, partial_arm_visibility >= 0, 0 <= partial_arm_agreement <= 1, "
                "misplaced_arm_conflict a number (inf: off), misplaced_arm_points >= 1, "
                "misplaced_arm_cooldown >= 0 and 0 <= misplaced_arm_relief <= 1, got "
                f"{self.arm_search_badness}, "
                f"{self.hidden_arm_visibility}, {self.seen_arm_fraction}, "
                f"{self.other_arm_margin_m}, {self.arm_agreement_slack}, "
                f"{self.partial_arm_visibility}, {self.partial_arm_agreement}, "
                f"{self.misplaced_arm_conflict}, {self.misplaced_arm_points}, "
                f"{self.misplaced_arm_cooldown}, {self.misplaced_arm_relief}"
            )

    def tracker_config(self):
        """The tracker's settings as a ``TrackerConfig``."""
        cls = _tracker_config_type()
        try:
            return config_from_dict(cls, dict(self.tracker), "hybrid tracker config")
        except ConfigError as err:
            raise HybridError(str(err)) from None


def _signals(res) -> dict[str, float]:
    """A tracker result's three failure signals, as reported per frame."""
    return {
        "depth_error_cm": float(res.depth_error_cm),
        "overlap": float(res.overlap),
        "surface_error_q97_mm": float(res.surface_error_q97_mm),
    }


def root_turn(q_a: torch.Tensor, q_b: torch.Tensor) -> float:
    """Angle (rad) of the rotation between the root orientations of two (34,) poses."""
    r = rotvec_to_matrix(q_a[3:6]) @ rotvec_to_matrix(q_b[3:6]).T
    return float(torch.arccos(((torch.diagonal(r).sum() - 1.0) / 2.0).clamp(-1.0, 1.0)))


def tracking_failed(
    depth_error_cm: float, overlap: float, cfg: HybridConfig, surface_error_q97_mm: float = 0.0
) -> bool:
    """Wei's two failure tests on a tracked frame, plus the optional surface error test."""
    return not (
        depth_error_cm <= cfg.epsilon1_cm
        and overlap >= cfg.epsilon2
        and surface_error_q97_mm <= cfg.epsilon3_mm
    )


def fit_badness(
    depth_error_cm: float, overlap: float, surface_q97_mm: float, cfg: HybridConfig
) -> float:
    """Sum of a pose's failure signals in units of their thresholds (0: perfect fit; a pose
    that sits on all three thresholds scores 3). The surface term drops out when epsilon3 is
    off (infinite)."""
    score = depth_error_cm / cfg.epsilon1_cm + (1.0 - overlap) / max(1.0 - cfg.epsilon2, 1e-6)
    if math.isfinite(cfg.epsilon3_mm):
        score += surface_q97_mm / cfg.epsilon3_mm
    return score


class HybridEstimator:
    """Tracker with detector (re)initialization for one stream (implements PoseEstimator).

    Args:
        labeler: per-pixel part labels of a frame (the forest).
        detector: the pose detector (with its refining tracker).
        tracker: the frame-to-frame tracker (``Tracker.step`` API).
        cfg: thresholds.
    """

    def __init__(
        self,
        labeler: Labeler | None,
        detector: Detector,
        tracker,
        cfg: HybridConfig,
        frame_labels: Callable[[int], torch.Tensor] | None = None,
    ) -> None:
        if labeler is None and frame_labels is None:
            raise HybridError("the hybrid needs a labeler (the forest) or frame_labels")
        self.labeler, self.detector, self.tracker, self.cfg = labeler, detector, tracker, cfg
        self.frame_labels = frame_labels
        self._frame_index = 0
        self.device = detector.device
        # The tracker's label term needs the forest on every frame, not only the detector's.
        self.labels_every_frame = bool(getattr(getattr(tracker, "cfg", None), "use_labels", False))
        self._frame_labels: torch.Tensor | None = None
        self.reset()

    def reset(self) -> None:
        """Forget the previous poses: the next frame goes to the detector."""
        self.q_prev: torch.Tensor | None = None
        self.q_prev2: torch.Tensor | None = None
        self.turned_round = 0  # consecutive failed frames whose detection turned round
        self.passed = 0  # frames tracked since the last detector run
        # Frame index of each arm's last misplaced-arm search that found nothing to take.
        self.misplaced_failed_at: dict[str, int] = {}

    def _joints(self, q: torch.Tensor) -> np.ndarray:
        kin = forward_kinematics(q[None].to(self.detector.body.lengths), self.detector.body)
        return named_joint_positions(kin)[0].detach().cpu().double().numpy()

    def _tracked(self, res, errors: dict) -> PoseEstimate:
        """The estimate of a frame the tracker's fit ``res`` (a ``TrackResult``) keeps."""
        q = res.q.detach()
        self.q_prev, self.q_prev2 = q, self.q_prev
        return PoseEstimate(
            q.cpu().double().numpy(), self._joints(q), "tracked", errors, observed=observed_of(res)
        )

    def _labels(self, depth: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """This frame's part labels (H, W): the forest's, or with ``frame_labels`` the
        recording's own (zero off ``mask``); computed once per frame."""
        if self._frame_labels is None:
            if self.frame_labels is None:
                labels = labels_from(self.labeler(depth, mask))
            else:
                labels = self.frame_labels(self._frame_index)
                if labels.shape != mask.shape:
                    raise HybridError(
                        f"frame {self._frame_index}: labels {tuple(labels.shape)} do not match "
                        f"the frame {tuple(mask.shape)}"
                    )
                labels = labels.to(device=mask.device, dtype=torch.long) * mask
            self._frame_labels = labels.to(mask.device)
        return self._frame_labels

    def _detect(self, depth: torch.Tensor, mask: torch.Tensor, errors: dict) -> PoseEstimate:
        labels = self._labels(depth, mask)
        hint = self.q_prev if self.cfg.hint_from_tracker else None
        det: DetectionResult = self.detector.detect(depth, labels, mask, q_hint=hint)
        errors["labelled_pixels"] = float(det.labelled_pixels)
        if not det.found:
            self.reset()
            return lost(**errors)
        errors["ik_rms_m"] = det.ik_rms
        if det.refined is not None:
            errors.update(
                depth_error_cm=det.refined.depth_error_cm,
                overlap=det.refined.overlap,
                surface_error_q97_mm=det.refined.surface_error_q97_mm,
            )
        q = det.q.detach()
        self.q_prev, self.q_prev2 = q, None
        return PoseEstimate(
            q.cpu().double().numpy(),
            self._joints(q),
            "detected",
            errors,
            det.labels.cpu().numpy().astype(np.uint8),
            observed=observed_of(det.refined),
        )

    def _best_refit(self, depth, mask, starts, badness, accept=None):
        """The tracker's refit of the frame from each pose of ``starts`` (K, 34) with the
        smallest fit_badness, as (result, badness, index of its start), if below ``badness``
        and, given ``accept`` (a refit's pose -> bool), accepted; else None."""
        labels = self._labels(depth, mask) if self.labels_every_frame else None
        best = None
        for k, start in enumerate(starts):
            r = self.tracker.step(depth, mask, start, None, labels=labels)
            b = fit_badness(r.depth_error_cm, r.overlap, r.surface_error_q97_mm, self.cfg)
            if b < badness and (accept is None or accept(r.q)):
                best, badness = (r, b, k), b
        return best

    def _search_hidden_arms(self, depth, mask, res, badness):
        """The best refit from the arm starts of every arm the model hides (or shows partly
        and away from its forest pixels, or shows on pixels the forest calls something else)
        while the forest sees it, as (result, its badness, index of its start), if one fits
        better than ``res`` and keeps the forest's pixels of that arm near it, else None; and
        the number of arms whose refits were tried."""
        vis = res.limb_visibility
        if vis is None:
            return None, 0
        cfg = self.cfg
        best, searched = None, 0
        points = kin = None  # only needed once an arm is suspect: most suspect frames have none
        body = self.detector.body
        check_placement = math.isfinite(cfg.misplaced_arm_conflict)

        def pose_kinematics(q):
            return forward_kinematics(q[None].to(body.lengths), body)

        for limb, side in ((0, "l"), (1, "r")):
            shown = float(vis[limb])
            hidden = shown < max(cfg.hidden_arm_visibility, cfg.partial_arm_visibility)
            if not (hidden or check_placement):
                continue
            if points is None:
                points = depth_to_points(depth[None], self.detector.intr)[0][mask]
                kin = pose_kinematics(res.q)
                labels = self._labels(depth, mask)
                point_labels = labels[mask]
                if check_placement:  # both arms' conflicts from one distance evaluation
                    signed = segment_distances(points[None].to(kin.origins), kin, body)
            conflicts = None
            waited = self._frame_index - self.misplaced_failed_at.get(side, -(1 << 30))
            if check_placement and waited > cfg.misplaced_arm_cooldown:
                share, count = label_conflict_from_distances(
                    signed, point_labels, side, CONFLICT_MARGIN_M, cfg.misplaced_arm_other_arm
                )
                share, count = float(share[0]), int(count[0])
                if count >= cfg.misplaced_arm_points and share > cfg.misplaced_arm_conflict:
                    conflicts = share * count
            if not hidden and conflicts is None:
                continue
            explained = torch.zeros_like(mask)
            if cfg.other_arm_margin_m > 0:
                explained[mask] = near_other_arm(points, kin, body, side, cfg.other_arm_margin_m)
            seen = arm_pixel_fraction(labels, mask, side, explained) >= cfg.seen_arm_fraction
            if not seen and conflicts is None:
                continue
            arm_points = points[(arm_pixels(labels, mask, side) & ~explained)[mask]]
            mine = float(arm_label_agreement(arm_points, kin, body, side, AGREEMENT_MARGIN_M)[0])
            partly = shown >= cfg.hidden_arm_visibility
            if conflicts is None and partly and not mine < cfg.partial_arm_agreement:
                continue  # shown partly, where the forest sees it: no search

            # No forest pixels of the arm (seen_arm_fraction 0): nothing to keep it near.
            check = math.isfinite(cfg.arm_agreement_slack) and math.isfinite(mine)
            floor = mine - cfg.arm_agreement_slack if check else 0.0

            def accept(q, arm_points=arm_points, side=side, check=check, floor=floor,
                       conflicts=conflicts, points=points, point_labels=point_labels):  # fmt: skip
                pose = pose_kinematics(q)
                if check:
                    agree = arm_label_agreement(arm_points, pose, body, side, AGREEMENT_MARGIN_M)
                    if not float(agree[0]) >= floor:
                        return False
                if conflicts is None:
                    return True
                share, count = arm_label_conflict(
                    points,
                    point_labels,
                    pose,
                    body,
                    side,
                    CONFLICT_MARGIN_M,
                    cfg.misplaced_arm_other_arm,
                )
                theirs = float(share[0]) * int(count[0]) if int(count[0]) else 0.0
                return theirs <= cfg.misplaced_arm_relief * conflicts

            starts = arm_candidates(res.q, side)
            searched += 1
            found = self._best_refit(depth, mask, starts, badness, accept)
            if found is not None:
                best, badness = found, found[1]
            elif conflicts is not None:
                self.misplaced_failed_at[side] = self._frame_index
        return best, searched

    def estimate(self, frame, mask) -> PoseEstimate:
        """Pose of the person in ``frame`` (``frame.depth_mm``: (H, W) millimetres)."""
        self._frame_labels = None  # a new frame: its forest labels are not computed yet
        self._frame_index = frame.index
        depth = depth_frame_to_metres(frame.depth_mm, self.device)
        m = torch.as_tensor(np.asarray(mask) if not torch.is_tensor(mask) else mask)
        m = m.to(device=self.device, dtype=torch.bool)
        if m.shape != depth.shape:
            raise HybridError(f"mask {tuple(m.shape)} does not match depth {tuple(depth.shape)}")
        if not bool(m.any()):
            self.reset()
            return lost()
        errors: dict[str, float] = {}
        if self.q_prev is not None:
            labels = self._labels(depth, m) if self.labels_every_frame else None
            res = self.tracker.step(depth, m, self.q_prev, self.q_prev2, labels=labels)
            errors = _signals(res)
            self.passed += 1
            mine = fit_badness(res.depth_error_cm, res.overlap, res.surface_error_q97_mm, self.cfg)
            if mine > self.cfg.arm_search_badness:
                found, searched = self._search_hidden_arms(depth, m, res, mine)
                if found is not None:
                    res, mine, _ = found
                    errors = {**_signals(res), "arm_searched": 1.0}
                if searched:  # refits tried, taken or not: what the search costs
                    errors["arms_searched"] = float(searched)
            fail = tracking_failed(
                res.depth_error_cm, res.overlap, self.cfg, res.surface_error_q97_mm
            )
            recheck = self.cfg.keep_better and (
                0 < self.cfg.recheck_every <= self.passed or mine > self.cfg.recheck_badness
            )
            if not fail and not recheck:
                self.turned_round = 0
                return self._tracked(res, errors)
            self.passed = 0
            failed = {f"tracker_{k}": v for k, v in errors.items()}
            if self.cfg.keep_better:
                before = self.q_prev, self.q_prev2
                detected = self._detect(depth, m, failed)
                det = detected.errors
                worse = "surface_error_q97_mm" in det  # not refined: nothing to compare
                if worse and self.cfg.compare_all_tests:
                    theirs = fit_badness(
                        det["depth_error_cm"], det["overlap"], det["surface_error_q97_mm"], self.cfg
                    )
                    worse = theirs >= mine
                elif worse:
                    worse = det["surface_error_q97_mm"] >= res.surface_error_q97_mm
                if detected.q is not None and before[0] is not None:
                    turn = root_turn(torch.as_tensor(detected.q).to(before[0]), before[0])
                    turned = turn > self.cfg.max_turn_rad
                    # Only a track that keeps failing may be turned round; a recheck never.
                    self.turned_round = self.turned_round + 1 if turned and fail else 0
                    if self.turned_round < self.cfg.max_turn_frames:
                        worse = worse or turned
                if detected.status == "lost" or worse:
                    self.q_prev, self.q_prev2 = before
                    kept = {"kept_over_detector": 1.0} if fail else {"rechecked": 1.0}
                    return self._tracked(res, {**errors, **kept})
                return detected
            errors = failed
        return self._detect(depth, m, errors)


def create_estimator(
    *,
    model_path: Path | None,
    body: BodyShape,
    intrinsics: Intrinsics,
    device: str = "cpu",
    config: Mapping[str, Any] | HybridConfig | None = None,
) -> HybridEstimator:
    """Mode "hybrid" for ``runtime.estimator.make_estimator`` (``config``: HybridConfig keys)."""
    if config is None:
        cfg = HybridConfig()
    elif isinstance(config, HybridConfig):
        cfg = config
    else:
        try:
            cfg = config_from_dict(HybridConfig, dict(config), "hybrid config")
        except ConfigError as err:
            raise HybridError(str(err)) from None
    from runtime.tracker import Tracker

    tcfg = cfg.tracker_config()
    labeler = frame_labels = None
    if cfg.labels_from_recording:
        frame_labels = recording_labels(Path(cfg.labels_from_recording))
    else:
        labeler = load_forest_labeler(
            model_path,
            device,
            intrinsics,
            smooth_window=cfg.detector.label_smoothing_window,
            smooth_depth_gate_m=cfg.detector.label_smoothing_gate_m,
        )
    detector = Detector(body, intrinsics, cfg.detector, tcfg, device=device)
    tracker = Tracker(body, intrinsics, tcfg, device=device)
    return HybridEstimator(labeler, detector, tracker, cfg, frame_labels)


def recording_labels(path: Path) -> Callable[[int], torch.Tensor]:
    """The ground-truth part labels of the recording at ``path``, by frame index: (H, W)
    int64 part classes (``shared.labels``).

    Raises:
        HybridError: not a readable recording, no labels/, or (when called) a frame the
            recording does not have or cannot read.
    """
    from shared.recording import Recording

    try:
        rec = Recording(path)
    except (OSError, ValueError) as err:
        raise HybridError(f"labels_from_recording: {err}") from None
    if not rec.has_labels:
        raise HybridError(f"labels_from_recording: {path} has no labels/")

    def read(index: int) -> torch.Tensor:
        try:
            return torch.from_numpy(rec.read_labels(index).astype(np.int64))
        except (OSError, ValueError, IndexError) as err:
            raise HybridError(f"labels_from_recording, frame {index}: {err}") from None

    return read
