"""Hybrid switching (Wei section 5): statuses, failure tests, lost frames and re-acquisition."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
import torch
from depthmocap.runtime.detector import Detector, DetectorConfig
from depthmocap.runtime.estimator import PoseEstimate, estimate_frame, make_estimator
from depthmocap.runtime.frame import Frame, FrameError
from depthmocap.runtime.hybrid import (
    ArmSearchConfig,
    FailureThresholds,
    HybridConfig,
    HybridError,
    HybridEstimator,
    KeepBetterConfig,
    MisplacedArmConfig,
    create_estimator,
)
from depthmocap.runtime.hybrid import arm_search as arm_search_module
from depthmocap.runtime.hybrid import hybrid_config as config_from_mapping
from depthmocap.runtime.hybrid import policy as policy_module
from depthmocap.runtime.hybrid.behind_model import BehindModelConfig
from depthmocap.runtime.raycast import part_labels, render_body
from depthmocap.runtime.streams.base import DepthFrame
from depthmocap.runtime.tracker import Tracker, TrackerConfig
from depthmocap.runtime.tracker.prior_term import MAX_VELOCITY_SCALE, velocity_scale
from depthmocap.runtime.tracker.signals import FitSignals
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.image_cut import image_cut_distance_m
from depthmocap.shared.joint_confidence import GROUPS, JointConfidence
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, rest_pose
from depthmocap.shared.labels import PART_NAMES
from depthmocap.shared.part_evidence import image_part_evidence

INTR = Intrinsics.kinect_v1(160)
BODY = BodyShape.default()


def render_labels(q: torch.Tensor):
    r = render_body(q[None], BODY, INTR)
    return r.depth[0], part_labels(r, BODY)[0], r.mask[0]


def frame_of(depth: torch.Tensor, index: int, mask) -> Frame:
    """The prepared frame ``runtime-track`` would hand the estimator."""
    raw = DepthFrame(index, index / 30, (depth.numpy() * 1000).round().astype(np.uint16), INTR)
    return Frame.from_depth(raw, torch.as_tensor(mask))


def _off(value):
    return None if value is None or not math.isfinite(value) else value


def cfg_of(**flat) -> HybridConfig:
    """The settings tree from the scenarios' flat names (``keep_better=True`` and its keys,
    ``arm_search_badness`` and the ``*arm*`` keys, ``misplaced_arm_*``); an infinite
    threshold means that mechanism is off, as the scenarios were first written, and so is
    the size search and the joint offsets unless given. Fixed
    choices (runtime.hybrid.arm_search's and policy's constants) are set with
    :func:`constants`."""
    failure = {k: flat.pop(k) for k in ("epsilon1_cm", "epsilon2", "epsilon3_mm", "lost_overlap")
               if k in flat}  # fmt: skip
    if "epsilon3_mm" in failure:
        failure["epsilon3_mm"] = _off(failure["epsilon3_mm"])
    keep = {k: flat.pop(k) for k in ("compare_all_tests", "recheck_badness",
                                     "wait_frames", "confirm_within_m", "agree_within_m")
            if k in flat}  # fmt: skip
    for k in ("recheck_badness",):
        if k in keep:
            keep[k] = _off(keep[k])
    arm = {k: flat.pop(k) for k in ("other_arm_margin_m",) if k in flat}
    if "arm_search_cooldown" in flat:
        arm["cooldown_frames"] = flat.pop("arm_search_cooldown")
    if "arm_agreement_slack" in flat:
        arm["agreement_slack"] = _off(flat.pop("arm_agreement_slack"))
    misplaced_names = {"misplaced_arm_conflict": "conflict",
                       "misplaced_arm_cooldown": "cooldown_frames",
                       "misplaced_arm_relief": "relief"}  # fmt: skip
    misplaced = {new: flat.pop(old) for old, new in misplaced_names.items() if old in flat}
    badness = _off(flat.pop("arm_search_badness", None))
    if _off(misplaced.get("conflict", math.inf)) is None:
        misplaced = None
    search = None
    if badness is not None:
        misplaced_cfg = None if misplaced is None else MisplacedArmConfig(**misplaced)
        search = ArmSearchConfig(badness=badness, misplaced=misplaced_cfg, **arm)
    keep_cfg = KeepBetterConfig(**keep) if flat.pop("keep_better", False) else None
    flat.setdefault("body_scale", None)  # the size search has its own tests (test_body_scale)
    flat.setdefault("joint_offsets", None)  # the model's joints: the scenes render the model
    return HybridConfig(
        failure=FailureThresholds(**failure), keep_better=keep_cfg, arm_search=search, **flat
    )


@pytest.fixture
def constants(monkeypatch):
    """Sets the hybrid's fixed choices for one test: ``constants(HIDDEN_VISIBILITY=0.5)``."""

    def set_constants(**values):
        for name, value in values.items():
            module = policy_module if hasattr(policy_module, name) else arm_search_module
            assert hasattr(module, name), name
            monkeypatch.setattr(module, name, value)

    return set_constants


@dataclass
class FakeResult:
    q: torch.Tensor
    depth_error_cm: float
    overlap: float
    surface_error_q97_mm: float
    iterations: int = 1
    converged: bool = True
    limb_visibility: torch.Tensor | None = None
    observed: torch.Tensor | None = None

    @property
    def signals(self) -> FitSignals:
        return FitSignals(self.depth_error_cm, self.overlap, self.surface_error_q97_mm)


class ScriptedTracker:
    """The hybrid's tracker API around a scripted ``step``: the frame's own fits follow the
    script, the detector's refinements (``iterations`` given) run a real tracker."""

    cfg = TrackerConfig()
    body = BODY.to(dtype=torch.float32)

    def __init__(self) -> None:
        self.real = Tracker(BODY, INTR)
        self.velocity_scales: list[float] = []  # of the frame's own fits

    def observe(self, depth, mask, labels=None, label_confidence=None):
        return self.real.observe(depth, mask, labels), (labels if self.cfg.use_labels else None)

    def fit(self, obs, q_prev, q_prev2=None, iterations=None, velocity_scale=1.0):
        if iterations is not None:
            return self.real.fit(obs[0], q_prev, q_prev2, iterations, velocity_scale)
        self.velocity_scales.append(velocity_scale)
        return self.step(None, None, q_prev, q_prev2, labels=obs[1])

    def fit_starts(self, obs, starts, iterations=None):
        if iterations is not None:
            return self.real.fit_starts(obs[0], starts, iterations)
        return [self.step(None, None, q, None, labels=obs[1]) for q in starts]


class FakeTracker(ScriptedTracker):
    """Returns the previous pose; fails (large depth error) on the listed call numbers."""

    def __init__(self, fail_calls=(), low_overlap_calls=(), surface_mm=12.0):
        super().__init__()
        self.calls, self.fail, self.low = 0, set(fail_calls), set(low_overlap_calls)
        self.seen_prev2 = []
        self.surface_mm = surface_mm

    def step(self, depth, mask, q_prev, q_prev2=None, labels=None):
        self.calls += 1
        self.seen_prev2.append(q_prev2 is not None)
        err = 5.0 if self.calls in self.fail else 1.0
        ov = 0.5 if self.calls in self.low else 0.95
        return FakeResult(q_prev.clone(), err, ov, self.surface_mm)


@pytest.fixture(scope="module")
def scene():
    q = rest_pose(1, (0.0, 0.1, 2.5))[0]
    q[sk.DOF_NAMES.index("l_humerus_abd")] = math.radians(40)
    return q, *render_labels(q)


def make_hybrid(scene, tracker, refine_iterations=0, **cfg):
    q, depth, labels, mask = scene
    det = Detector(BODY, INTR, DetectorConfig(refine_iterations=refine_iterations))
    calls = []

    def labeler(f):
        calls.append(1)
        return labels * f.mask

    return HybridEstimator(labeler, det, tracker, cfg_of(**cfg)), calls


