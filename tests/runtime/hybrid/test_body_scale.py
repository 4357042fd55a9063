"""The person's size from tracked frames (runtime.hybrid.body_scale): the grid and its peak,
the collection of frames, and the search on frames rendered from a scaled body."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from depthmocap.bench.scenes import camera_motion
from depthmocap.runtime.frame import Frame
from depthmocap.runtime.hybrid import HybridConfig, hybrid_config
from depthmocap.runtime.hybrid.body_scale import (
    BodyScaleConfig,
    BodyScaleSearch,
    fold_angle_deg,
    peak_of,
)
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker import Tracker
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import ConfigError
from depthmocap.shared.skeleton import JOINT_NAMES

INTR = Intrinsics.kinect_v1(320)


def test_the_grid():
    np.testing.assert_allclose(BodyScaleConfig().scales(), np.arange(0.84, 1.1601, 0.04))
    assert len(BodyScaleConfig(min_scale=0.9, max_scale=1.1, step=0.1).scales()) == 3
    for bad in ({"samples": 0}, {"min_scale": 1.2}, {"step": 0.0}, {"step": 1.0}):
        with pytest.raises(ConfigError):
            BodyScaleConfig(**bad)


def test_peak_of_a_parabola_is_its_vertex():
    scales = BodyScaleConfig().scales()
    for true in (0.9, 1.0, 1.03, 1.13):
        assert peak_of(scales, -((scales - true) ** 2)) == pytest.approx(true, abs=1e-9)
    assert peak_of(scales, scales) == pytest.approx(1.16)  # rising to the end: the end
    assert peak_of(scales, -scales) == pytest.approx(0.84)
    step = np.zeros_like(scales)
    step[3:6] = 1.0  # the parabola through (0.92, 0), (0.96, 1), (1.0, 1) peaks at 0.98
    assert peak_of(scales, step) == pytest.approx(0.98)


def test_refits_every_kth_frame_at_all_sizes_then_stops():
    body = BodyShape.default()
    cfg = BodyScaleConfig(
        first_at_once=False, samples=3, every=2, correction=1.0, interim_after=None
    )
    search = BodyScaleSearch(cfg, body)
    stature = float(body.stature())
    seen = []

    def fit(bodies, frame, q):  # overlap peaking at the body 8% taller than the default
        seen.append(frame)
        return -((bodies.stature().numpy() / stature - 1.08) ** 2)

    found = [search.offer(f"frame{i}", torch.full((34,), float(i)), fit) for i in range(10)]
    assert seen == ["frame0", "frame2", "frame4"]  # refitted as they come, no stall at the end
    assert found[:4] == [None] * 4 and found[5:] == [None] * 5
    assert found[4] == pytest.approx(1.08, abs=1e-6) and search.scale == found[4]
    assert search.bodies.lengths.shape == (len(search.factors), 15)
    bad = BodyScaleSearch(BodyScaleConfig(every=1, first_at_once=False), body)
    bad.offer("f", torch.zeros(34), lambda *a: [1.0])  # read at the next sample
    with pytest.raises(ValueError, match="overlaps"):
        bad.offer("g", torch.zeros(34), lambda *a: [1.0])
    at_once = BodyScaleSearch(BodyScaleConfig(every=1, first_at_once=True), body)
    with pytest.raises(ValueError, match="overlaps"):
        at_once.offer("f", torch.zeros(34), lambda *a: [1.0])


def test_samples_on_a_thread_give_the_inline_size_on_the_same_frame():
    """A Future of the overlaps gives the same size on the same frame as the overlaps
    themselves (each sample read at the next one taken, the last at once), and its failure
    reaches the caller when the sample is read."""
    from concurrent.futures import ThreadPoolExecutor

    body = BodyShape.default()
    stature = float(body.stature())

    def fit(bodies, frame, q):
        return -((bodies.stature().numpy() / stature - 0.9 - 0.01 * frame) ** 2)

    cfg = BodyScaleConfig(
        first_at_once=False, samples=4, every=3, correction=1.0, interim_after=None
    )
    inline = BodyScaleSearch(cfg, body)
    found_inline = [inline.offer(i, torch.zeros(34), fit) for i in range(16)]
    with ThreadPoolExecutor(1) as worker:
        threaded = BodyScaleSearch(cfg, body)
        found = [
            threaded.offer(i, torch.zeros(34), lambda b, f, q: worker.submit(fit, b, f, q))
            for i in range(16)
        ]
        assert found == found_inline and found[9] is not None  # samples 0, 3, 6, 9: found at 9
        assert threaded.scale == pytest.approx(0.9 + 0.01 * 4.5, abs=0.01)
        np.testing.assert_array_equal(np.stack(threaded.curves), np.stack(inline.curves))

        def broken(bodies, frame, q):
            raise RuntimeError("refit failed")

        failing = BodyScaleSearch(BodyScaleConfig(first_at_once=False, samples=2, every=1), body)
        assert failing.offer(0, torch.zeros(34), lambda *a: worker.submit(broken, *a)) is None
        with pytest.raises(RuntimeError, match="refit failed"):
            failing.offer(1, torch.zeros(34), fit)


def test_interim_sizes_from_the_samples_read_so_far():
    """With ``interim_after`` k, each sampled frame once k samples are read returns the size
    of those samples (the one being refitted not waited for); the final size is the same as
    without interim sizes, on the same frame."""
    body = BodyShape.default()
    stature = float(body.stature())
    peaks = [1.10, 1.02, 0.98, 1.06]  # each sample's overlaps peak at its own size

    def fit(bodies, frame, q):
        return -((bodies.stature().numpy() / stature - peaks[frame // 2]) ** 2)

    def run(**kw):
        search = BodyScaleSearch(
            BodyScaleConfig(first_at_once=False, samples=4, every=2, **kw), body
        )
        return search, [search.offer(i, torch.zeros(34), fit) for i in range(10)]

    plain, found_plain = run(interim_after=None)
    search, found = run(interim_after=1)
    # Frames 0, 2, 4, 6 are sampled; at frame 2 the sample of frame 0 is read, and so on.
    assert found[0] is None and found[1] is None and found[3] is None and found[5] is None
    assert found[2] == pytest.approx(1.10, abs=1e-6)
    assert found[4] == pytest.approx(1.06, abs=0.005)  # the peak of the mean of two curves
    assert search.interim == found[4]
    assert found[6] == found_plain[6] == search.scale and found[7:] == [None] * 3
    _, later = run(interim_after=2)
    assert later[2] is None and later[4] == found[4]
    _, never = run(interim_after=4)  # as many as the samples: only the final size
    assert never == found_plain
    assert BodyScaleConfig().interim_after == 1  # shipped
    with pytest.raises(ConfigError):
        BodyScaleConfig(first_at_once=False, samples=4, interim_after=0)


def test_the_first_sample_read_at_once():
    """With ``first_at_once`` the first sample is read when it is taken: its size is returned
    on that frame, a sampling period sooner; later samples are read as before and the final
    size is the same, on the same frame."""
    body = BodyShape.default()
    stature = float(body.stature())
    peaks = [1.10, 1.02, 0.98, 1.06]

    def fit(bodies, frame, q):
        return -((bodies.stature().numpy() / stature - peaks[frame // 2]) ** 2)

    def run(**kw):
        search = BodyScaleSearch(BodyScaleConfig(samples=4, every=2, **kw), body)
        return search, [search.offer(i, torch.zeros(34), fit) for i in range(10)]

    _, later = run()
    search, found = run(first_at_once=True)
    assert found[0] == pytest.approx(1.10, abs=1e-6) and later[0] is None
    # Frame 2 reads nothing new (sample 0 is in, sample 2 in flight): the same size again.
    assert found[2] == found[0] and found[4] == later[4] and found[6] == later[6] == search.scale
    assert [found[k] for k in (1, 3, 5, 7, 8, 9)] == [None] * 6
    _, alone = run(first_at_once=True, interim_after=None)  # no interim sizes: nothing early
    assert alone[:6] == [None] * 6 and alone[6] == search.scale
    with pytest.raises(ConfigError, match="sample_detection"):
        BodyScaleConfig(sample_detection=True)  # needs first_at_once: said, not ignored
    wants = BodyScaleSearch(BodyScaleConfig(first_at_once=True, sample_detection=True), body)
    assert wants.wants_detection and not search.wants_detection
    wants.offer(0, torch.zeros(34), fit)
    assert not wants.wants_detection  # only before the first sample
    single = BodyScaleSearch(BodyScaleConfig(samples=1, first_at_once=True), body)
    assert single.offer(0, torch.zeros(34), fit) == single.scale == pytest.approx(1.10, abs=1e-6)


def test_no_interim_size_after_a_folded_sample():
    """A sample of a folded body (seated, crouched) stops the interim sizes: the body stays
    until the final size, which still counts every sample."""
    body = BodyShape.default()
    stature = float(body.stature())
    standing = _stick_figure((0, 1, 0), (0, 1, 0))
    seated = _stick_figure((0, 0, -1), (0, 0, -1))

    def fit(bodies, frame, q):
        return -((bodies.stature().numpy() / stature - 1.0 - 0.02 * frame) ** 2)

    def run(poses, **kw):
        search = BodyScaleSearch(
            BodyScaleConfig(first_at_once=False, samples=4, every=1, **kw), body
        )
        return [search.offer(i, torch.zeros(34), fit, j) for i, j in enumerate(poses)]

    upright = run([standing] * 5)
    assert [f is not None for f in upright] == [False, True, True, True, False]
    sits = run([standing, standing, seated, standing, standing])
    assert sits[1] == upright[1] and sits[2] is None and sits[3] == upright[3]  # final kept
    starts_seated = run([seated] + [standing] * 4)
    assert starts_seated[:3] == [None] * 3 and starts_seated[3] == upright[3]
    assert run([seated] * 5, interim_max_fold_deg=None) == upright  # the gate off
    with pytest.raises(ConfigError):
        BodyScaleConfig(interim_max_fold_deg=0.0)


def _demo_hybrid(stream, config: dict, background: bool):
    """The shipped hybrid with ``config`` over it for ``stream``, its size refits on a worker
    thread or inline."""
    from depthmocap.runtime.estimator import make_estimator
    from depthmocap.runtime.estimator_setup import load_body
    from depthmocap.runtime.forest.inference import DEFAULT_MODEL
    from depthmocap.runtime.hybrid import HybridEstimator

    shipped = make_estimator(
        "hybrid", DEFAULT_MODEL, load_body(None), stream.intrinsics, "cpu", config
    )
    return HybridEstimator(
        shipped.label_source, shipped.detector, shipped.tracker, shipped.cfg,
        shipped.offsets, background=background,
    )  # fmt: skip


def _demo_runs(config: dict, frames: int, before=None) -> list[tuple]:
    """The shipped hybrid with ``config`` over the demo's first ``frames`` frames, its size
    refits on a worker thread and then inline: for each run the estimator, its body's stature
    before the first frame and per frame (estimate, stature after it, interim factor).
    ``before(est)`` runs on each estimator before its first frame."""
    from depthmocap.runtime.estimator import estimate_frame, prepare_frame
    from depthmocap.runtime.segmentation import PersonSegmenter, SegmentationConfig
    from depthmocap.runtime.streams import open_stream

    runs = []
    for background in (True, False):
        segment = PersonSegmenter(SegmentationConfig())
        with open_stream("demo") as stream:
            est = _demo_hybrid(stream, config, background)
            if before is not None:
                before(est)
            base = float(est.body.stature())
            steps = []
            for k, frame in enumerate(stream):
                if k == frames:
                    break
                estimate = estimate_frame(est, prepare_frame(est, frame, segment))
                steps.append((estimate, float(est.body.stature()), est.scale_search.interim))
            runs.append((est, base, steps))
    return runs


def test_the_hybrid_tracks_with_the_interim_sizes(one_thread):
    """On the demo the hybrid moves its tracker to each interim size and then the final one,
    each the search's own body scaled (not a scaled body scaled again), and the arm search
    keeps its memory across the changes; background and inline runs agree."""
    config = {"body_scale": {"samples": 3, "every": 1, "min_scale": 0.9, "max_scale": 1.1,
                             "step": 0.1, "interim_after": 1, "iterations": 2,
                             "first_at_once": False}}  # fmt: skip

    def remember(est):
        est.arm_search.failed_at["left"] = -5  # a memory that must survive the changes

    runs = []
    for est, base, steps in _demo_runs(config, 6, remember):
        assert est.arm_search.failed_at.get("left") == -5
        for other in (est.arm_search.body, est.detector.body):
            torch.testing.assert_close(other.lengths, est.body.lengths)
        search = est.scale_search
        runs.append(([s for _, s, _ in steps], [e.q for e, _, _ in steps], search.scale,
                     search.interim, base))  # fmt: skip
    (statures, poses, scale, interim, base_stature), inline = runs
    # Frame 0 detected; samples at 1, 2, 3: an interim size at 2 (sample 1 read), then 3 final.
    assert statures[:2] == [base_stature] * 2
    assert interim is not None and statures[2] == pytest.approx(base_stature * interim, rel=1e-5)
    assert statures[3] == pytest.approx(base_stature * scale, rel=1e-5)
    assert statures[3:] == [statures[3]] * 3
    assert (statures, scale, interim) == (inline[0], inline[2], inline[3])
    for a, b in zip(poses, inline[1], strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "use", [{"extent_check": 1e-9}, {"extent_check": None, "extent_sizes": True}]
)
def test_the_hybrid_measures_the_extent_on_its_frames_and_uses_it(one_thread, use):
    """The hybrid hands the size search the extents of the demo's upright frames (read off
    each frame's mask along the tracked torso) and, with a tolerance too tight to keep the
    search's size or with ``extent_sizes``, tracks at the extents' size from the frame that
    reads them; the search then ends. Background and inline runs agree."""
    config = {"body_scale": {"samples": 3, "every": 1, "min_scale": 0.8, "max_scale": 1.2,
                             "step": 0.1, "iterations": 2, "first_at_once": False,
                             "extent_frames": 2, **use}}  # fmt: skip
    runs = []
    for est, base, steps in _demo_runs(config, 8):
        search = est.scale_search
        assert search.extent_scale is not None and len(search.extents) == 2
        assert not search.searching and est._worker is None
        assert 0.8 <= search.scale <= 1.2
        assert search.scale == pytest.approx(min(max(search.extent_scale, 0.8), 1.2))
        assert steps[-1][1] == pytest.approx(base * search.scale, rel=1e-5)
        runs.append(([s for _, s, _ in steps], search.extents, search.scale))
    assert runs[0] == runs[1]


@pytest.mark.parametrize("sample_detection", [True, False])
def test_the_hybrid_reads_its_first_sample_at_once(one_thread, sample_detection):
    """With ``first_at_once`` the first sample is read when taken: with ``sample_detection``
    that is the detection starting the track (the first tracked frame is tracked at its
    size), otherwise the first tracked frame (the second on); inline and worker agree."""
    config = {"body_scale": {"samples": 3, "every": 2, "min_scale": 0.9, "max_scale": 1.1,
                             "step": 0.1, "iterations": 2, "first_at_once": True,
                             "sample_detection": sample_detection}}  # fmt: skip
    runs = [
        ([e.status for e, _, _ in steps], [s for _, s, _ in steps], [i for _, _, i in steps],
         base)
        for _, base, steps in _demo_runs(config, 3)
    ]  # fmt: skip
    (status, statures, interims, base), inline = runs
    assert status[:2] == ["detected", "tracked"]
    first = 0 if sample_detection else 1  # the frame whose size is read at once
    assert interims[:first] == [None] * first and interims[first] not in (None, 1.0)
    assert statures[:first] == [base] * first
    assert statures[first] == pytest.approx(base * interims[first], rel=1e-5)
    assert (status, statures, interims, base) == inline


def _stick_figure(l_thigh, r_thigh) -> np.ndarray:
    """(J, 3) joints of an upright torso (camera y down) with the thighs along the given
    directions; the other joints are not read."""
    j = np.zeros((len(JOINT_NAMES), 3))
    at = {n: k for k, n in enumerate(JOINT_NAMES)}
    j[at["neck"]] = (0.0, -0.5, 3.0)
    j[at["pelvis"]] = (0.0, 0.0, 3.0)
    for side, thigh in (("l", l_thigh), ("r", r_thigh)):
        hip = np.array((0.1 if side == "l" else -0.1, 0.0, 3.0))
        j[at[f"{side}_hip"]] = hip
        j[at[f"{side}_knee"]] = hip + 0.4 * np.asarray(thigh, dtype=float)
    return j


def test_fold_angle_of_standing_seated_and_one_raised_leg():
    down, forward = (0, 1, 0), (0, 0, -1)  # towards the camera
    diagonal = (0, np.sqrt(0.5), -np.sqrt(0.5))
    assert fold_angle_deg(_stick_figure(down, down)) == pytest.approx(0.0, abs=1e-6)
    assert fold_angle_deg(_stick_figure(forward, forward)) == pytest.approx(90.0)
    assert fold_angle_deg(_stick_figure(forward, down)) == pytest.approx(0.0, abs=1e-6)  # kick
    assert fold_angle_deg(_stick_figure(forward, diagonal)) == pytest.approx(45.0)
    batch = np.stack([_stick_figure(down, down), _stick_figure(forward, forward)])[None]
    np.testing.assert_allclose(fold_angle_deg(batch), [[0.0, 90.0]], atol=1e-6)  # (1, 2)
    assert np.isnan(fold_angle_deg(_stick_figure((0, 0, 0), (0, 0, 0))))


def test_a_folded_body_is_not_sampled_nor_counted():
    body = BodyShape.default()
    cfg = BodyScaleConfig(
        first_at_once=False, samples=2, every=2, correction=1.0, max_fold_deg=60.0
    )
    search = BodyScaleSearch(cfg, body)
    seen = []

    def fit(bodies, frame, q):
        seen.append(frame)
        return -((bodies.stature().numpy() / float(body.stature()) - 1.0) ** 2)

    seated = _stick_figure((0, 0, -1), (0, 0, -1))
    standing = _stick_figure((0, 1, 0), (0, 1, 0))
    poses = [seated] * 3 + [standing] * 3 + [seated, standing]
    found = [search.offer(i, torch.zeros(34), fit, j) for i, j in enumerate(poses)]
    assert seen == [3, 5]  # every 2nd unfolded frame
    assert found[5] == pytest.approx(1.0, abs=1e-6) and found[:5] == [None] * 5
    free = BodyScaleSearch(BodyScaleConfig(first_at_once=False, samples=1, max_fold_deg=None), body)
    assert free.offer(0, torch.zeros(34), fit, seated) is not None  # the check switched off
    with pytest.raises(ConfigError):
        BodyScaleConfig(max_fold_deg=0.0)


def test_on_in_the_shipped_system_and_off_by_config():
    assert HybridConfig().body_scale == BodyScaleConfig()
    assert hybrid_config({"body_scale": {}}).body_scale == BodyScaleConfig()
    assert hybrid_config({"body_scale": None}).body_scale is None


@pytest.mark.slow
@pytest.mark.parametrize("true_scale", [0.9, 1.1])
def test_the_search_finds_the_size_of_a_rendered_person(one_thread, true_scale):
    """Frames rendered from the default body scaled by ``true_scale``, tracked poses given;
    the search with the tracker's batched refits recovers the factor."""
    default = BodyShape.default()
    person = default.scaled(true_scale)
    truth = camera_motion("walk", 24, seed=0, body=person).float()
    depth = render_body(truth, person, INTR).depth
    # The size alone: the person is the default body scaled, and ``fit`` keeps one tracker.
    cfg = BodyScaleConfig(first_at_once=False, samples=6, every=4, correction=1.0, girths=(1.0,))
    search = BodyScaleSearch(cfg, default)
    trackers: dict = {}

    def fit(bodies, frame, q):  # as the hybrid does: one batched fit of all sizes
        tracker = trackers.setdefault("sizes", Tracker(bodies, INTR))
        starts = q[None].expand(bodies.lengths.shape[0], -1)
        return [r.overlap for r in tracker.fit_starts(frame.observation(tracker), starts, 5)]

    found = [
        search.offer(Frame(i, i / 30, depth[i], depth[i] > 0, INTR), truth[i], fit)
        for i in range(len(truth))
    ]
    assert found[20] == pytest.approx(true_scale, abs=0.03)  # the 6th frame taken, every 4th
    assert found[20] == search.scale and found[21:] == [None] * 3
    # Interim sizes at the frames taken after the first, from the samples read before them.
    interim = [f for i, f in enumerate(found[:20]) if f is not None]
    assert [i for i, f in enumerate(found[:20]) if f is not None] == [4, 8, 12, 16]
    assert interim[-1] == pytest.approx(true_scale, abs=0.03)


