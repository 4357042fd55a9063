"""Detector (Wei 4.2) and Shotton baseline on ray-cast cylinder bodies with exact part labels."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depthmocap.runtime.detector import (
    DetectorConfig,
    DetectorError,
    DetectorEstimator,
    create_estimator,
    detect_pose,
    fit_bones,
    labels_from,
    part_markers,
)
from depthmocap.runtime.detector.meanshift_baseline import propose_joints
from depthmocap.runtime.estimator import estimate_frame, make_estimator
from depthmocap.runtime.frame import Frame
from depthmocap.runtime.raycast import part_labels, render_body
from depthmocap.runtime.streams.base import DepthFrame
from depthmocap.runtime.tracker import Tracker, TrackerConfig
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, rest_pose
from depthmocap.shared.labels import NUM_CLASSES, PART_NAMES

INTR = Intrinsics.kinect_v1(320)
BODY = BodyShape.default()
D = {n: i for i, n in enumerate(sk.DOF_NAMES)}


def render_labels(q: torch.Tensor, body: BodyShape, intr: Intrinsics = INTR):
    """Depth (H, W), exact part labels (H, W) int64 and mask of the cylinder body at q (34,)."""
    r = render_body(q[None], body, intr)
    return r.depth[0], part_labels(r, body)[0], r.mask[0]


def make_pose(name: str) -> torch.Tensor:
    q = rest_pose(1, (0.1, 0.1, 2.6))[0]
    deg = {
        "rest": {},
        "arms_raised": {"l_humerus_abd": 160, "r_humerus_abd": 150, "l_radius_flex": 20},
        "arms_crossed": {
            "l_humerus_flex": 80, "r_humerus_flex": 70, "l_humerus_abd": -30,
            "r_humerus_abd": -25, "l_radius_flex": 90, "r_radius_flex": 100,
        },
        "walk": {
            "l_femur_flex": 30, "r_femur_flex": -15, "r_tibia_flex": 40, "l_humerus_flex": -25,
            "r_humerus_flex": 30, "r_radius_flex": 45,
        },
    }[name]  # fmt: skip
    for k, v in deg.items():
        q[D[k]] = math.radians(v)
    return q


def true_joints(q: torch.Tensor, body: BodyShape = BODY) -> torch.Tensor:
    return named_joint_positions(forward_kinematics(q[None], body))[0]


@pytest.fixture(scope="module")
def refiner() -> Tracker:
    return Tracker(BODY, INTR, TrackerConfig(iterations=3))


def refine_with(tracker: Tracker, depth, mask, labels=None):
    """The refinement the estimators bind: the tracker on this frame's one observation."""
    obs = tracker.observe(depth, mask, labels)
    return lambda starts: tracker.fit_starts(obs, starts)


def detect_refined(depth, labels, mask, tracker: Tracker):
    """The detector on one rendered frame, refined by the tracker as the estimators bind it."""
    return detect_pose(
        depth,
        labels,
        INTR,
        BODY,
        DetectorConfig(),
        mask=mask,
        refine=refine_with(tracker, depth, mask),
    )


def corrupt(
    labels: torch.Tensor, fraction: float, seed: int = 1
) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    hit = (torch.rand(labels.shape, generator=g) < fraction) & (labels > 0)
    out = labels.clone()
    out[hit] = torch.randint(1, NUM_CLASSES, (int(hit.sum()),), generator=g)
    return out, hit & (out != labels)


@pytest.mark.parametrize(
    "name",
    [
        "arms_raised",
        "arms_crossed",
        pytest.param("rest", marks=pytest.mark.slow),
        pytest.param("walk", marks=pytest.mark.slow),
    ],
)
def test_detector_recovers_joints(name, refiner):
    q = make_pose(name)
    depth, labels, mask = render_labels(q, BODY)
    res = detect_refined(depth, labels, mask, refiner)
    assert res.found
    err = (res.joints - true_joints(q)).norm(dim=-1)
    assert float(err.mean()) < 0.05, err
    # The IK alone (before refinement) is already close.
    ik = true_joints(q) - named_joint_positions(forward_kinematics(res.q_ik[None], BODY))[0]
    assert float(ik.norm(dim=-1).mean()) < 0.06


def test_ransac_rejects_corrupted_labels(refiner):
    q = make_pose("arms_raised")
    depth, labels, mask = render_labels(q, BODY)
    bad_labels, wrong = corrupt(labels, 0.2)
    res = detect_refined(depth, bad_labels, mask, refiner)
    err = (res.joints - true_joints(q)).norm(dim=-1)
    assert float(err.mean()) < 0.05
    # Most wrongly labelled pixels are dropped; most correct ones survive.
    rejected = res.labels == 0
    assert float(rejected[wrong].float().mean()) > 0.6
    assert float(rejected[(labels > 0) & ~wrong].float().mean()) < 0.1