def test_status_sequence_with_failures_and_empty_frames(scene):
    q, depth, labels, mask = scene
    tracker = FakeTracker(fail_calls={2}, low_overlap_calls={4})
    est, labeler_calls = make_hybrid(scene, tracker)
    empty = np.zeros(mask.shape, dtype=bool)
    masks = [mask, mask, mask, mask, mask, mask, empty, empty, mask, mask]
    statuses = [estimate_frame(est, frame_of(depth, i, m)).status for i, m in enumerate(masks)]
    # d: first frame; t; tracker call 2 fails (depth) -> d; t; call 4 fails (overlap) -> d;
    # t; two empty frames lost; the person returns -> d; t.
    assert statuses == ["detected", "tracked", "detected", "tracked", "detected", "tracked",
                        "lost", "lost", "detected", "tracked"]  # fmt: skip
    assert len(labeler_calls) == 4  # the forest runs only when the detector does
    # The prior sees two previous poses except right after a detection.
    assert tracker.seen_prev2 == [False, True, False, True, False, False]


def test_the_prior_predicts_over_the_frames_a_live_stream_skipped(scene):
    """Frames 0, 1, 2, 5, 6, 10 of a stream (a live one keeps the newest): each fit's prior
    extrapolates the last step by the frames that passed over the last two poses' interval."""
    q, depth, labels, mask = scene
    tracker = FakeTracker()
    est, _ = make_hybrid(scene, tracker)
    statuses = [estimate_frame(est, frame_of(depth, i, mask)).status for i in (0, 1, 2, 5, 6, 10)]
    assert statuses == ["detected"] + ["tracked"] * 5
    # frame 1 right after the detection has no velocity (scale unused, 1); 2: 1/1; 5: 3/1;
    # 6: 1/3; 10: 4/1.
    assert tracker.velocity_scales == pytest.approx([1.0, 1.0, 3.0, 1 / 3, 4.0])
    assert est.state.index_prev == 10 and est.state.index_prev2 == 6


def test_velocity_scale_table():
    assert velocity_scale(5, 4, 3) == 1.0  # every frame: Wei's prior
    assert velocity_scale(7, 4, 3) == 3.0 and velocity_scale(5, 4, 2) == 0.5
    assert velocity_scale(40, 4, 3) == MAX_VELOCITY_SCALE  # a long stall: capped
    assert velocity_scale(5, 4, None) == velocity_scale(5, None, None) == 1.0
    assert velocity_scale(5, 4, 4) == 1.0  # no interval: nothing to scale by


def test_errors_and_joints_are_reported(scene):
    q, depth, labels, mask = scene
    est, _ = make_hybrid(scene, FakeTracker(fail_calls={2}))
    first = estimate_frame(est, frame_of(depth, 0, mask))
    assert first.status == "detected" and first.labels is not None
    true = named_joint_positions(forward_kinematics(q[None], BODY))[0].numpy()
    assert np.linalg.norm(first.joints - true, axis=-1).mean() < 0.06
    tracked = estimate_frame(est, frame_of(depth, 1, mask))
    assert set(tracked.errors) == {"depth_error_cm", "overlap", "surface_error_q97_mm"}
    redetected = estimate_frame(est, frame_of(depth, 2, mask))
    assert redetected.status == "detected"
    assert redetected.errors["tracker_depth_error_cm"] == 5.0


def test_observed_joints_come_from_the_tracker_fits(scene):
    """Detected (refined) and tracked frames carry the fits' observed-joint flags; a fit
    without flags (the fake tracker, or no refinement) reports none."""
    q, depth, labels, mask = scene
    est, _ = make_hybrid(scene, Tracker(BODY, INTR), refine_iterations=2)
    first, second = (estimate_frame(est, frame_of(depth, i, mask)) for i in range(2))
    assert (first.status, second.status) == ("detected", "tracked")
    for e in (first, second):
        assert e.observed.shape == (16,) and e.observed.dtype == bool
        assert e.observed.sum() >= 14, e.observed
    fake, _ = make_hybrid(scene, FakeTracker())
    assert all(estimate_frame(fake, frame_of(depth, i, mask)).observed is None for i in range(2))


def test_a_joint_confidence_sets_the_flags_not_the_poses(scene):
    """With a confidence model the flags are its; the poses (whose unseen-limb hold reads
    the tracker's own area test) and the evidence reported are the same as without."""
    q, depth, labels, mask = scene
    G = len(GROUPS)
    models = {
        "area test": None,
        "none": JointConfidence(np.zeros((G, 3)), np.full(G, -50.0), 0.5, version=1),
        "all": JointConfidence(np.zeros((G, 9)), np.full(G, 50.0), 0.5, version=2),
    }
    frames = []
    for i in range(4):  # the right arm rises: a held limb would lag it
        qi = q.clone()
        qi[sk.DOF_NAMES.index("r_humerus_abd")] = math.radians(12 * i)
        d, _, m = render_labels(qi)
        frames.append(frame_of(d, i, m))
    runs = {}
    for name, model in models.items():
        est, _ = make_hybrid(scene, Tracker(BODY, INTR), refine_iterations=2)
        est.confidence = model
        runs[name] = [estimate_frame(est, f) for f in frames]
    area = TrackerConfig().observed_joint_area_cm2
    for plain, none, every in zip(runs["area test"], runs["none"], runs["all"], strict=True):
        assert plain.joint_support_cm2.shape == (16,) and plain.limb_visibility.shape == (4,)
        np.testing.assert_array_equal(plain.observed, plain.joint_support_cm2 >= area)
        assert not none.observed.any() and every.observed.all()
        for other in (none, every):
            np.testing.assert_array_equal(other.q, plain.q)
            np.testing.assert_array_equal(other.joint_support_cm2, plain.joint_support_cm2)