@pytest.mark.slow
def test_runtime_track_with_the_search_on(tmp_path, one_thread):
    """End to end: the factor is reported, and body.json and the BVH's skeleton are the
    scaled default body; a given body file switches the search off."""
    import json

    import depthmocap.runtime.track_cli as cli
    from depthmocap.runtime.estimator_setup import POPULATION_BODY
    from depthmocap.runtime.export.bvh import bvh_hierarchy

    cfg = tmp_path / "scale.yaml"
    cfg.write_text(
        "body_scale: {samples: 2, every: 1, min_scale: 0.9, max_scale: 1.1, step: 0.1}\n"
    )
    out = tmp_path / "out"
    assert cli.main(["-i", "demo", "-o", str(out), "--stop", "12", "-q", "--config", str(cfg)]) == 0
    scale = json.loads((out / "summary.json").read_text())["extra"]["body_scale"]
    assert 0.9 <= scale <= 1.1
    body = BodyShape.load(out / "body.json")
    population = BodyShape.load(POPULATION_BODY)  # the body tracked without a file
    girth = json.loads((out / "summary.json").read_text())["extra"]["body_girth"]
    assert girth in BodyScaleConfig().girths  # the shipped girths, the preset's
    torch.testing.assert_close(body.lengths, population.scaled(scale).lengths)
    torch.testing.assert_close(body.radii, population.scaled(scale).girthed(girth).radii)
    assert bvh_hierarchy(body.to(torch.float64)) in (out / "motion.bvh").read_text()
    with_body = tmp_path / "with_body"
    args = ["-i", "demo", "-o", str(with_body), "--stop", "4", "-q", "--config", str(cfg)]
    assert cli.main([*args, "--body", str(out / "body.json")]) == 0
    summary = json.loads((with_body / "summary.json").read_text())
    assert summary["extra"]["body_scale"] is None and summary["extra"]["body_girth"] is None
    assert summary["extra"]["settings"]["body_scale"] is None