def test_missing_arm_does_not_break_it(refiner):
    q = make_pose("walk")
    depth, labels, mask = render_labels(q, BODY)
    for part in ("l_upper_arm", "l_forearm"):
        labels[labels == PART_NAMES.index(part)] = 0
    res = detect_refined(depth, labels, mask, refiner)
    assert res.found and bool(torch.isfinite(res.q).all())
    assert float(res.weights[PART_NAMES.index("l_forearm") - 1]) == 0.0
    err = (res.joints - true_joints(q)).norm(dim=-1)
    others = [i for i, n in enumerate(sk.JOINT_NAMES) if not n.startswith("l_") or "hip" in n]
    assert float(err[others].mean()) < 0.06


def test_no_person_is_not_found():
    depth = torch.zeros(INTR.height, INTR.width)
    res = detect_pose(depth, torch.zeros_like(depth, dtype=torch.long), INTR, BODY)
    assert not res.found and res.q is None


def test_posteriors_give_the_same_labels():
    labels = torch.randint(0, NUM_CLASSES, (6, 5))
    post = torch.nn.functional.one_hot(labels, NUM_CLASSES).permute(2, 0, 1).float()
    assert torch.equal(labels_from(post), labels)
    assert torch.equal(labels_from(post.permute(1, 2, 0)), labels)
    with pytest.raises(DetectorError):
        labels_from(torch.zeros(3, 4, 5))


def test_fit_bones_rejects_outliers_on_a_line():
    g = torch.Generator().manual_seed(0)
    thigh = PART_NAMES.index("l_thigh_upper")
    t = torch.rand(200, generator=g) * 0.4
    line = torch.stack([0.02 * torch.randn(200, generator=g), t, 2.5 + 0.01 * t], -1)
    outliers = torch.tensor([[0.6, 0.2, 2.5], [-0.5, 0.1, 2.4], [0.0, 0.9, 2.5]])
    points = torch.cat([line, outliers])
    labels = torch.full((203,), thigh)
    fit = fit_bones(points, labels, BODY, generator=g)
    assert bool(fit.inlier[:200].float().mean() > 0.95)
    assert not bool(fit.inlier[200:].any())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_compiled_inlier_counts_equal_torch(dtype):
    """The RANSAC scoring's compiled loop counts what the torch test counts, pair by pair,
    points on the test's borders included."""
    pytest.importorskip("numba")
    from depthmocap.runtime.detector import bone_ransac
    from depthmocap.runtime.detector.ransac_kernel import inlier_counts_cpu

    g = torch.Generator().manual_seed(3)
    K, S, P = 15, 64, 300
    sub = (torch.rand(K, P, 3, generator=g) * 0.6 + torch.tensor([0.0, 0.0, 2.5])).to(dtype)
    ok = torch.rand(K, P, generator=g) < 0.8
    a = sub[:, torch.randint(0, P, (S,), generator=g)]
    b = sub[:, torch.randint(0, P, (S,), generator=g)]
    d = (b - a).norm(dim=-1)
    u = (b - a) / d[..., None].clamp_min(1e-9)
    reach = (torch.rand(K, generator=g) * 0.3 + 0.2).to(dtype)
    max_perp = (torch.rand(K, generator=g) * 0.1 + 0.05).to(dtype)
    # Points exactly on the axial borders: t = reach and t = d - reach along a pair's line.
    sub[0, :2] = torch.stack(
        [a[0, 0] + reach[0] * u[0, 0], a[0, 0] + (d[0, 0] - reach[0]) * u[0, 0]]
    )
    ok[0, :2] = True
    want = (
        bone_ransac._inliers(
            sub[:, None], a[:, :, None], u[:, :, None], d[..., None], reach[:, None, None],
            max_perp[:, None, None],
        ) & ok[:, None]
    ).sum(-1)  # fmt: skip
    got = inlier_counts_cpu(sub, ok, a, u, d, reach, max_perp)
    assert got.dtype == torch.int64 and torch.equal(got, want)


def _rendered_points():
    """A rendered walking pose's labelled points (N, 3) and labels (N,)."""
    from depthmocap.shared.camera import depth_to_points

    depth, labels, _ = render_labels(make_pose("walk"), BODY)
    use = labels > 0
    return depth_to_points(depth[None], INTR)[0][use], labels[use]


def _scattered_points():
    """Points on a 1 cm lattice (many equal distances and scores), labels of every class, one
    class with a single point (no pair) and one with none."""
    g = torch.Generator().manual_seed(11)
    points = torch.randint(0, 40, (900, 3), generator=g).float() * 0.01 + torch.tensor(
        [0.0, 0.0, 2.5]
    )
    labels = torch.randint(1, NUM_CLASSES, (900,), generator=g)
    labels[labels == 7] = 6
    labels[0] = 7
    labels[labels == 9] = 8
    return points, labels


