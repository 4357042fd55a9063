"""The broad dev protocol (train.evaluation.protocol): a deterministic spec that covers the
variety it promises, cameras that see (or cut) what they should, and its CLI's errors."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import ConfigError, load_config
from depthmocap.shared.labels import PART_NAMES
from depthmocap.train.evaluation.protocol import (
    PROTOCOL_VERSION,
    BroadProtocolConfig,
    camera_at,
    joints_outside,
    motion_class,
    place_camera,
    protocol_variants,
    recorded_camera,
)
from depthmocap.train.synth.sequence import OutOfRangeError

REPO = Path(__file__).resolve().parents[3]
# The dev takes' layout: ten classes, 40 takes (train.evaluation.dev_recordings.all_dev_clips).
TAKES = {"depositFloorR": 8, "elbowToKnee1RepsLelbowStart": 2, "grabHighR": 6,
         "hopBothLegs1hops": 3, "jogLeftCircle4StepsRstart": 3, "kickLFront1Reps": 6,
         "rotateArmsBothBackward1Reps": 3, "sneak2StepsLStart": 3, "squat1Reps": 4,
         "throwBasketball": 2}  # fmt: skip
CLIPS = [f"HDM_mm_{c}_{10 + i:03d}_120.amc" for c, n in TAKES.items() for i in range(n)]


@pytest.fixture(scope="module")
def variants():
    return protocol_variants(BroadProtocolConfig(), CLIPS)


def test_same_seed_same_variants_and_another_seed_others(variants):
    assert protocol_variants(BroadProtocolConfig(), list(reversed(CLIPS))) == variants
    other = protocol_variants(BroadProtocolConfig(seed=38), CLIPS)
    assert [v.name for v in other] == [v.name for v in variants]
    assert [v.phenotype for v in other] != [v.phenotype for v in variants]


def test_the_preset_is_the_frozen_spec():
    """configs/dev_broad.yaml repeats the version-1 defaults: changing either is a new version."""
    assert load_config(BroadProtocolConfig, REPO / "configs" / "dev_broad.yaml") == (
        BroadProtocolConfig()
    )
    with pytest.raises(ConfigError, match="renders version 1"):
        BroadProtocolConfig(version=PROTOCOL_VERSION + 1).validate()
    with pytest.raises(ConfigError, match="Kinect v1"):
        BroadProtocolConfig(distance=(1.5, 6.0)).validate()
    with pytest.raises(ConfigError, match="low <= high"):
        BroadProtocolConfig(camera_height=(2.0, 1.0)).validate()


def test_every_take_has_three_different_bodies_of_both_sexes(variants):
    assert len(variants) == 3 * len(CLIPS) and len({v.name for v in variants}) == len(variants)
    for t in range(len(CLIPS)):
        take = [v for v in variants if v.take_index == t]
        assert len(take) == 3 and len({v.clip for v in take}) == 1
        assert {v.sex for v in take} == {"female", "male"}
        assert {v.height_class for v in take} == {"short", "medium", "tall"}
        assert {v.weight_class for v in take} == {"slim", "average", "heavy"}
        assert len({v.seed for v in take}) == 3


def test_bodies_cover_heights_weights_and_adult_ages(variants):
    cfg = BroadProtocolConfig()
    for sex, span in (("female", cfg.female_height), ("male", cfg.male_height)):
        heights = sorted(v.phenotype["height"] for v in variants if v.sex == sex)
        assert len(heights) == 60
        assert heights[0] < span[0] + 0.03 and heights[-1] > span[1] - 0.03  # the whole range
        genders = [v.phenotype["gender"] for v in variants if v.sex == sex]
        assert all((g >= 0.9) if sex == "female" else (g <= 0.1) for g in genders)
    weights = {c: [v.phenotype["weight"] for v in variants if v.weight_class == c]
               for c in ("slim", "average", "heavy")}  # fmt: skip
    assert max(weights["slim"]) <= 0.25 and min(weights["heavy"]) >= 0.75
    assert all(0.7 <= v.phenotype["age"] <= 0.92 for v in variants)
    # Every (sex, height, weight) cell occurs.
    assert len({(v.sex, v.height_class, v.weight_class) for v in variants}) == 18


def test_cameras_cover_distances_heights_side_views_and_cuts(variants):
    cfg = BroadProtocolConfig()
    kinds = [(v.view, v.cut) for v in variants]
    assert kinds.count(("side", "none")) >= 40 and kinds.count(("frontal", "none")) >= 40
    assert kinds.count(("frontal", "feet")) >= 8 and kinds.count(("frontal", "arm")) >= 8
    for t in range(len(CLIPS)):  # every take: a frontal and a side view
        take = {(v.view, v.cut) for v in variants if v.take_index == t}
        assert {("frontal", "none"), ("side", "none")} <= take
    side = [abs(v.yaw_deg) for v in variants if v.view == "side"]
    assert min(side) >= 45 and max(side) > 85  # up to a profile
    assert all(abs(v.yaw_deg) <= 30 for v in variants if v.view == "frontal")
    assert {math.copysign(1, v.yaw_deg) for v in variants if v.view == "side"} == {-1, 1}
    uncut = sorted(v.nominal_distance_m for v in variants if v.cut == "none")
    assert uncut[0] < 2.1 and uncut[-1] > 4.4 and uncut[-1] <= 4.5
    heights = sorted(v.camera_height_m for v in variants)
    assert heights[0] < 0.65 and heights[-1] > 1.95
    assert {v.cut_side for v in variants if v.cut == "arm"} == {"left", "right"}
    assert min(cfg.distance) == 1.5 and max(cfg.distance) == 4.5


def test_motion_class_of_take_names():
    assert motion_class("HDM_mm_squat1Reps_037_120.amc") == "squat1Reps"
    assert motion_class("HDM_mm_jogLeftCircle4StepsRstart_012_120") == "jogLeftCircle4StepsRstart"
    with pytest.raises(ValueError, match="not an HDM05 take"):
        motion_class("walk.bvh")


# ---------------------------------------------------------------------------------------------
# Cameras on a hand-made person: a 1.75 m box with a head, a trunk and two arms held out.


def _person(frames: int = 3):
    rng = np.random.default_rng(0)
    parts = []  # (label, centre, half size)
    parts.append(("head", (0.0, 1.62, 0.0), (0.09, 0.12, 0.1)))
    parts.append(("chest", (0.0, 1.2, 0.0), (0.2, 0.3, 0.12)))
    parts.append(("pelvis", (0.0, 0.75, 0.0), (0.18, 0.15, 0.12)))
    parts.append(("l_shank_lower", (0.1, 0.3, 0.0), (0.06, 0.3, 0.06)))
    parts.append(("r_shank_lower", (-0.1, 0.3, 0.0), (0.06, 0.3, 0.06)))
    parts.append(("l_forearm", (0.55, 1.4, 0.0), (0.3, 0.04, 0.04)))
    parts.append(("r_forearm", (-0.55, 1.4, 0.0), (0.3, 0.04, 0.04)))
    verts, labels = [], []
    for name, c, h in parts:
        verts.append(np.asarray(c) + rng.uniform(-1, 1, (400, 3)) * np.asarray(h))
        labels.append(np.full(400, PART_NAMES.index(name), np.uint8))
    v = np.concatenate(verts)
    placed = SimpleNamespace(
        vertices=np.repeat(v[None], frames, 0), q=np.tile([0.0, 0.95, 0.0], (frames, 1))
    )
    return placed, SimpleNamespace(labels=np.concatenate(labels)), v, np.concatenate(labels)


def _pixels(cam, points, intr):
    p = points @ cam[:3, :3].T + cam[:3, 3]
    return intr.fx * p[:, 0] / p[:, 2] + intr.cx, intr.fy * p[:, 1] / p[:, 2] + intr.cy, p[:, 2]


def _inside(u, v, intr, margin=0.0):
    lo = margin - 0.5
    return (
        (u >= lo) & (u <= intr.width - 0.5 - margin) & (v >= lo) & (v <= intr.height - 0.5 - margin)
    )


def _variant(variants, view, cut, **kw):
    v = next(v for v in variants if (v.view, v.cut) == (view, cut))
    return dataclasses.replace(v, roll_deg=0.0, **kw)


def test_uncut_cameras_see_everything_within_range_from_the_nearest_distance(variants):
    cfg, intr = BroadProtocolConfig(), Intrinsics.kinect_v1(320)
    placed, body, pts, _ = _person()
    for view in ("frontal", "side"):
        v = _variant(variants, view, "none", nominal_distance_m=1.5, camera_height_m=1.0)
        cam = place_camera(v, cfg, placed, body, intr, 4.5).cam_from_world[0]
        u, w, z = _pixels(cam, pts[::20], intr)  # the vertices it checks, as for anny meshes
        assert _inside(u, w, intr).all() and z.max() < 4.5
        got = recorded_camera(cam)
        assert got["camera_height_m"] == pytest.approx(1.0, abs=1e-3)
        assert got["yaw_deg"] == pytest.approx(v.yaw_deg, abs=0.01)
        # The nearest 5 cm step that fits: 5 cm nearer cuts something.
        nearer = camera_at(got["distance_m"] - 0.05, 1.0, v.yaw_deg, 0.95).cam_from_world[0]
        assert not _inside(*_pixels(nearer, pts[::20], intr)[:2], intr, cfg.margin_px).all()
    far = _variant(variants, "frontal", "none", nominal_distance_m=4.5)
    assert (
        recorded_camera(place_camera(far, cfg, placed, body, intr, 4.5).cam_from_world[0])[
            "distance_m"
        ]
        < 4.4
    )  # moved in until the back of the motion is within range
    with pytest.raises(OutOfRangeError, match="whole motion"):
        place_camera(far, cfg, placed, body, intr, 1.0)


def test_feet_cuts_keep_the_head_and_cut_the_legs(variants):
    cfg, intr = BroadProtocolConfig(), Intrinsics.kinect_v1(320)
    placed, body, pts, labels = _person()
    v = _variant(variants, "frontal", "feet", camera_height_m=1.2, cut_amount_m=0.3, yaw_deg=0.0)
    cam = place_camera(v, cfg, placed, body, intr, 4.5).cam_from_world[0]
    u, w, _ = _pixels(cam, pts, intr)
    seen = _inside(u, w, intr)
    assert seen[labels == PART_NAMES.index("head")].all()
    assert seen[labels == PART_NAMES.index("chest")].all()
    low = pts[:, 1] < 0.25
    assert not seen[low].any() and seen[pts[:, 1] > 0.4].all()
    assert 1.5 <= recorded_camera(cam)["distance_m"] <= 2.1


@pytest.mark.parametrize(
    "side, cut_arm, kept_arm",
    [("left", "r_forearm", "l_forearm"), ("right", "l_forearm", "r_forearm")],
)
def test_arm_cuts_cut_the_arm_on_their_side_only(variants, side, cut_arm, kept_arm):
    cfg, intr = BroadProtocolConfig(), Intrinsics.kinect_v1(320)
    placed, body, pts, labels = _person()
    v = _variant(variants, "frontal", "arm", yaw_deg=0.0, cut_side=side, cut_amount_m=0.05,
                 nominal_distance_m=3.0, camera_height_m=1.0)  # fmt: skip
    cam = place_camera(v, cfg, placed, body, intr, 4.5).cam_from_world[0]
    seen = _inside(*_pixels(cam, pts, intr)[:2], intr)
    # Facing the camera, the person's right arm is on the image's left.
    assert not seen[labels == PART_NAMES.index(cut_arm)].all()
    assert seen[labels == PART_NAMES.index(kept_arm)].all()
    for trunk in ("head", "chest", "pelvis"):  # what it measured: every tenth trunk vertex
        assert seen[labels == PART_NAMES.index(trunk)][::10].all()


def test_joints_outside_marks_joints_beyond_the_border_or_behind():
    intr = Intrinsics.kinect_v1(320)
    joints = np.array([[[0.0, 0.0, 2.0], [3.0, 0.0, 2.0], [0.0, 0.0, -1.0]]])
    assert joints_outside(joints, intr).tolist() == [[False, True, True]]


# ---------------------------------------------------------------------------------------------
# CLI


@pytest.mark.parametrize(
    "args, message",
    [
        (["--protocol-config", "x.yaml"], "--protocol-config needs --protocol broad"),
        (["--protocol", "broad", "--all-clips"], "set by the broad protocol's spec"),
        (["--protocol", "broad", "--frames", "30"], "set by the broad protocol's spec"),
    ],
)
def test_dev_recordings_cli_refuses_conflicting_options(tmp_path, capsys, args, message):
    from depthmocap.train.evaluation.dev_recordings import main

    with pytest.raises(SystemExit) as exit_info:
        main(["--clips", str(tmp_path), "--out", str(tmp_path / "out"), *args])
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_dev_recordings_cli_reports_a_bad_spec(tmp_path, capsys):
    from depthmocap.train.evaluation.dev_recordings import main

    spec = tmp_path / "spec.yaml"
    spec.write_text("version: 2\n")
    args = ["--clips", str(tmp_path), "--out", str(tmp_path / "out"), "--protocol", "broad"]
    assert main([*args, "--protocol-config", str(spec)]) == 2
    assert "renders version 1" in capsys.readouterr().err
    spec.write_text("seeds: 3\n")
    assert main([*args, "--protocol-config", str(spec)]) == 2
    assert "unknown key(s) seeds" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_tiny_protocol_recording_holds_its_variant(tmp_path, variants):
    """render_sequence with a protocol variant's body and camera (2 frames of a procedural
    motion): the recording holds that body, that camera and the feet cut."""
    import json
    import os

    pytest.importorskip("pyrender")
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    from depthmocap.train.evaluation.protocol import variant_record
    from depthmocap.train.synth.render import DepthLabelRenderer
    from depthmocap.train.synth.sequence import render_sequence

    try:
        DepthLabelRenderer(Intrinsics.kinect_v1(320)).close()
    except RuntimeError as err:
        pytest.skip(f"EGL rendering unavailable: {err}")
    cfg = BroadProtocolConfig()
    v = next(v for v in variants if v.cut == "feet")
    rec = render_sequence(
        "wave", tmp_path / v.name, frames=2, seed=v.seed, phenotype=v.phenotype,
        camera=lambda placed, body, intr, far: place_camera(v, cfg, placed, body, intr, far),
    )  # fmt: skip
    assert json.loads((rec / "phenotype.json").read_text()) == pytest.approx(v.phenotype)
    record = variant_record(v, rec)
    assert record["frames"] == 2 and record["name"] == v.name
    assert record["camera"]["camera_height_m"] == pytest.approx(v.camera_height_m, abs=1e-3)
    assert record["camera"]["yaw_deg"] == pytest.approx(v.yaw_deg, abs=0.01)
    assert 1.5 <= record["camera"]["distance_m"] <= 2.5
    assert record["joints_cut"].get("l_ankle") == 100.0 and "head" not in record["joints_cut"]