def test_the_correction_multiplies_the_peak_and_the_curves_are_kept():
    body = BodyShape.default()
    search = BodyScaleSearch(
        BodyScaleConfig(first_at_once=False, samples=2, every=1, correction=1.05), body
    )
    stature = float(body.stature())

    def fit(bodies, frame, q):
        return -((bodies.stature().numpy() / stature - 0.96) ** 2)

    found = [search.offer(i, torch.zeros(34), fit) for i in range(2)]
    assert search.peak == pytest.approx(0.96, abs=1e-6)
    assert found[1] == pytest.approx(0.96 * 1.05, abs=1e-6) and search.scale == found[1]
    G, S = len(search.girths), len(search.factors)
    assert len(search.curves) == 2 and search.curves[0].shape == (G * S,)  # girth-major
    with pytest.raises(ConfigError):
        BodyScaleConfig(correction=0.0)


def test_the_corrected_size_stays_within_the_grid():
    body = BodyShape.default()
    search = BodyScaleSearch(
        BodyScaleConfig(first_at_once=False, samples=1, every=1, correction=1.1), body
    )
    found = search.offer(0, torch.zeros(34), lambda bodies, f, q: bodies.stature().numpy())
    assert search.peak == pytest.approx(1.16) and found == pytest.approx(1.16)