@pytest.mark.parametrize("make_points", [_rendered_points, _scattered_points])
def test_fit_bones_is_the_same_without_the_compiled_fit(monkeypatch, make_points):
    """The compiled RANSAC (pairs, scores, winners, inliers) is the torch fit to the bit."""
    from depthmocap.runtime.detector import bone_ransac

    points, labels = make_points()
    fits = []
    for kernel in (bone_ransac._compiled_kernel, lambda: None):
        monkeypatch.setattr(bone_ransac, "_compiled_kernel", kernel)
        fits.append(fit_bones(points, labels, BODY, generator=torch.Generator().manual_seed(5)))
    new, ref = fits
    assert torch.equal(new.inlier, ref.inlier) and torch.equal(new.score, ref.score)
    assert torch.equal(new.found, ref.found)
    assert bool(ref.found.all()) == (make_points is _rendered_points)  # bones without a pair
    assert torch.equal(new.line_point[ref.found], ref.line_point[ref.found])
    assert torch.equal(new.line_dir[ref.found], ref.line_dir[ref.found])


def test_fit_bones_of_no_points_finds_no_bone(monkeypatch):
    from depthmocap.runtime.detector import bone_ransac

    for kernel in (bone_ransac._compiled_kernel, lambda: None):
        monkeypatch.setattr(bone_ransac, "_compiled_kernel", kernel)
        fit = fit_bones(torch.zeros(0, 3), torch.zeros(0, dtype=torch.long), BODY)
        assert fit.inlier.shape == (0,) and not bool(fit.found.any())
        assert fit.score.shape == (sk.NUM_SEGMENTS,) and int(fit.score.sum()) == 0


def test_part_markers_split_halves():
    m = part_markers(BODY)
    upper, lower = PART_NAMES.index("l_thigh_upper") - 1, PART_NAMES.index("l_thigh_lower") - 1
    assert m.fraction[upper] == pytest.approx(0.25)
    assert m.fraction[lower] == pytest.approx(0.75)
    assert len(m) == NUM_CLASSES - 1


def test_shotton_baseline_on_rendered_pose():
    q = make_pose("rest")
    depth, labels, mask = render_labels(q, BODY)
    prop = propose_joints(depth, labels, INTR, BODY, mask=mask)
    assert bool(prop.found.all())
    err = (prop.joints - true_joints(q)).norm(dim=-1)
    assert float(err.mean()) < 0.08
    empty = propose_joints(torch.zeros_like(depth), labels, INTR, BODY)
    assert not bool(empty.found.any())


def test_detector_estimator_statuses():
    q = make_pose("rest")
    depth, labels, mask = render_labels(q, BODY)
    from depthmocap.runtime.detector import Detector

    est = DetectorEstimator(
        lambda d, m: labels * m, Detector(BODY, INTR, DetectorConfig(refine_iterations=0))
    )
    raw = DepthFrame(0, 0.0, (depth.numpy() * 1000).astype(np.uint16), INTR)
    out = estimate_frame(est, Frame.from_depth(raw, mask.numpy()))
    assert out.status == "detected" and out.joints.shape == (16, 3)
    assert np.linalg.norm(out.joints - true_joints(q).numpy(), axis=-1).mean() < 0.06
    empty = Frame.from_depth(raw, np.zeros_like(mask.numpy()))
    assert estimate_frame(est, empty).status == "lost"
    # Too few labelled pixels on a person: lost, from the detector itself.
    nobody = DetectorEstimator(lambda d, m: labels * 0, est.detector)
    assert nobody.estimate(Frame.from_depth(raw, mask.numpy())).status == "lost"


def test_modes_need_a_model(tmp_path):
    with pytest.raises(ValueError, match="model"):
        create_estimator(model_path=None, body=BODY, intrinsics=INTR)
    for mode in ("detector", "shotton"):
        with pytest.raises(ValueError):
            make_estimator(mode, tmp_path / "missing.npz", BODY, INTR)


def test_limb_swaps_mirror_legs_and_arms():
    from depthmocap.runtime.detector.detect import limb_swaps

    q = torch.arange(34, dtype=torch.float64)
    base, legs, arms, both = limb_swaps(q)
    assert torch.equal(base, q)
    assert legs[26] == 29 and legs[29] == 26 and legs[32] == 33 and legs[18] == 18
    assert arms[18] == 21 and arms[25] == 24 and arms[26] == 26
    assert both[26] == 29 and both[21] == 18
    assert torch.equal(limb_swaps(both)[3], q)  # swapping twice is the identity