def test_joints_near_the_person_s_cut_by_the_image_edge_are_inferred(scene):
    """A version 2 confidence reads each output joint's distance to where the person leaves
    the image: here it alone decides (observed beyond 0.3 m), so the flags are exactly the
    joints that far from the cut, which the test measures on the frame's own mask."""
    q, depth, labels, mask = scene
    G = len(GROUPS)
    w = np.zeros((G, 9))
    w[:, 8] = 100.0
    # p >= 0.5 iff cut distance >= 0.3 m
    model = JointConfidence(w, np.full(G, -30.0), 0.5, version=2)
    cut_mask = torch.as_tensor(mask).clone()
    rows = torch.nonzero(cut_mask.any(1))[:, 0]
    cut_mask[rows[len(rows) // 2] :, -1] = True  # the person reaches the right edge below the waist
    est, _ = make_hybrid(scene, Tracker(BODY, INTR), refine_iterations=2)
    est.confidence = model
    flags = []
    for i in range(2):
        frame = frame_of(depth, i, cut_mask)
        e = estimate_frame(est, frame)
        near = image_cut_distance_m(frame.mask, torch.as_tensor(e.joints), INTR).numpy()
        np.testing.assert_array_equal(e.observed, near >= 0.3)
        flags.append(e.observed)
    assert not all(f.all() for f in flags) and any(f.any() for f in flags)


def test_joints_far_from_the_forest_s_pixels_of_their_parts_are_inferred(scene):
    """A version 3 confidence reads each output joint's distance to the labelled pixels of
    its parts: here it alone decides (observed within 5 cm), so the flags are exactly the
    joints that close, measured on the frame's own depth, mask and labels."""
    q, depth, labels, mask = scene
    G = len(GROUPS)
    w = np.zeros((G, 15))
    w[:, 13] = -100.0  # the feature is log(1 + 100 near)
    model = JointConfidence(w, np.full(G, 100.0 * math.log(6.0)), 0.5, version=3)
    est, _ = make_hybrid(scene, Tracker(BODY, INTR), refine_iterations=2)
    est.confidence = model
    flags = []
    for i in range(2):
        frame = frame_of(depth, i, mask)
        e = estimate_frame(est, frame)
        ev = image_part_evidence(frame.depth_m, frame.mask, frame.labels(est.label_source), INTR,
                                 torch.as_tensor(e.joints))  # fmt: skip
        np.testing.assert_array_equal(e.observed, ev[:, 0].numpy() < 0.05)
        flags.append(e.observed)
    assert any(f.any() for f in flags)


def test_no_labelled_pixels_is_lost_and_resets(scene):
    q, depth, labels, mask = scene
    det = Detector(BODY, INTR, DetectorConfig(refine_iterations=0))
    est = HybridEstimator(lambda f: torch.zeros_like(labels), det, FakeTracker(), HybridConfig())
    assert estimate_frame(est, frame_of(depth, 0, mask)).status == "lost"
    assert est.state.q_prev is None


def test_failure_thresholds():
    paper = FailureThresholds()
    assert (paper.epsilon1_cm, paper.epsilon2, paper.epsilon3_mm) == (2.5, 0.9, None)

    def failed(thresholds, d, o, surface=0.0):
        return thresholds.failed(FitSignals(d, o, surface))

    assert not failed(paper, 2.4, 0.95) and failed(paper, 2.6, 0.95) and failed(paper, 1.0, 0.85)
    assert not failed(FailureThresholds(4.0, 0.4), 3.0, 0.5)
    assert not failed(paper, 1.0, 0.95, 1e4)  # no surface test by default
    with_surface = FailureThresholds(epsilon3_mm=100.0)
    assert not failed(with_surface, 1.0, 0.95, 99.0) and failed(with_surface, 1.0, 0.95, 101.0)
    assert failed(paper, math.nan, 0.95)  # a NaN signal fails


@pytest.mark.parametrize("lost_overlap, status", [(None, "tracked"), (0.4, "tracked"),
                                                 (0.6, "lost")])  # fmt: skip
def test_a_kept_fit_that_explains_too_little_is_lost(scene, lost_overlap, status):
    """The track fails (overlap 0.5 under epsilon2 0.9), the detector's refit is no better
    (the fake track's surface error is 0): kept, unless its overlap is under lost_overlap."""
    q, depth, labels, mask = scene
    tracker = FakeTracker(low_overlap_calls={2}, surface_mm=0.0)
    est, _ = make_hybrid(scene, tracker, 1, keep_better=True, lost_overlap=lost_overlap)
    got = [estimate_frame(est, frame_of(depth, i, mask)) for i in range(4)]
    assert [e.status for e in got] == ["detected", "tracked", status, "detected" if
                                       status == "lost" else "tracked"]  # fmt: skip
    if status == "lost":
        assert got[2].errors["unsupported"] == 1.0 and got[2].joints is None


def test_a_detection_that_explains_too_little_is_lost(scene):
    q, depth, labels, mask = scene
    est, _ = make_hybrid(scene, FakeTracker(), 2, lost_overlap=0.0)
    assert estimate_frame(est, frame_of(depth, 0, mask)).status == "detected"
    strict, _ = make_hybrid(scene, FakeTracker(), 2, lost_overlap=0.999)
    first = estimate_frame(strict, frame_of(depth, 0, mask))
    assert first.status == "lost" and first.errors["unsupported"] == 1.0
    assert strict.state.q_prev is None
    with pytest.raises(ValueError, match="lost_overlap"):
        FailureThresholds(lost_overlap=1.5)


@pytest.mark.parametrize("tracker_surface_mm, status", [(1e4, "detected"), (0.0, "tracked")])
def test_keep_better_takes_the_pose_with_the_smaller_surface_error(
    scene, tracker_surface_mm, status
):
    q, depth, labels, mask = scene
    tracker = FakeTracker(fail_calls={2, 3}, surface_mm=tracker_surface_mm)
    est, _ = make_hybrid(scene, tracker, refine_iterations=1, keep_better=True)
    assert estimate_frame(est, frame_of(depth, 0, mask)).status == "detected"
    first = est.state.q_prev.clone()
    assert estimate_frame(est, frame_of(depth, 1, mask)).status == "tracked"
    failed = estimate_frame(est, frame_of(depth, 2, mask))  # the tracker fails its depth test
    assert failed.status == status
    if status == "tracked":  # kept: the tracker's pose, and the history goes on from it
        assert failed.errors["kept_over_detector"] == 1.0
        assert torch.equal(est.state.q_prev, first) and est.state.q_prev2 is not None
    else:
        assert failed.errors["tracker_surface_error_q97_mm"] == 1e4
        assert est.state.q_prev2 is None


@pytest.mark.parametrize("within_m, status", [(None, "detected"), (1e-4, "detected"),
                                              (1.0, "tracked")])  # fmt: skip
def test_a_detection_that_finds_the_track_confirms_it_unrefined(scene, within_m, status):
    """The track fails (depth) and fits worse than any detection (surface 10 m): the detection
    is taken, unless its IK pose puts every joint within ``confirm_within_m`` of the track's.
    Then the track is kept with its history, flagged, and the refinement is not run."""
    q, depth, labels, mask = scene
    tracker = FakeTracker(fail_calls={2}, surface_mm=1e4)
    est, _ = make_hybrid(scene, tracker, refine_iterations=1, keep_better=True,
                         confirm_within_m=within_m)  # fmt: skip
    for i in range(2):
        estimate_frame(est, frame_of(depth, i, mask))
    refits = []
    real_fit_starts = tracker.real.fit_starts
    tracker.real.fit_starts = lambda *a, **k: refits.append(1) or real_fit_starts(*a, **k)
    got = estimate_frame(est, frame_of(depth, 2, mask))
    assert got.status == status
    assert ("confirmed_by_detector" in got.errors) == (status == "tracked")
    assert (not refits) == (status == "tracked")  # the 8 starts may come in two halves
    assert (est.state.q_prev2 is not None) == (status == "tracked")
    with pytest.raises(ValueError, match="confirm_within_m"):
        KeepBetterConfig(confirm_within_m=0.0)


def test_a_better_detection_on_the_track_s_pose_agrees_with_it(scene):
    """The track fails (depth) and fits worse than any detection (surface 10 m): the refined
    detection is taken, unless it puts every joint within ``agree_within_m`` of the track's.
    Then the track is kept with its history, flagged, after the refinement ran."""
    q, depth, labels, mask = scene

    def third_frame(agree_m):
        tracker = FakeTracker(fail_calls={2}, surface_mm=1e4)
        est, _ = make_hybrid(scene, tracker, refine_iterations=1, keep_better=True,
                             agree_within_m=agree_m)  # fmt: skip
        for i in range(2):
            estimate_frame(est, frame_of(depth, i, mask))
        track = est.state.q_prev.clone()  # the fake tracker keeps the previous pose
        refits = []
        real_fit_starts = tracker.real.fit_starts
        tracker.real.fit_starts = lambda *a, **k: refits.append(1) or real_fit_starts(*a, **k)
        got = estimate_frame(est, frame_of(depth, 2, mask))
        assert refits  # agreement is judged on the refined detection
        return got, track, est

    taken, track, est = third_frame(None)
    assert taken.status == "detected" and est.state.q_prev2 is None
    kin = forward_kinematics(torch.stack([track, est.state.q_prev]).to(BODY.lengths), BODY)
    joints = named_joint_positions(kin)
    gap = float((joints[0] - joints[1]).norm(dim=-1).max())
    assert gap > 1e-3  # the detection is another pose, so the boundary below means something
    farther, _, _ = third_frame(0.9 * gap)
    assert farther.status == "detected"
    agreed, _, est = third_frame(1.1 * gap)
    assert agreed.status == "tracked" and agreed.errors["confirmed_by_detector"] == 1.0
    assert torch.equal(est.state.q_prev, track) and est.state.q_prev2 is not None
    with pytest.raises(ValueError, match="agree_within_m"):
        KeepBetterConfig(agree_within_m=-0.01)


@pytest.mark.parametrize("threshold, rechecked", [(0.5, True), (1.0, False)])
def test_recheck_badness_questions_suspect_fits(scene, threshold, rechecked):
    q, depth, labels, mask = scene
    # The fake tracker passes with depth error 1 cm and overlap 0.95: badness 1/2.5 + 0.05/0.1.
    est, calls = make_hybrid(
        scene, FakeTracker(surface_mm=0.0), refine_iterations=1, keep_better=True,
        recheck_badness=threshold,
    )  # fmt: skip
    got = [estimate_frame(est, frame_of(depth, i, mask)) for i in range(3)]
    assert [g.status for g in got] == ["detected", "tracked", "tracked"]
    assert len(calls) == (3 if rechecked else 1)
    assert ("rechecked" in got[1].errors) == rechecked


def test_catch_up_gives_passed_frames_behind_the_stream_no_second_opinion(scene):
    """Frames 0, 1, 2, 4, 7, 8, 10 of a live stream; every fit passes but is suspect (a
    recheck each), frame 7's fails. With catch_up, the frames after a skip (4, 10) are not
    rechecked, the failed frame 7 still asks the detector, and consecutive frames as before."""
    q, depth, labels, mask = scene
    indices = (0, 1, 2, 4, 7, 8, 10)

    def run(catch_up):
        tracker = FakeTracker(fail_calls={4}, surface_mm=0.0)  # the 4th fit: frame 7
        est, calls = make_hybrid(
            scene, tracker, refine_iterations=1, keep_better=True, recheck_badness=0.5,
            catch_up=catch_up,
        )  # fmt: skip
        got = [estimate_frame(est, frame_of(depth, i, mask)) for i in indices]
        return got, len(calls)

    plain, asked_plain = run(False)
    hurried, asked = run(True)
    assert asked_plain == 7  # the first detection and every later frame
    assert asked == 5  # not frames 4 and 10
    flags = [("hurried" in g.errors, "rechecked" in g.errors) for g in hurried]
    assert flags == [(False, False), (False, True), (False, True), (True, False),
                     (False, False), (False, True), (True, False)]  # fmt: skip
    assert "rechecked" not in hurried[4].errors and "hurried" not in hurried[4].errors
    assert [g.status for g in hurried] == [g.status for g in plain]
    assert not any("hurried" in g.errors for g in plain)


def test_behind_table():
    assert not policy_module.behind(5, None)  # no pose yet
    assert not policy_module.behind(5, 4)  # every frame: a file
    assert policy_module.behind(6, 4)


@pytest.mark.parametrize("wait, asked", [(0, [1, 2, 3, 4, 5, 6]), (2, [1, 4])])
def test_a_refused_detection_makes_the_detector_wait(scene, wait, asked):
    """Every tracked frame is suspect and the track always fits better: the detector is asked
    and refused; with a wait it is not asked again for that many frames, and a failed track
    is kept meanwhile too. A reset (lost frame) forgets the wait."""
    q, depth, labels, mask = scene
    tracker = FakeTracker(fail_calls={3}, surface_mm=0.0)  # frame 3's track fails
    est, calls = make_hybrid(
        scene, tracker, refine_iterations=1, keep_better=True, recheck_badness=0.5,
        wait_frames=wait,
    )  # fmt: skip
    got = [estimate_frame(est, frame_of(depth, i, mask)) for i in range(7)]
    assert [g.status for g in got] == ["detected"] + ["tracked"] * 6
    assert len(calls) == 1 + len(asked)  # the forest's labels run when the detector does
    waited = [i for i, g in enumerate(got) if "detector_waited" in g.errors]
    assert waited == [i for i in range(1, 7) if i not in asked]
    assert ("kept_over_detector" in got[3].errors) == (3 in asked)
    estimate_frame(est, frame_of(depth * 0, 7, torch.zeros_like(mask)))
    assert est.state.refused_at is None


def test_recheck_is_off_without_keep_better(scene):
    q, depth, labels, mask = scene
    est, calls = make_hybrid(scene, FakeTracker(surface_mm=1e4), recheck_badness=0.0)
    assert [estimate_frame(est, frame_of(depth, i, mask)).status for i in range(3)] == [
        "detected",
        "tracked",
        "tracked",
    ]
    assert len(calls) == 1
    est, calls = make_hybrid(
        scene, FakeTracker(surface_mm=1e4), keep_better=True, recheck_badness=0.0
    )
    for i in range(3):  # every passed frame is rechecked: the detector runs on each
        estimate_frame(est, frame_of(depth, i, mask))
    assert len(calls) == 3


def test_fit_badness_golden():
    cfg = FailureThresholds(epsilon1_cm=3.0, epsilon2=0.7, epsilon3_mm=80.0)
    assert cfg.badness(FitSignals(3.0, 0.7, 80.0)) == pytest.approx(3.0)
    assert cfg.badness(FitSignals(0.0, 1.0, 0.0)) == 0.0
    assert cfg.badness(FitSignals(1.5, 0.85, 40.0)) == pytest.approx(1.5)
    without_surface = FailureThresholds(epsilon1_cm=3.0, epsilon2=0.7)
    assert without_surface.badness(FitSignals(3.0, 0.7, 1e6)) == 2.0


@pytest.mark.parametrize("compare_all, status", [(False, "tracked"), (True, "detected")])
def test_keep_better_can_compare_all_three_signals(scene, compare_all, status):
    q, depth, labels, mask = scene
    # The tracker fails on depth error alone; its surface error is perfect.
    tracker = FakeTracker(fail_calls={1}, surface_mm=0.0)
    est, _ = make_hybrid(
        scene, tracker, refine_iterations=1, keep_better=True, compare_all_tests=compare_all
    )
    estimate_frame(est, frame_of(depth, 0, mask))
    got = estimate_frame(est, frame_of(depth, 1, mask))
    assert got.status == status


def test_with_real_tracker_and_detector(scene):
    """A small motion: detected once, then tracked (exact data pass both tests)."""
    q, depth, labels, mask = scene
    det = Detector(BODY, INTR, DetectorConfig(refine_iterations=2))
    trk = Tracker(BODY, INTR, TrackerConfig(iterations=3))
    state = {}

    def labeler(f):
        return state["labels"] * f.mask

    est = HybridEstimator(labeler, det, trk, HybridConfig())
    statuses, errs = [], []
    for i in range(3):
        qi = q.clone()
        qi[0] += 0.01 * i
        qi[sk.DOF_NAMES.index("r_humerus_abd")] = math.radians(5 * i)
        d, lab, m = render_labels(qi)
        state["labels"] = lab
        out = estimate_frame(est, frame_of(d, i, m))
        statuses.append(out.status)
        true = named_joint_positions(forward_kinematics(qi[None], BODY))[0].numpy()
        errs.append(np.linalg.norm(out.joints - true, axis=-1).mean())
    assert statuses == ["detected", "tracked", "tracked"]
    assert max(errs) < 0.03


def test_config_and_factory_errors(tmp_path):
    with pytest.raises(HybridError):
        create_estimator(
            model_path=tmp_path / "f.npz", body=BODY, intrinsics=INTR, config={"epsilon3": 1}
        )
    with pytest.raises(ValueError):
        make_estimator("hybrid", tmp_path / "missing.npz", BODY, INTR)
    with pytest.raises(HybridError, match="no_such_key"):
        config_from_mapping({"tracker": {"no_such_key": 1}})
    for section, bad in (
        ("failure", {"epsilon1_cm": 0.0}),
        ("failure", {"epsilon2": 1.0}),
        ("failure", {"epsilon3_mm": float("nan")}),
        ("keep_better", {"recheck_badness": float("nan")}),
        ("keep_better", {"wait_frames": -1}),
    ):
        with pytest.raises(HybridError, match="epsilon|recheck|wait_frames"):
            config_from_mapping({section: bad})
    with pytest.raises(HybridError, match="recheck_every"):  # a setting that is no more
        create_estimator(
            model_path=tmp_path / "f.npz", body=BODY, intrinsics=INTR,
            config={"keep_better": {"recheck_every": 5}},
        )  # fmt: skip


def test_the_shipped_preset_is_a_tree_of_values():
    from depthmocap.shared.config import load_settings

    cfg = config_from_mapping(load_settings("configs/hybrid.yaml"))
    assert cfg.failure == FailureThresholds(3.0, 0.7, 80.0, lost_overlap=0.3)
    assert cfg.keep_better == KeepBetterConfig(True, 2.4, agree_within_m=0.05)
    assert cfg.arm_search.badness == 1.9 and cfg.arm_search.misplaced.conflict == 0.7
    assert cfg.tracker.use_labels and cfg.tracker.use_collision


class ArmHidingTracker(ScriptedTracker):
    """Tracks with the left arm hidden (visible fraction 0.1) and a suspect fit; of the refits
    that follow in the same frame, the one from 40 degrees of flexion and a straight elbow
    fits best. ``starts``: (flexion, elbow) of every call after the frame's first."""

    GOOD = (math.radians(40), 0.0)

    def __init__(self, use_labels=False, shown=0.1):
        super().__init__()
        self.calls, self.starts, self.labels_seen = 0, [], []
        self.cfg = TrackerConfig(use_labels=use_labels)
        self.shown = shown

    def step(self, depth, mask, q_prev, q_prev2=None, labels=None):
        self.calls += 1
        self.labels_seen.append(labels)
        vis = torch.tensor([self.shown, 1.0, 1.0, 1.0])
        if self.calls == 1:
            return FakeResult(q_prev.clone(), 2.0, 0.95, 12.0, limb_visibility=vis)
        start = tuple(
            float(q_prev[sk.DOF_NAMES.index(f"l_{n}")]) for n in ("humerus_flex", "radius_flex")
        )
        self.starts.append(start)
        err = 1.0 if start == pytest.approx(self.GOOD) else 2.2
        return FakeResult(q_prev.clone(), err, 0.95, 12.0, limb_visibility=vis)


def _track_second_frame(scene, tracker, labels_scale=1, **cfg):
    q, depth, labels, mask = scene
    det = Detector(BODY, INTR, DetectorConfig(refine_iterations=0))
    first = HybridEstimator(lambda f: labels * f.mask, det, tracker, cfg_of(**cfg))
    assert estimate_frame(first, frame_of(depth, 0, mask)).status == "detected"
    # The forest's labels on the second frame decide whether the camera sees the arm.
    first.label_source = lambda f: labels * f.mask * labels_scale
    return estimate_frame(first, frame_of(depth, 1, mask))


@pytest.mark.parametrize("use_labels", [False, True])
def test_hidden_arm_search_keeps_the_best_refit(scene, use_labels):
    tracker = ArmHidingTracker(use_labels)
    # badness of the track: 2.0 / 2.5 + 0.05 / 0.1 = 1.3; of the good refit 0.9
    out = _track_second_frame(scene, tracker, arm_search_badness=1.0, arm_agreement_slack=math.inf)
    assert out.status == "tracked" and out.errors["arm_searched"] == 1.0
    assert out.errors["depth_error_cm"] == 1.0
    assert len(tracker.starts) == 8  # the left arm's starts only
    flex = out.q[sk.DOF_NAMES.index("l_humerus_flex")]
    assert flex == pytest.approx(ArmHidingTracker.GOOD[0], abs=1e-6)
    # The refits get the frame's labels exactly when the tracker has the label term.
    assert all((seen is not None) == use_labels for seen in tracker.labels_seen[-8:])


@pytest.mark.parametrize("slack, searched", [(0.1, False), (1.0, True)])
def test_an_arm_search_refit_must_keep_the_forest_s_arm_pixels(scene, slack, searched):
    # The forest labels the left arm where the track has it; the best-fitting refit lifts
    # the arm 40 degrees away from those pixels, and is refused unless the slack allows it.
    tracker = ArmHidingTracker()
    out = _track_second_frame(scene, tracker, arm_search_badness=1.0, arm_agreement_slack=slack)
    assert len(tracker.starts) == 8
    assert ("arm_searched" in out.errors) == searched
    flex = out.q[sk.DOF_NAMES.index("l_humerus_flex")]
    assert (flex == pytest.approx(ArmHidingTracker.GOOD[0], abs=1e-6)) == searched


def test_an_arm_the_forest_does_not_label_is_searched_without_the_agreement_test(scene, constants):
    # With SEEN_FRACTION 0 a hidden arm is searched even where the forest labels none of
    # it; there is then no label to keep the arm near, and the best refit is taken.
    constants(SEEN_FRACTION=0.0)
    tracker = ArmHidingTracker()
    out = _track_second_frame(scene, tracker, 0, arm_search_badness=1.0)
    assert out.errors["arm_searched"] == 1.0 and len(tracker.starts) == 8
    flex = out.q[sk.DOF_NAMES.index("l_humerus_flex")]
    assert flex == pytest.approx(ArmHidingTracker.GOOD[0], abs=1e-6)


@pytest.mark.parametrize(
    "labels_scale, cfg, fixed",
    [
        (1, {}, {}),  # off by default
        (1, {"arm_search_badness": 1.5}, {}),  # the fit is not suspect enough
        (1, {"arm_search_badness": 1.0}, {"HIDDEN_VISIBILITY": 0.05}),  # not hidden enough
        (0, {"arm_search_badness": 1.0}, {}),  # the forest does not see the arm
    ],
)
def test_hidden_arm_search_needs_all_its_conditions(scene, labels_scale, cfg, fixed, constants):
    constants(**fixed)
    tracker = ArmHidingTracker()
    out = _track_second_frame(scene, tracker, labels_scale, **cfg)
    assert out.status == "tracked" and "arm_searched" not in out.errors
    assert tracker.starts == []


@pytest.mark.parametrize(
    "cfg",
    [
        {"badness": math.nan},
        {"hidden_visibility": -0.1},
        {"seen_fraction": 1.5},
        {"agreement_slack": -0.1},
        {"partial_visibility": -0.1},
        {"partial_agreement": 1.5},
        {"other_arm_margin_m": -0.01},
        {"misplaced": {"conflict": math.nan}},
        {"misplaced": {"min_points": 0}},
        {"misplaced": {"cooldown_frames": -1}},
        {"cooldown_frames": -1},
        {"misplaced": {"relief": 1.5}},
    ],
)
def test_bad_arm_search_settings_are_rejected(cfg):
    with pytest.raises(HybridError, match="arm_search|misplaced"):
        config_from_mapping({"arm_search": cfg})


def _left_arm_labelled_on_the_right(labels):
    """The forest's left/right swap in profile: the right arm's pixels labelled left arm, the
    left arm's pixels labelled chest."""
    swapped = labels.clone()
    for part in ("upper_arm", "forearm"):
        swapped[labels == PART_NAMES.index(f"r_{part}")] = PART_NAMES.index(f"l_{part}")
        swapped[labels == PART_NAMES.index(f"l_{part}")] = PART_NAMES.index("chest")
    return swapped


def _second_frame_with_labels(scene, tracker, cfg, seen):
    """Detect the scene's first frame, then track the second with the forest's labels
    ``seen``."""
    q, depth, labels, mask = scene
    det = Detector(BODY, INTR, DetectorConfig(refine_iterations=0))
    est = HybridEstimator(lambda f: labels * f.mask, det, tracker, cfg)
    estimate_frame(est, frame_of(depth, 0, mask))
    est.label_source = lambda f: seen * f.mask
    return estimate_frame(est, frame_of(depth, 1, mask))


@pytest.mark.parametrize("swap, searched", [(False, False), (True, True)])
def test_a_partly_shown_arm_is_searched_only_away_from_its_forest_pixels(
    scene, swap, searched, constants
):
    labels = scene[2]
    # The model shows 45% of the left arm. Where the forest labels the left arm on the
    # model's left arm there is nothing to search; where it labels it elsewhere (here: on
    # the right arm, counted with other_arm_margin_m 0) the arm is searched.
    seen = _left_arm_labelled_on_the_right(labels) if swap else labels
    common = dict(arm_search_badness=1.0, other_arm_margin_m=0.0, arm_agreement_slack=math.inf)
    tracker = ArmHidingTracker(shown=0.45)
    out = _second_frame_with_labels(scene, tracker, cfg_of(**common), seen)
    assert ("arm_searched" in out.errors) == searched
    assert len(tracker.starts) == (8 if searched else 0)
    # Below HIDDEN_VISIBILITY the arm counts as hidden and is searched either way.
    constants(HIDDEN_VISIBILITY=0.5)
    cfg = cfg_of(**common)
    out = _second_frame_with_labels(scene, ArmHidingTracker(shown=0.45), cfg, seen)
    assert "arm_searched" in out.errors


def test_forest_arm_pixels_on_the_other_arm_do_not_start_an_arm_search(scene):
    # The forest calls the right arm's pixels left arm (a left/right swap in profile) and
    # sees no other arm: the hidden left arm is not moved onto the right one.
    swapped = _left_arm_labelled_on_the_right(scene[2])
    for margin, searched in ((0.05, False), (0.0, True)):
        tracker = ArmHidingTracker()
        cfg = cfg_of(
            arm_search_badness=1.0, other_arm_margin_m=margin, arm_agreement_slack=math.inf
        )
        out = _second_frame_with_labels(scene, tracker, cfg, swapped)
        assert ("arm_searched" in out.errors) == searched
        assert len(tracker.starts) == (8 if searched else 0)


class LabelTracker(FakeTracker):
    """A tracker with the label term on: records the labels it is given."""

    def __init__(self, **kw):
        super().__init__(**kw)
        self.cfg = TrackerConfig(use_labels=True)
        self.labels_seen = []

    def step(self, depth, mask, q_prev, q_prev2=None, labels=None):
        self.labels_seen.append(labels)
        return super().step(depth, mask, q_prev, q_prev2)


def test_label_term_gets_the_forest_labels_once_per_frame(scene):
    q, depth, labels, mask = scene
    tracker = LabelTracker(fail_calls={2})
    est, labeler_calls = make_hybrid(scene, tracker)
    statuses = [estimate_frame(est, frame_of(depth, i, mask)).status for i in range(4)]
    assert statuses == ["detected", "tracked", "detected", "tracked"]
    # Every frame runs the forest once, also when the tracker fails and the detector runs.
    assert len(labeler_calls) == 4
    assert len(tracker.labels_seen) == 3
    for seen in tracker.labels_seen:
        torch.testing.assert_close(seen, (labels * torch.as_tensor(mask)).long())
    # Without the label term the tracker gets no labels, and the forest runs only to detect.
    plain = LabelTracker()
    plain.cfg = TrackerConfig()
    est, labeler_calls = make_hybrid(scene, plain)
    for i in range(3):
        estimate_frame(est, frame_of(depth, i, mask))
    assert plain.labels_seen == [None, None] and len(labeler_calls) == 1


def _write_recording(path, depth, labels, frames, with_labels=True):
    from depthmocap.shared.recording import RecordingWriter

    depth_mm = (depth.numpy() * 1000).round().astype(np.uint16)
    with RecordingWriter(path, INTR) as w:
        for _ in range(frames):
            w.write_frame(depth_mm, labels.numpy().astype(np.uint8) if with_labels else None)


def test_labels_from_a_recording_stand_in_for_the_forest(scene, tmp_path):
    """A synthetic recording's own labels replace the forest's, frame by frame; no forest is
    loaded (model_path None) and the detector finds the rendered pose from them."""
    q, depth, labels, mask = scene
    _write_recording(tmp_path / "rec", depth, labels, 3)
    est = create_estimator(
        model_path=None, body=BODY, intrinsics=INTR,
        config={"labels_from_recording": str(tmp_path / "rec"),
                "detector": {"refine_iterations": 2},
                "tracker": {"use_labels": True, "iterations": 3},
                "joint_offsets": None},  # the scene is the model: its own joints are true
    )  # fmt: skip
    outs = [estimate_frame(est, frame_of(depth, i, mask)) for i in range(3)]
    assert [o.status for o in outs] == ["detected", "tracked", "tracked"]
    frame = frame_of(depth, 2, mask)
    torch.testing.assert_close(frame.labels(est.label_source), labels * mask)
    true = named_joint_positions(forward_kinematics(q[None], BODY))[0].numpy()
    assert np.linalg.norm(outs[-1].joints - true, axis=-1).mean() < 0.03
    # Each frame reads its own labels: another frame's labels are not reused.
    seen = []
    est.label_source = lambda f: seen.append(f.index) or labels
    est.reset()
    for i in (5, 6):
        estimate_frame(est, frame_of(depth, i, mask))
    assert seen == [5, 6]


def test_the_tracker_reads_only_the_labels_the_forest_is_sure_of(scene, tmp_path):
    """A label source that gives each label's posterior (the forest's): the frame keeps both,
    and with ``tracker.label_min_posterior`` every observation the hybrid makes for its
    tracker (its fit, refits, the detector's refinement) has its label term skip the unsure
    labels; without the setting, or from a source without posteriors, it reads them all."""
    q, depth, labels, mask = scene
    _write_recording(tmp_path / "rec", depth, labels, 2)
    confidence = torch.where(labels % 2 == 0, 0.9, 0.2)  # every other part unsure
    from depthmocap.runtime.tracker.observation import label_term_pixels

    made = {}
    for gate in (0.0, 0.5):
        est = create_estimator(
            model_path=None, body=BODY, intrinsics=INTR,
            config={"labels_from_recording": str(tmp_path / "rec"), "joint_offsets": None,
                    "tracker": {"use_labels": True, "label_min_posterior": gate}},
        )  # fmt: skip
        est.label_source = lambda f: (labels * f.mask, confidence)
        frame = frame_of(depth, 0, mask)
        torch.testing.assert_close(frame.label_confidence(est.label_source), confidence)
        made[gate] = label_term_pixels(est._observation(frame, est.tracker))
        estimate_frame(est, frame_of(depth, 1, mask))  # a whole frame runs through it
    t = Tracker(BODY, INTR, TrackerConfig(use_labels=True))
    plain = frame_of(depth, 0, mask)
    want = t.observe(plain.depth_m, plain.mask, labels * plain.mask * (confidence >= 0.5))
    assert torch.equal(made[0.5], label_term_pixels(want))
    full = t.observe(plain.depth_m, plain.mask, labels * plain.mask)
    assert torch.equal(made[0.0], label_term_pixels(full))
    assert not torch.equal(made[0.0], made[0.5])
    with pytest.raises(FrameError, match="label confidence"):
        plain.labels(lambda f: (labels, confidence[:-1]))
    assert plain.label_confidence(lambda f: labels) is None


def test_labels_from_a_recording_errors(scene, tmp_path):
    q, depth, labels, mask = scene

    def make(path):
        # The label term reads the labels on every frame, not only on detected ones.
        config = {"labels_from_recording": str(path), "tracker": {"use_labels": True}}
        return create_estimator(model_path=None, body=BODY, intrinsics=INTR, config=config)

    with pytest.raises(HybridError, match="no such recording"):
        make(tmp_path / "missing")
    _write_recording(tmp_path / "plain", depth, labels, 1, with_labels=False)
    with pytest.raises(HybridError, match="has no labels"):
        make(tmp_path / "plain")
    _write_recording(tmp_path / "rec", depth, labels, 1)
    est = make(tmp_path / "rec")
    estimate_frame(est, frame_of(depth, 0, mask))
    with pytest.raises(HybridError, match="frame 1: .*out of range"):
        estimate_frame(est, frame_of(depth, 1, mask))
    est.label_source = lambda f: labels[:-1]
    with pytest.raises(ValueError, match="do not match the frame"):
        estimate_frame(est, frame_of(depth, 2, mask))


def _left_arm_labelled_chest(labels):
    """The forest calling the left arm's pixels chest: the model's arm lies on something
    else."""
    out = labels.clone()
    for part in ("upper_arm", "forearm"):
        out[labels == PART_NAMES.index(f"l_{part}")] = PART_NAMES.index("chest")
    return out


@pytest.mark.parametrize(
    "conflict, relabel, relief, searched",
    [
        (math.inf, True, 0.5, False),  # off by default
        (0.5, False, 0.5, False),  # the forest labels the shown arm as that arm
        (0.5, True, 0.5, True),
        (0.5, True, 0.0, False),  # the refit must leave no point the forest calls otherwise
    ],
)
def test_an_arm_shown_on_pixels_the_forest_calls_something_else_is_searched(
    scene, conflict, relabel, relief, searched
):
    labels = scene[2]
    seen = _left_arm_labelled_chest(labels) if relabel else labels
    cfg = cfg_of(
        arm_search_badness=1.0, misplaced_arm_conflict=conflict, misplaced_arm_relief=relief
    )
    tracker = ArmHidingTracker(shown=1.0)
    out = _second_frame_with_labels(scene, tracker, cfg, seen)
    assert ("arm_searched" in out.errors) == searched
    tried = relabel and math.isfinite(conflict)
    assert len(tracker.starts) == (8 if tried else 0)
    assert out.errors.get("arms_searched") == (1.0 if tried else None)  # taken or not
    flex = out.q[sk.DOF_NAMES.index("l_humerus_flex")]
    assert (flex == pytest.approx(ArmHidingTracker.GOOD[0], abs=1e-6)) == searched


class ArmShowingTracker(ArmHidingTracker):
    """Shows both arms fully on every frame; its refits (the arm search's starts, whose left
    abduction is zero, unlike the scene's) are counted per frame in ``refits``."""

    def __init__(self):
        super().__init__(shown=1.0)
        self.refits: list[int] = []

    def step(self, depth, mask, q_prev, q_prev2=None, labels=None):
        vis = torch.ones(4)
        if abs(float(q_prev[sk.DOF_NAMES.index("l_humerus_abd")])) > 1e-6:
            self.refits.append(0)  # the frame's track
            return FakeResult(q_prev.clone(), 2.0, 0.95, 12.0, limb_visibility=vis)
        self.refits[-1] += 1
        return FakeResult(q_prev.clone(), 1.0, 0.95, 12.0, limb_visibility=vis)


@pytest.mark.parametrize(
    "which, cooldown, refits",
    [
        ("misplaced_arm_cooldown", 0, [8, 8, 8, 8]),
        ("misplaced_arm_cooldown", 2, [8, 0, 0, 8]),
        ("arm_search_cooldown", 0, [8, 8, 8, 8]),
        ("arm_search_cooldown", 2, [8, 0, 0, 8]),  # any fruitless search of the arm waits
        ("arm_search_cooldown", 3, [8, 0, 0, 0]),
    ],
)
def test_a_misplaced_arm_search_that_finds_nothing_waits_cooldown_frames(
    scene, which, cooldown, refits
):
    q, depth, labels, mask = scene
    seen = _left_arm_labelled_chest(labels)
    # Relief 0: every refit leaves some of its points labelled otherwise, none is taken.
    cfg = cfg_of(
        arm_search_badness=1.0,
        misplaced_arm_conflict=0.5,
        misplaced_arm_relief=0.0,
        **{which: cooldown},
    )
    tracker = ArmShowingTracker()
    det = Detector(BODY, INTR, DetectorConfig(refine_iterations=0))
    est = HybridEstimator(lambda f: labels * f.mask, det, tracker, cfg)
    assert estimate_frame(est, frame_of(depth, 0, mask)).status == "detected"
    est.label_source = lambda f: seen * f.mask
    for i in range(1, 5):
        out = estimate_frame(est, frame_of(depth, i, mask))
        assert out.status == "tracked" and "arm_searched" not in out.errors
    assert tracker.refits == refits
    # A lost frame forgets the wait: the next track searches again.
    estimate_frame(est, frame_of(depth * 0, 5, torch.zeros_like(mask)))
    est.label_source = lambda f: labels * f.mask
    estimate_frame(est, frame_of(depth, 6, mask))
    est.label_source = lambda f: seen * f.mask
    estimate_frame(est, frame_of(depth, 7, mask))
    assert tracker.refits[-1] == 8


@pytest.mark.parametrize("other_arm, searched", [(True, True), (False, False)])
def test_other_arm_labels_count_against_an_arm_unless_swaps_are_forgiven(
    scene, other_arm, searched, constants
):
    labels = scene[2]
    seen = labels.clone()
    for part in ("upper_arm", "forearm"):  # the left arm's pixels labelled right arm
        seen[labels == PART_NAMES.index(f"l_{part}")] = PART_NAMES.index(f"r_{part}")
    cfg = cfg_of(
        arm_search_badness=1.0,
        misplaced_arm_conflict=0.5,
        other_arm_margin_m=0.0,
    )
    constants(OTHER_ARM_COUNTS=other_arm)
    tracker = ArmHidingTracker(shown=1.0)
    out = _second_frame_with_labels(scene, tracker, cfg, seen)
    assert (out.errors.get("arms_searched") == 1.0) == searched
    assert len(tracker.starts) == (8 if searched else 0)


def test_joint_offsets_move_the_output_joints_only(scene, tmp_path):
    """The shipped offsets move each output joint by its segment-frame offset, scaled by the
    body's stature; the pose is the one without them. A missing file is a clear error."""
    from depthmocap.runtime.hybrid import HybridError
    from depthmocap.shared.joint_offsets import JointOffsets, save_joint_offsets

    q, depth, labels, mask = scene
    _write_recording(tmp_path / "rec", depth, labels, 2)
    offsets = np.zeros((16, 3))
    offsets[2] = [0.0, 0.1, 0.0]  # the spine joint 10 cm along its segment's y
    save_joint_offsets(tmp_path / "o.json", JointOffsets(offsets, float(BODY.stature()) / 2))
    runs = {}
    for name in (None, str(tmp_path / "o.json")):
        est = create_estimator(
            model_path=None, body=BODY, intrinsics=INTR,
            config={"labels_from_recording": str(tmp_path / "rec"), "body_scale": None,
                    "joint_offsets": name},
        )  # fmt: skip
        runs[name] = [estimate_frame(est, frame_of(depth, i, mask)) for i in range(2)]
    for plain, moved in zip(runs[None], runs[str(tmp_path / "o.json")], strict=True):
        np.testing.assert_array_equal(plain.q, moved.q)
        shift = moved.joints - plain.joints
        assert np.abs(np.delete(shift, 2, axis=0)).max() < 1e-9
        assert np.linalg.norm(shift[2]) == pytest.approx(0.2, abs=1e-5)  # 10 cm x stature 2
    with pytest.raises(HybridError, match="joint_offsets.*no such"):
        create_estimator(
            model_path=None, body=BODY, intrinsics=INTR,
            config={"labels_from_recording": str(tmp_path / "rec"),
                    "joint_offsets": str(tmp_path / "missing.json")},
        )  # fmt: skip


def test_pose_dependent_offsets_follow_the_tracked_pose(scene, tmp_path):
    """A version-2 file: each output joint moves by its offset at the frame's own pose."""
    from depthmocap.shared.joint_offsets import (
        NUM_POSE_FEATURES,
        JointOffsets,
        offset_joints,
        offsets_at,
        save_joint_offsets,
    )

    q, depth, labels, mask = scene
    _write_recording(tmp_path / "rec", depth, labels, 2)
    rng = np.random.default_rng(3)
    offsets = JointOffsets(
        rng.normal(0, 0.02, (16, 3)), float(BODY.stature()),
        pose_coefficients_m=rng.normal(0, 0.01, (16, NUM_POSE_FEATURES, 3)),
    )  # fmt: skip
    save_joint_offsets(tmp_path / "o.json", offsets)
    est = create_estimator(
        model_path=None, body=BODY, intrinsics=INTR,
        config={"labels_from_recording": str(tmp_path / "rec"), "body_scale": None,
                "joint_offsets": str(tmp_path / "o.json")},
    )  # fmt: skip
    for i in range(2):
        out = estimate_frame(est, frame_of(depth, i, mask))
        pose = torch.from_numpy(out.q)[None]
        kin = forward_kinematics(pose, BODY.to(torch.float64))
        per_pose = offsets_at(
            pose, torch.from_numpy(offsets.offsets_m), torch.from_numpy(offsets.pose_coefficients_m)
        )
        want = offset_joints(named_joint_positions(kin), kin.rotations, per_pose, torch.tensor(1.0))
        np.testing.assert_allclose(out.joints, want[0].numpy(), atol=2e-5)


def test_the_shipped_offsets_load_and_a_body_file_switches_them_off():
    from depthmocap.runtime.estimator_setup import settings_for_body
    from depthmocap.runtime.hybrid import load_offsets

    assert HybridConfig().joint_offsets == "joint_offsets.json"
    assert load_offsets("joint_offsets.json").offsets_m.shape == (16, 3)
    with_body = settings_for_body({"body_scale": {}}, "hybrid", body_given=True)
    assert with_body["joint_offsets"] is None and with_body["body_scale"] is None
    assert settings_for_body({}, "hybrid", body_given=False) == {}


class _UnseenLeftArm(FakeTracker):
    """Bends the left elbow 0.1 rad more each call and calls the left elbow and wrist
    inferred; records the two poses each of the frame's own fits got."""

    def __init__(self):
        super().__init__()
        self.given = []

    def step(self, depth, mask, q_prev, q_prev2=None, labels=None):
        self.given.append((q_prev.clone(), None if q_prev2 is None else q_prev2.clone()))
        res = super().step(depth, mask, q_prev, q_prev2, labels)
        res.q[sk.DOF_NAMES.index("l_radius_flex")] += 0.1
        res.observed = torch.ones(len(sk.JOINT_NAMES), dtype=torch.bool)
        res.observed[[sk.JOINT_NAMES.index("l_elbow"), sk.JOINT_NAMES.index("l_wrist")]] = False
        return res


def _given(scene, hold: bool) -> list:
    q, depth, labels, mask = scene
    tracker = _UnseenLeftArm()
    est, _ = make_hybrid(scene, tracker, hold_unseen_limbs=hold)
    statuses = [estimate_frame(est, frame_of(depth, i, mask)).status for i in range(4)]
    assert statuses == ["detected", "tracked", "tracked", "tracked"]
    return tracker.given


def test_the_hybrid_holds_an_unseen_arm(scene):
    """With ``hold_unseen_limbs`` the pose before carries the unseen left arm's angles at the
    last pose's (no velocity); every other angle, and the option off, as before."""
    arm = [sk.DOF_NAMES.index(n) for n in
           ("l_humerus_abd", "l_humerus_flex", "l_humerus_twist", "l_radius_flex")]  # fmt: skip
    rest = torch.ones(sk.NUM_DOFS, dtype=torch.bool)
    rest[arm] = False
    elbow = sk.DOF_NAMES.index("l_radius_flex")
    held, plain = _given(scene, True), _given(scene, False)
    assert held[0][1] is None and plain[0][1] is None  # after the detection: no pose before
    for (prev, before), (prev_p, before_p) in zip(held[1:], plain[1:]):
        assert torch.equal(prev, prev_p)  # the fake tracker's poses do not depend on it
        assert torch.equal(before[arm], prev[arm])
        assert torch.equal(before[rest], before_p[rest])
        assert float(prev_p[elbow] - before_p[elbow]) > 0.05  # off: the velocity carried on


def test_a_still_chair_behind_the_legs_leaves_the_mask(scene):
    """The static-surface memory (``behind_model``) runs before the frame's estimate: a patch
    0.4 m behind the legs in the mask is dropped once it has been still behind the tracked
    body for ``static_frames`` frames, and never a body pixel."""
    q, depth, labels, mask = scene
    rows, cols = torch.nonzero(mask, as_tuple=True)
    chair = torch.zeros_like(mask)
    v0 = int(rows.float().quantile(0.55))
    chair[v0 : v0 + 12, int(cols.min()) - 6 : int(cols.max()) + 6] = True
    chair &= ~mask
    d = torch.where(chair, torch.full_like(depth, 2.9), depth)
    det = Detector(BODY, INTR, DetectorConfig(refine_iterations=2))
    trk = Tracker(BODY, INTR, TrackerConfig(iterations=3))
    cfg = HybridConfig(behind_model=BehindModelConfig(behind_m=0.12, static_frames=2))
    est = HybridEstimator(lambda f: labels * f.mask, det, trk, cfg)
    kept = []
    for i in range(5):
        frame = frame_of(d, i, mask | chair)
        assert estimate_frame(est, frame).status in ("detected", "tracked")
        kept.append(int((frame.mask & chair).sum()))
        assert bool(frame.mask[mask].all())
    # Frame 0 has no track, frame 1 none before it; counted from frame 2, dropped at frame 3.
    assert kept[:3] == [int(chair.sum())] * 3 and kept[3:] == [0, 0]


def test_a_frame_refitted_from_the_poses_after_it_leaves_the_track_alone(scene):
    """runtime.look_back's refit: frame 0 fitted backwards from the true poses of frames 1
    and 2 finds frame 0's pose; the estimator's track is not touched."""
    q, depth, labels, mask = scene
    det = Detector(BODY, INTR, DetectorConfig(refine_iterations=0))
    trk = Tracker(BODY, INTR, TrackerConfig(iterations=6))
    cfg = HybridConfig(body_scale=None, joint_offsets=None, joint_confidence=None)
    est = HybridEstimator(lambda f: labels * f.mask, det, trk, cfg)
    poses = []
    for k in range(3):
        qk = q.clone()
        qk[0] += 0.02 * k
        qk[sk.DOF_NAMES.index("r_humerus_abd")] = math.radians(8 * k)
        poses.append(qk)
    d0, _, m0 = render_labels(poses[0])

    def pose_estimate(qk):
        return PoseEstimate(qk.double().numpy(), np.zeros((16, 3)), "tracked", {})

    refit, badness = est.refit_from_later(
        frame_of(d0, 0, m0), pose_estimate(poses[1]), pose_estimate(poses[2]), 1.0
    )
    true = named_joint_positions(forward_kinematics(poses[0][None], BODY))[0].numpy()
    assert np.linalg.norm(refit.joints - true, axis=-1).max() < 0.02
    assert refit.status == "tracked" and refit.observed is not None
    assert badness == pytest.approx(est.badness_of(refit))  # its errors carry its signals
    assert badness < 1.0
    assert est.state.q_prev is None  # no track was started


def test_badness_of_an_estimate_reads_its_errors_golden(scene):
    det = Detector(BODY, INTR, DetectorConfig(refine_iterations=0))
    est = HybridEstimator(lambda f: f.mask.long(), det, FakeTracker(), HybridConfig())
    errors = {"depth_error_cm": 1.5, "overlap": 0.85, "surface_error_q97_mm": 40.0}
    # Shipped thresholds 3 cm, 0.7, 80 mm: 1.5 / 3 + 0.15 / 0.3 + 40 / 80.
    good = PoseEstimate(np.zeros(34), np.zeros((16, 3)), "detected", errors)
    assert est.badness_of(good) == pytest.approx(1.5)
    unrefined = PoseEstimate(np.zeros(34), np.zeros((16, 3)), "detected", {"ik_rms_m": 0.01})
    assert math.isnan(est.badness_of(unrefined))