@pytest.mark.slow
def test_the_hybrid_sizes_on_its_worker_thread_as_inline(one_thread):
    """The shipped hybrid's size refits on its worker thread give the inline run's size on
    the same frame and the same poses (the demo, a short search)."""
    from depthmocap.runtime.estimator import estimate_frame, prepare_frame
    from depthmocap.runtime.segmentation import PersonSegmenter, SegmentationConfig
    from depthmocap.runtime.streams import open_stream

    config = {"body_scale": {"samples": 2, "every": 2, "min_scale": 0.9, "max_scale": 1.1,
                             "step": 0.1, "first_at_once": False}}  # fmt: skip
    runs = []
    for background in (True, False):
        segment = PersonSegmenter(SegmentationConfig())
        poses, scales = [], []
        with open_stream("demo") as stream:
            est = _demo_hybrid(stream, config, background)
            assert (est._worker is not None) == background
            for k, frame in enumerate(stream):
                if k == 8:
                    break
                estimate = estimate_frame(est, prepare_frame(est, frame, segment))
                poses.append(estimate.q)
                scales.append(est.body_scale)
        runs.append((poses, scales))
    (poses_bg, scales_bg), (poses_in, scales_in) = runs
    assert scales_bg == scales_in and scales_bg[-1] is not None
    assert scales_bg.index(scales_bg[-1]) == 3  # frame 0 detected; samples at 1 and 3
    for a, b in zip(poses_bg, poses_in, strict=True):
        np.testing.assert_array_equal(a, b)


