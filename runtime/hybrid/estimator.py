"""Hybrid tracking and detection (Wei section 5): mode "hybrid" of ``runtime-track``.

Per frame (a :class:`~runtime.frame.Frame` with a person in it):

1. No previous pose (first frame, after a lost one): the detector gives the pose ("detected").
2. Otherwise the tracker fits the frame from the previous two poses. A suspect fit (badness
   over ``arm_search.badness``) whose model hides or misplaces an arm the forest sees is
   refitted from a few arm poses first (:class:`~runtime.hybrid.arm_search.ArmSearch`).
3. :func:`~runtime.hybrid.policy.judge_track` tests the fit (Wei's epsilon1, epsilon2, and the
   optional surface error). A passed fit is the frame's pose ("tracked").
4. A failed (or rechecked) fit goes to the detector; :func:`~runtime.hybrid.policy.choose`
   keeps the track ("tracked", flagged ``kept_over_detector`` or ``rechecked``) or takes the
   detection ("detected"). With ``keep_better.confirm_within_m``, a detection whose IK pose
   puts every joint that close to the track's confirms the track before any refinement: the
   track is kept ("tracked", flagged ``confirmed_by_detector``), its history goes on, and the
   refinement's cost is saved. With ``keep_better.agree_within_m``, a better refined detection
   that lands that close to the track agrees with it: the track is kept the same way. A
   detection that finds nobody leaves the frame "lost" and the next
   frame starts afresh. So does a frame whose chosen fit explains almost none of the
   silhouette (overlap below ``failure.lost_overlap``): it is not the person's pose.

With ``catch_up``, a live stream that skipped frames since the last pose gives a frame that
passed its tests no second opinion (steps 2 and 4's arm search and recheck; flagged
``hurried``), so recovery work goes to failed frames until the estimates keep up again.

One tracker serves the tracking, every refit and the detector's refinement, all on the frame's
one observation. The forest's labels are computed once per frame, when first needed (every
frame when the tracker's label term is on).
"""

from __future__ import annotations

import functools
import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch
from depthmocap.runtime.detector import DetectionResult, Detector
from depthmocap.runtime.estimator import PoseEstimate, evidence_of, lost, observed_of
from depthmocap.runtime.frame import Frame, LabelSource
from depthmocap.runtime.tracker.prior_term import velocity_scale
from depthmocap.runtime.tracker.signals import FitSignals
from depthmocap.runtime.tracker.tracker import Tracker, TrackResult
from depthmocap.shared.image_cut import image_cut_distance_m
from depthmocap.shared.joint_confidence import JointConfidence, frame_features
from depthmocap.shared.joint_offsets import JointOffsets, apply_offsets
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
from depthmocap.shared.part_evidence import image_part_evidence

from .arm_search import ArmSearch
from .behind_model import StaticBehindMask
from .body_scale import BodyScaleSearch
from .config import HybridConfig
from .pieces import PiecesInFlight
from .policy import Detection, behind, choose, judge_track
from .split_refits import SplitRefits
from .stature_extent import upright_extent
from .unseen_limbs import held_dofs, hold_unseen

__all__ = ["HybridEstimator", "TrackState", "overlaps_of"]


@dataclass
class TrackState:
    """What the hybrid carries from frame to frame.

    Attributes:
        q_prev, q_prev2: (34,) the last two poses (None: no track).
        index_prev, index_prev2: the stream indices of the frames they are of: a live stream
            skips frames, and the prior's velocity is per frame of the stream, not per pose.
        refused_at: the frame whose detection was last refused (None: none since the reset).
        held: (34,) bool angles of the limbs the last tracked pose did not see
            (``cfg.hold_unseen_limbs``; None: none held).
    """

    q_prev: torch.Tensor | None = None
    q_prev2: torch.Tensor | None = None
    index_prev: int | None = None
    index_prev2: int | None = None
    refused_at: int | None = None
    held: torch.Tensor | None = None