def test_reset_limbs_is_checked():
    with pytest.raises(ValueError, match="reset_limbs"):
        DetectorConfig(reset_limbs="arms")


def test_limb_resets_set_one_limb_back_at_a_time():
    from depthmocap.runtime.detector.detect import limb_resets

    q = torch.arange(1, 35, dtype=torch.float64)
    assert limb_resets(q, "none") == []
    left_leg, right_leg = limb_resets(q, "legs")
    assert torch.equal(left_leg[[26, 27, 28, 32]], torch.zeros(4, dtype=q.dtype))
    assert torch.equal(right_leg[[29, 30, 31, 33]], torch.zeros(4, dtype=q.dtype))
    # Everything else, the other leg included, is the IK pose's.
    keep = [i for i in range(34) if i not in (26, 27, 28, 32)]
    assert torch.equal(left_leg[keep], q[keep])
    resets = limb_resets(q, "limbs")
    assert len(resets) == 4 and torch.equal(resets[0], left_leg)
    assert torch.equal(resets[2][[14, 15, 18, 19, 20, 24]], torch.zeros(6, dtype=q.dtype))
    assert torch.equal(resets[3][16:18], torch.zeros(2, dtype=q.dtype))
    assert torch.equal(q, torch.arange(1, 35, dtype=torch.float64))  # not changed in place


@pytest.mark.parametrize("use_labels", [False, True])
def test_refinement_gets_the_labels_for_the_label_term(use_labels):
    """Every limb-swap refinement is given the frame's labels; a tracker with the label term
    uses them, and the result is as good as without."""
    q = make_pose("walk")
    depth, labels, mask = render_labels(q, BODY)
    tracker = Tracker(BODY, INTR, TrackerConfig(iterations=3, use_labels=use_labels))
    obs = tracker.observe(depth, mask, labels)
    assert (obs.labels is not None) == use_labels
    seen = []

    def refine(starts):
        seen.extend(starts)
        return tracker.fit_starts(obs, starts)

    res = detect_pose(depth, labels, INTR, BODY, DetectorConfig(), mask=mask, refine=refine)
    assert len(seen) == 8  # the IK pose, its three limb swaps and its four limb resets
    assert float((res.joints - true_joints(q)).norm(dim=-1).mean()) < 0.05


@pytest.mark.parametrize("agrees", [False, True])
def test_an_ik_pose_the_caller_confirms_is_not_refined(agrees):
    """``confirm`` is asked with the IK pose before the refinement; True skips it."""
    q = make_pose("walk")
    depth, labels, mask = render_labels(q, BODY)
    asked, refined = [], []

    def confirm(q_ik):
        asked.append(q_ik)
        return agrees

    def refine(starts):
        refined.append(starts)
        return Tracker(BODY, INTR, TrackerConfig(iterations=1)).fit_starts(
            Tracker(BODY, INTR).observe(depth, mask), starts
        )

    res = detect_pose(depth, labels, INTR, BODY, DetectorConfig(), mask=mask, refine=refine,
                      confirm=confirm)  # fmt: skip
    assert len(asked) == 1 and torch.equal(asked[0], res.q_ik)
    assert res.confirmed == agrees and len(refined) == (0 if agrees else 1)
    assert (res.refined is None) == agrees
    if agrees:
        assert torch.equal(res.q, res.q_ik)
    unasked = detect_pose(depth, labels, INTR, BODY, DetectorConfig(), mask=mask, confirm=confirm)
    assert len(asked) == 1 and not unasked.confirmed  # without a refinement nothing is asked


@pytest.mark.parametrize("reset_limbs", ["none", "legs", "limbs"])
def test_a_limb_drawn_to_mislabelled_pixels_is_set_back(refiner, reset_limbs):
    """The forest labels a forearm as the left lower shank and misses the real one (as in a
    side view): the IK bends the left leg up to the forearm. The start with that leg set back
    explains the depth better, so with limb resets the leg is found where the data put it."""
    q = make_pose("rest")
    depth, labels, mask = render_labels(q, BODY)
    shank, forearm = PART_NAMES.index("l_shank_lower"), PART_NAMES.index("r_forearm")
    wrong = labels.clone()
    wrong[labels == shank] = 0
    wrong[labels == forearm] = shank
    res = detect_pose(
        depth, wrong, INTR, BODY, DetectorConfig(reset_limbs=reset_limbs), mask=mask,
        refine=refine_with(refiner, depth, mask),
    )  # fmt: skip
    ankle = sk.JOINT_NAMES.index("l_ankle")
    error = float((res.joints[ankle] - true_joints(q)[ankle]).norm())
    if reset_limbs == "none":
        assert error > 0.2  # the scene is the failure it is meant to be
    else:
        assert error < 0.05