def _sized_by_pose(body: BodyShape):
    """A ``fit`` whose overlaps peak at 1.12 on a seated frame's refits and at 0.96 on a
    standing one's (a seated person sized too large), recording the frames it refits."""
    stature, seen = float(body.stature()), []

    def fit(bodies, frame, q):
        seen.append(frame)
        peak = 1.12 if frame.startswith("seated") else 0.96
        return -((bodies.stature().numpy() / stature - peak) ** 2)

    return fit, seen


def test_upright_extents_replace_a_size_they_disagree_with():
    """Seated samples size the body at 1.12; the extents of upright frames give 0.96 and
    replace it once ``extent_frames`` are in; extents within the tolerance leave it."""
    body = BodyShape.default()
    stature = float(body.stature())
    seated = _stick_figure((0, 0, -1), (0, 0, -1))

    def run(extent_factor, **kw):
        cfg = BodyScaleConfig(
            first_at_once=False, samples=3, every=1, interim_after=None, extent_frames=2,
            extent_ratio=0.9, **kw,
        )  # fmt: skip
        search, fit = BodyScaleSearch(cfg, body), _sized_by_pose(body)[0]
        extent = 0.9 * extent_factor * stature  # what an upright person of that size shows
        frames = [("seated", None)] * 4 + [("standing", extent)] * 3
        found = [
            search.offer(f"{n}{i}", torch.zeros(34), fit, seated, e)
            for i, (n, e) in enumerate(frames)
        ]
        return search, found

    search, found = run(0.96, extent_check=0.06)
    assert found[2] == pytest.approx(1.12, abs=1e-6) and found[3:5] == [None, None]
    assert found[5] == pytest.approx(0.96, rel=1e-6) == search.scale == search.extent_scale
    assert not search.searching and found[6] is None
    search, found = run(1.08, extent_check=0.06)  # 3.6% from 1.12: kept
    assert search.scale == pytest.approx(1.12, abs=1e-6) and found[3:] == [None] * 4
    assert search.extent_scale == pytest.approx(1.08, rel=1e-6) and not search.searching
    search, found = run(0.5, extent_check=0.06)  # beyond the grid: its end
    assert found[5] == pytest.approx(0.84)
    search, found = run(0.96, extent_check=None)  # no check: the search ends with its size
    assert not search.searching and search.extent_scale is None and found[3:] == [None] * 4
    for bad in ({"extent_check": 0.0}, {"extent_frames": 0}, {"extent_ratio": 1.2}):
        with pytest.raises(ConfigError):
            BodyScaleConfig(**bad)