def _lower_priority() -> None:
    """Give the calling thread the lowest CPU priority where the OS allows it per thread
    (Linux): the size search should take the time the reader leaves idle, not the frame's."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)
    except (AttributeError, OSError):  # no per-thread priorities here: an ordinary thread
        pass


# The size search's refits of a sample are queued in this many pieces (batches of bodies),
# so the frame that reads the sample runs the pieces the worker has not reached (1: one
# batch, waited for whole). Any number gives the same sizes.
SIZE_SEARCH_PIECES = 3


def overlaps_of(sizes: Tracker, obs, starts: torch.Tensor, iterations: int) -> np.ndarray:
    """(S,) silhouette overlaps of ``obs`` refitted by ``sizes`` (a tracker of S bodies)
    from the (S, 34) ``starts``, start k with body k (in inference mode, as the estimate:
    it runs on the size search's worker thread too)."""
    with torch.inference_mode():
        return sizes.fit_overlaps(obs, starts, iterations).numpy()


class HybridEstimator:
    """Tracker with detector (re)initialization for one stream (a ``PoseEstimator``).

    Args:
        labels: the frame's part labels (the forest's, or a recording's).
        detector: the pose detector (its refinement runs on ``tracker``).
        tracker: the one tracker of the stream.
        cfg: the settings.
        offsets: where the output joints sit relative to the model's
            (``shared.joint_offsets``), or None: the model's own joints.
        confidence: which joints to report observed (``shared.joint_confidence``), or
            None: the tracker's own area test. Either way the unseen-limb hold reads the
            area test, so the poses do not depend on it.
        background: run the size search's refits on a worker thread (the same size, found
            on the same frame, as inline) and half of every batched refit's starts on a
            helper thread (:mod:`~runtime.hybrid.split_refits`; the same fits); False: all
            on the calling thread.
    """

    def __init__(
        self,
        labels: LabelSource,
        detector: Detector,
        tracker: Tracker,
        cfg: HybridConfig,
        offsets: JointOffsets | None = None,
        background: bool = True,
        confidence: JointConfidence | None = None,
    ) -> None:
        self.label_source, self.detector, self.tracker, self.cfg = labels, detector, tracker, cfg
        self.offsets, self.confidence = offsets, confidence
        self.arm_search = (
            None if cfg.arm_search is None else ArmSearch(cfg.arm_search, tracker.body)
        )
        self.state = TrackState()
        self.scale_search = (
            None if cfg.body_scale is None else BodyScaleSearch(cfg.body_scale, tracker.body)
        )
        self._behind = None if cfg.behind_model is None else StaticBehindMask(cfg.behind_model)
        self._refits = SplitRefits(background)
        # The size search's trackers of its candidate bodies, in SIZE_SEARCH_PIECES pieces.
        self._sizes: list[Tracker] | None = None
        self._sizes_of = None  # the bodies self._sizes fit
        self._size_in_use = (1.0, 1.0)  # (factor, girth) on the search's body tracked with
        # The size search's refits run here, off the frame's path (``_size_overlaps``).
        self._worker = (
            ThreadPoolExecutor(1, thread_name_prefix="size-search", initializer=_lower_priority)
            if background and self.scale_search is not None
            else None
        )

    @property
    def body(self):
        """The body in use: the given one, or the default scaled to the person once
        :attr:`body_scale` is known."""
        return self.tracker.body

    @property
    def body_scale(self) -> float | None:
        """The factor found on the default body (None: not searched, or not yet)."""
        return None if self.scale_search is None else self.scale_search.scale

    @property
    def body_girth(self) -> float | None:
        """The girth found with :attr:`body_scale` (None: not searched, or not yet)."""
        search = self.scale_search
        return None if search is None or search.scale is None else search.girth

    def reset(self) -> None:
        """Forget the track: the next frame goes to the detector, which then behaves as a new
        one would (its random sequence restarts)."""
        self.state = TrackState()
        self.detector.reset()
        if self.arm_search is not None:
            self.arm_search.reset()
        if self._behind is not None:
            self._behind.reset()

    def close(self) -> None:
        """Wait for the size search's refits in flight and release its worker thread (the
        estimator goes on without one: later samples are refitted inline)."""
        if self._worker is not None:
            self._worker.shutdown(wait=True)
            self._worker = None

    def prefetch(self, frame: Frame) -> None:
        """Compute what every frame needs before the estimate (the forest's labels, when the
        tracker's label term reads them), so a caller can do it on another thread while the
        previous frame is estimated (``runtime-track`` live:
        :mod:`runtime.streams.latest_frame`)."""
        if self.tracker.cfg.use_labels:
            frame.labels(self.label_source)

    # ---- the pieces a frame is made of ----

    def _observation(self, frame: Frame, tracker: Tracker):
        """``tracker``'s observation of ``frame`` with the labels its label term reads (none
        when it is off), and their posteriors for its label gate."""
        if not tracker.cfg.use_labels:
            return frame.observation(tracker)
        return frame.observation(
            tracker, frame.labels(self.label_source), frame.label_confidence(self.label_source)
        )

    def _fit(self, frame: Frame, start: torch.Tensor, before: torch.Tensor | None = None,
             iterations: int | None = None) -> TrackResult:  # fmt: skip
        """The frame's own fit; its prior predicts over the stream frames since the last pose
        (a live stream skips some: :func:`~runtime.tracker.prior_term.velocity_scale`)."""
        obs = self._observation(frame, self.tracker)
        ahead = velocity_scale(frame.index, self.state.index_prev, self.state.index_prev2)
        return self.tracker.fit(obs, start, before, iterations, velocity_scale=ahead)

    def _fit_starts(self, frame: Frame, starts: torch.Tensor,
                    iterations: int | None = None) -> list[TrackResult]:  # fmt: skip
        """Refits of ``frame`` from each of the (K, 34) ``starts``, batched (split over two
        threads on the CPU)."""
        obs = self._observation(frame, self.tracker)
        return self._refits.fit_starts(self.tracker, obs, starts, iterations)

    def _joints(self, q: torch.Tensor) -> np.ndarray:
        """(J, 3) output joints of pose ``q`` (34,): the model's, moved by the offsets."""
        body = self.tracker.body
        kin = forward_kinematics(q[None].to(body.lengths), body)
        joints = named_joint_positions(kin)
        if self.offsets is not None:
            joints = apply_offsets(joints, kin.rotations, q[None], self.offsets, body.stature())
        return joints[0].detach().cpu().double().numpy()

    def _drop_behind(self, frame: Frame) -> None:
        """Take the static surfaces far behind the last tracked pose out of ``frame``'s mask
        (:mod:`~runtime.hybrid.behind_model`), before anything reads the mask."""
        q = self.state.q_prev
        body = self.tracker.body
        kin = None if q is None else forward_kinematics(q[None].to(body.lengths), body)
        drop = self._behind.update(frame.depth_m, frame.mask, kin, frame.intrinsics)
        if bool(drop.any()):
            frame.drop_pixels(drop)

    def _run_detector(self, frame: Frame, track: torch.Tensor | None = None) -> DetectionResult:
        """The detector on ``frame``, refined on the shared tracker; changes no state.
        ``track`` (34,): the frame's track, which an IK pose close to it confirms
        (``keep_better.confirm_within_m``; the refinement is then skipped)."""
        labels = frame.labels(self.label_source)
        hint = self.state.q_prev  # one more IK start, used only if it fits the centroids best
        k = self.detector.cfg.refine_iterations
        refine = None if k <= 0 else (lambda starts: self._fit_starts(frame, starts, k))
        keep = self.cfg.keep_better
        within = None if keep is None or track is None else keep.confirm_within_m
        confirm = None if within is None else functools.partial(self._agrees, track, within)
        return self.detector.detect(
            frame.depth_m, labels, frame.mask, q_hint=hint, refine=refine, confirm=confirm
        )

    def _agrees(self, track: torch.Tensor, within_m: float, q: torch.Tensor) -> bool:
        """Whether pose ``q`` (34,) puts every model joint within ``within_m`` of ``track``'s."""
        return self._joint_gap(track, q) <= within_m

    def _joint_gap(self, track: torch.Tensor, q: torch.Tensor) -> float:
        """The largest distance (m) between a model joint of pose ``q`` (34,) and ``track``'s."""
        body = self.tracker.body
        kin = forward_kinematics(torch.stack([track, q.to(track)]).to(body.lengths), body)
        joints = named_joint_positions(kin)  # (2, J, 3)
        return float((joints[0] - joints[1]).norm(dim=-1).max())

    # ---- estimates, each updating the track ----

    def _observed(self, fit, errors: dict, status: str, joints: np.ndarray, frame: Frame):
        """The (16,) observed flags of ``fit`` (:func:`~runtime.estimator.observed_of`), the
        output ``joints`` (16, 3) read against where the person leaves ``frame``."""
        confidence = self.confidence
        if confidence is None or confidence.version < 2:
            return observed_of(fit, confidence)
        joints_t = torch.as_tensor(joints)
        cut = image_cut_distance_m(frame.mask, joints_t, frame.intrinsics)
        if confidence.version < 3:
            return observed_of(fit, confidence, frame_features(errors, status), cut)
        parts = image_part_evidence(
            frame.depth_m, frame.mask, frame.labels(self.label_source), frame.intrinsics, joints_t
        )
        return observed_of(fit, confidence, frame_features(errors, status), cut, joints_t, parts)

    def refit_from_later(
        self, frame: Frame, later: PoseEstimate, later2: PoseEstimate | None,
        velocity_scale: float = 1.0,
    ) -> tuple[PoseEstimate, float]:  # fmt: skip
        """``frame`` fitted from the poses of the two estimates after it (``later2`` None: no
        motion predicted), as the tracker fits a frame from the two before it, and that
        fit's badness (:meth:`FailureThresholds.badness`). The track is not touched:
        :mod:`runtime.look_back` revises frames already estimated with it."""
        t = self.tracker

        def pose(estimate: PoseEstimate | None) -> torch.Tensor | None:
            return None if estimate is None else torch.as_tensor(estimate.q, dtype=t.dtype)

        obs = self._observation(frame, t)
        res = t.fit(obs, pose(later), pose(later2), velocity_scale=velocity_scale)
        errors = res.signals.as_errors()
        joints = self._joints(res.q.detach())
        estimate = PoseEstimate(
            res.q.detach().cpu().double().numpy(),
            joints,
            "tracked",
            errors,
            observed=self._observed(res, errors, "tracked", joints, frame),
            **evidence_of(res),
        )
        return estimate, self.cfg.failure.badness(res.signals)

    def badness_of(self, estimate: PoseEstimate) -> float:
        """The badness of ``estimate``'s own fit, from the signals in its ``errors`` (a
        track's, or a refined detection's); NaN when it has none (lost, or a detection
        without refinement)."""
        e = estimate.errors
        signals = FitSignals(
            *(e.get(k, math.nan) for k in ("depth_error_cm", "overlap", "surface_error_q97_mm"))
        )
        return self.cfg.failure.badness(signals)

    def _tracked(self, res: TrackResult, errors: dict, frame: Frame) -> PoseEstimate:
        q = res.q.detach()
        self.state.q_prev, self.state.q_prev2 = q, self.state.q_prev
        self.state.index_prev, self.state.index_prev2 = frame.index, self.state.index_prev
        joints = self._joints(q)
        estimate = PoseEstimate(
            q.cpu().double().numpy(),
            joints,
            "tracked",
            errors,
            observed=self._observed(res, errors, "tracked", joints, frame),
            **evidence_of(res),
        )
        if self.cfg.hold_unseen_limbs:
            self.state.held = held_dofs(observed_of(res))
        self._offer_size(frame, q, estimate.joints)
        return estimate

    def _offer_size(self, frame: Frame, q: torch.Tensor, joints: np.ndarray) -> None:
        """Give the size search a frame's pose; track at the size it returns, if any."""
        search = self.scale_search
        if search is None:
            return
        extent = None
        if search.wants_extent:
            extent = upright_extent(frame.depth_m, frame.mask, frame.intrinsics, joints)
        scale = search.offer(frame, q, self._size_overlaps, joints, extent)
        if scale is not None and (scale, search.girth) != self._size_in_use:
            self._use_body(search.sized_body(scale))
            self._size_in_use = (scale, search.girth)
        if scale is not None and not search.searching:  # the search ends here
            self._sizes = None
            if self._worker is not None:
                self._worker.shutdown(wait=False)
                self._worker = None

    def _size_overlaps(self, bodies, frame: Frame, q: torch.Tensor) -> PiecesInFlight | np.ndarray:
        """(S,) silhouette overlaps of ``frame`` refitted from ``q`` with each of the S
        candidate ``bodies`` of the size search, in one batched fit on the frame's
        observation (the observation does not depend on the body).

        With ``background`` their :class:`~runtime.hybrid.pieces.PiecesInFlight`, queued on
        the worker thread in :data:`SIZE_SEARCH_PIECES` batches of bodies: the search reads a
        sample a sampling period later (all but the last), so the refits (~30 ms, 9 sizes of
        5 iterations) run in the time the stream's reader leaves idle instead of stalling the
        frame, and what the worker has not started by then runs on the reading thread beside
        it. Each body's fit is the same in any batch."""
        t = self.tracker
        if self._sizes is None or self._sizes_of is not bodies:  # new after a girth is kept
            self._sizes_of = bodies
            S = bodies.lengths.shape[0]
            edges = np.linspace(0, S, min(SIZE_SEARCH_PIECES, S) + 1).round().astype(int)
            self._sizes = [
                Tracker(bodies.select(slice(a, b)), t.intr, t.cfg, device=t.device, dtype=t.dtype)
                for a, b in zip(edges[:-1], edges[1:], strict=True)
            ]
        obs = self._observation(frame, t)
        iterations = self.cfg.body_scale.iterations
        refits = [
            functools.partial(
                overlaps_of, sizes, obs, q[None].expand(sizes.body.lengths.shape[0], -1),
                iterations,
            )
            for sizes in self._sizes
        ]  # fmt: skip
        if self._worker is None:
            return np.concatenate([refit() for refit in refits])
        return PiecesInFlight(self._worker, refits)

    def _use_body(self, body) -> None:
        """Track and detect with ``body`` from now on; the track goes on from its pose."""
        t, d = self.tracker, self.detector
        self.tracker = Tracker(body, t.intr, t.cfg, device=t.device, dtype=t.dtype)
        detector = Detector(body, d.intr, d.cfg, device=d.device, dtype=d.dtype)
        detector.generator.set_state(d.generator.get_state())
        self.detector = detector
        if self.arm_search is not None:
            self.arm_search = self.arm_search.with_body(body)

    def _unsupported(self, overlap: float) -> bool:
        """The fit explains too little of the silhouette to be the person's pose."""
        limit = self.cfg.failure.lost_overlap
        return limit is not None and not overlap >= limit  # NaN is unsupported too

    def _lose(self, errors: dict) -> PoseEstimate:
        """A frame without a usable pose: reported lost, the next frame starts afresh."""
        self.reset()
        return lost(**errors)

    def _keep(self, res: TrackResult, errors: dict, flags: dict, frame: Frame) -> PoseEstimate:
        """A failed or suspect track kept instead of a detection: tracked with ``flags`` added
        to its errors, unless it explains too little of the silhouette to be the person's pose
        (then lost)."""
        if self._unsupported(res.signals.overlap):
            return self._lose({**errors, "unsupported": 1.0})
        return self._tracked(res, {**errors, **flags}, frame)

    def _detected(self, det: DetectionResult, errors: dict, frame: Frame) -> PoseEstimate:
        errors["labelled_pixels"] = float(det.labelled_pixels)
        if not det.found:
            self.reset()
            return lost(**errors)
        errors["ik_rms_m"] = det.ik_rms
        if det.refined is not None:
            errors.update(det.refined.signals.as_errors())
            if self._unsupported(det.refined.signals.overlap):
                return self._lose({**errors, "unsupported": 1.0})
        q = det.q.detach()
        self.state.q_prev, self.state.q_prev2 = q, None
        self.state.index_prev, self.state.index_prev2 = frame.index, None
        self.state.held = None
        joints = self._joints(q)
        estimate = PoseEstimate(
            q.cpu().double().numpy(),
            joints,
            "detected",
            errors,
            det.labels.cpu().numpy().astype(np.uint8),
            observed=self._observed(det.refined, errors, "detected", joints, frame),
            **evidence_of(det.refined),
        )
        if self.scale_search is not None and self.scale_search.wants_detection:
            # Sized from the detection that starts the track: the body is near the
            # person's size from the first tracked frame, when most re-detections happen.
            self._offer_size(frame, q, estimate.joints)
        return estimate

    def estimate(self, frame: Frame) -> PoseEstimate:
        """Pose of the person in ``frame`` (module docstring)."""
        state, cfg = self.state, self.cfg
        if self._behind is not None:
            self._drop_behind(frame)
        if state.q_prev is None:
            return self._detected(self._run_detector(frame), {}, frame)
        res = self._fit(frame, state.q_prev, hold_unseen(state.q_prev, state.q_prev2, state.held))
        errors = res.signals.as_errors()
        badness = cfg.failure.badness(res.signals)
        # Behind a live stream, a second opinion on a frame that passed costs more frames
        # skipped, which make the next frames harder to track than the opinion is worth.
        hurry = (
            cfg.catch_up
            and behind(frame.index, state.index_prev)
            and not cfg.failure.failed(res.signals)
        )
        if hurry:
            errors["hurried"] = 1.0
        elif self.arm_search is not None and self.arm_search.wanted(badness):
            found = self.arm_search.search(
                frame,
                frame.labels(self.label_source),
                res,
                badness,
                lambda starts: self._fit_starts(frame, starts),
                cfg.failure.badness,
            )
            if found.best is not None:
                res, badness = found.best, found.badness
                errors = {**res.signals.as_errors(), "arm_searched": 1.0}
            if found.arms_searched:  # refits tried, taken or not: what the search costs
                errors["arms_searched"] = float(found.arms_searched)
        verdict = judge_track(res.signals, badness, cfg.failure, cfg.keep_better)
        if not verdict.run_detector or hurry:  # a hurried fit passed: res is unchanged
            return self._tracked(res, errors, frame)
        wait = 0 if cfg.keep_better is None else cfg.keep_better.wait_frames
        if state.refused_at is not None and frame.index - state.refused_at <= wait:
            # The detector was just refused: the track is kept without asking it again.
            return self._keep(res, errors, {"detector_waited": 1.0}, frame)
        failed = {f"tracker_{k}": v for k, v in errors.items()}
        det = self._run_detector(frame, res.q.detach())
        if cfg.keep_better is None:
            return self._detected(det, failed, frame)
        if det.confirmed:  # the detector found the track's own pose: nothing to weigh
            return self._keep(res, errors, {"confirmed_by_detector": 1.0}, frame)
        measure = det.found and cfg.keep_better.agree_within_m is not None
        gap = self._joint_gap(res.q.detach(), det.q.detach()) if measure else None
        detection = Detection(det.found, det.refined.signals if det.refined else None, gap)
        decision = choose(res.signals, detection, cfg.failure, cfg.keep_better)
        if decision.forget and self.arm_search is not None:
            self.arm_search.reset()
        if decision.agreed:
            return self._keep(res, errors, {"confirmed_by_detector": 1.0}, frame)
        if decision.keep_track:
            state.refused_at = frame.index
            kept = {"kept_over_detector": 1.0} if verdict.failed else {"rechecked": 1.0}
            return self._keep(res, errors, kept, frame)
        return self._detected(det, failed, frame)