def test_upright_extents_size_the_body_before_or_after_the_search():
    """With ``extent_sizes`` the extents' size is taken whatever the search says: on the
    frame the ``extent_frames``-th upright extent comes, ending a search still running (its
    refits in flight are not read), or after the search has ended, even within the check's
    tolerance. The ratio read is ``extent_ratio``."""
    body = BodyShape.default()
    stature = float(body.stature())
    standing = _stick_figure((0, 0, -1), (0, 0, -1))
    cfg = dict(first_at_once=False, samples=3, every=1, interim_after=None, extent_frames=2,
               extent_ratio=0.9, extent_sizes=True)  # fmt: skip

    def run(frames, extent_factor=1.04):
        search, (fit, seen) = BodyScaleSearch(BodyScaleConfig(**cfg), body), _sized_by_pose(body)
        extent = 0.9 * extent_factor * stature
        found = [
            search.offer(f"f{i}", torch.zeros(34), fit, standing, extent if up else None)
            for i, up in enumerate(frames)
        ]
        return search, found, seen

    search, found, seen = run([True, True, False, False, False])  # upright from the start
    assert found[0] is None and found[1] == pytest.approx(1.04, rel=1e-6)
    assert search.scale == found[1] == search.extent_scale and search.peak is None
    assert not search.searching and found[2:] == [None] * 3 and seen == ["f0"]
    search, found, seen = run([False, False, False, True, True, True])  # the search first
    assert found[2] is not None and found[2] != pytest.approx(1.04)
    assert found[3] is None and found[4] == pytest.approx(1.04, rel=1e-6)
    assert not search.searching and found[5] is None and len(seen) == 3
    search, found, _ = run([False] * 3 + [True] * 2, extent_factor=found[2] * 1.01)
    assert found[4] == pytest.approx(search.extent_scale) and search.scale == found[4]
    search, found, _ = run([False] * 6)  # never upright: the search's size stands
    assert search.searching and search.scale == found[2] and found[3:] == [None] * 3
    with pytest.raises(ConfigError):
        BodyScaleConfig(extent_ratio=0.4)


def test_the_search_finds_a_girth_with_the_size():
    """With two girths the search refits G x S bodies, girth-major, and returns the size
    peaked within the girth whose best overlap is highest; ``sized_body`` is the default
    body at that size and girth. One girth of 1.0 is the search without girths."""
    body = BodyShape.default()
    stature = float(body.stature())
    radius = float(body.radii[0, 0])
    cfg = dict(first_at_once=False, samples=2, every=1, interim_after=None, extent_check=None)

    def fit(bodies, frame, q):  # peaks at size 0.96 and girth 1.2 (radius / size / radius)
        size = bodies.stature().numpy() / stature
        girth = bodies.radii[:, 0, 0].numpy() / (radius * size)
        return -((size - 0.96) ** 2) - 0.1 * (girth - 1.2) ** 2

    search = BodyScaleSearch(BodyScaleConfig(girths=(1.0, 1.2), girth_samples=None, **cfg), body)
    S = len(search.factors)
    assert search.bodies.lengths.shape[0] == 2 * S
    torch.testing.assert_close(search.bodies.lengths[:S], search.bodies.lengths[S:])
    torch.testing.assert_close(search.bodies.radii[S:], 1.2 * search.bodies.radii[:S])
    found = [search.offer(f"f{i}", torch.zeros(34), fit) for i in range(3)]
    assert found[1] == pytest.approx(0.96, abs=1e-6) and search.girth == 1.2
    sized = search.sized_body(found[1])
    torch.testing.assert_close(sized.radii, body.radii * 0.96 * 1.2)
    torch.testing.assert_close(sized.stature(), body.stature() * 0.96)
    plain = BodyScaleSearch(BodyScaleConfig(girths=(1.0,), **cfg), body)
    assert plain.bodies.lengths.shape[0] == S
    found = [plain.offer(f"f{i}", torch.zeros(34), fit) for i in range(3)]
    assert found[1] == pytest.approx(0.96, abs=1e-6) and plain.girth == 1.0
    torch.testing.assert_close(plain.sized_body(found[1]).radii, body.radii * 0.96)
    for bad in ({"girths": ()}, {"girths": (1.0, 3.0)}):
        with pytest.raises(ConfigError):
            BodyScaleConfig(**bad)


def test_the_girth_kept_after_girth_samples():
    """With ``girth_samples`` the search refits every girth for that many samples, keeps the
    one whose best mean overlap is highest, and refits its sizes alone after: the size is
    peaked over all samples of that girth, the other girths' curves NaN from then on. Without
    it (None) every sample refits every girth and the girth may change."""
    body = BodyShape.default()
    stature = float(body.stature())
    radius = float(body.radii[0, 0])
    calls = []

    def fit(bodies, frame, q):  # girth 1.2 best on f0, 1.0 on later frames; size 0.96 / 1.0
        calls.append(bodies.lengths.shape[0])
        size = bodies.stature().numpy() / stature
        girth = bodies.radii[:, 0, 0].numpy() / (radius * size)
        best, at = (1.2, 0.96) if frame == "f0" else (1.0, 1.0)
        return -((size - at) ** 2) - 0.5 * (girth - best) ** 2

    cfg = dict(first_at_once=False, samples=4, every=1, interim_after=1, extent_check=None)
    search = BodyScaleSearch(BodyScaleConfig(girths=(1.0, 1.2), girth_samples=1, **cfg), body)
    S = len(search.factors)
    found = [search.offer(f"f{i}", torch.zeros(34), fit) for i in range(4)]
    assert calls == [2 * S, S, S, S]  # the girth is kept once f0's overlaps are read
    assert search.girth == 1.2 and search.bodies.lengths.shape[0] == S
    torch.testing.assert_close(search.bodies.radii, search._all.radii[S:])
    assert np.isnan(search.curves[1][:S]).all() and np.isfinite(search.curves[1][S:]).all()
    # The size: the peak of the mean of 4 quadratics at girth 1.2 (0.96 once, 1.0 thrice).
    assert found[1] == pytest.approx(0.96, abs=1e-6) and found[-1] == pytest.approx(0.99, abs=1e-6)
    calls.clear()
    free = BodyScaleSearch(BodyScaleConfig(girths=(1.0, 1.2), girth_samples=None, **cfg), body)
    [free.offer(f"f{i}", torch.zeros(34), fit) for i in range(4)]
    assert calls == [2 * S] * 4 and free.girth == 1.0
    with pytest.raises(ConfigError):
        BodyScaleConfig(girth_samples=0)


@pytest.mark.parametrize("girth_samples", [None, 1])
def test_the_hybrid_tracks_at_the_girth_found(one_thread, girth_samples):
    """With girths the hybrid tracks at the search's size and girth: its body's radii are the
    default body's times both, its stature the size's alone; background and inline agree.
    With the girth kept after the first sample, the second refits that girth's sizes only,
    on trackers rebuilt for them."""
    config = {"body_scale": {"samples": 2, "every": 1, "iterations": 2, "first_at_once": False,
                             "girths": [1.0, 1.15], "extent_check": None,
                             "girth_samples": girth_samples}}  # fmt: skip
    runs = []
    for est, base, steps in _demo_runs(config, 4):
        search = est.scale_search
        assert search.scale is not None and search.girth in (1.0, 1.15)
        assert len(search.curves[0]) == 2 * len(search.factors)
        not_refitted = 0 if girth_samples is None else len(search.factors)
        assert np.isnan(search.curves[1]).sum() == not_refitted
        torch.testing.assert_close(est.body.radii, search.body.radii * search.scale * search.girth)
        assert steps[-1][1] == pytest.approx(base * search.scale, rel=1e-5)
        runs.append((search.scale, search.girth, [s for _, s, _ in steps]))
    assert runs[0] == runs[1]
