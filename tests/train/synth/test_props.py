"""Furniture against the person (train/synth/props.py): where each kind of prop stands, the
person/clutter labels, pixel heights, the set's class names (rendered: test_synth.py)."""

import json
from dataclasses import replace

import numpy as np
import pytest
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import load_config
from depthmocap.shared.labels import CLUTTER_CLASSES, PART_NAMES
from depthmocap.train.synth.props import (
    PROP_KINDS,
    PropConfig,
    attached_prop,
    chair_under,
    person_clutter_labels,
    pixel_heights,
    sitting_pose,
)
from depthmocap.train.synth.trainset import (
    Shard,
    TrainSet,
    TrainSetError,
    write_manifest,
    write_shard,
)
from depthmocap.train.synth.trainset_builder import SynthConfig, _config_fingerprint, class_names

CAMERA_HEIGHT = 1.0


def standing_body(n: int = 4000, seed: int = 0) -> np.ndarray:
    """(n, 3) points of an upright cylinder 1.7 m tall, radius 0.2, 2.5 m ahead, in a level
    frame (y down, floor at y = CAMERA_HEIGHT)."""
    rng = np.random.default_rng(seed)
    a, h = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 1.7, n)
    return np.stack([0.2 * np.cos(a), CAMERA_HEIGHT - h, 2.5 + 0.2 * np.sin(a)], -1)


@pytest.mark.parametrize("kind", sorted(PROP_KINDS))
def test_each_prop_stands_on_the_floor_against_the_body(kind):
    body = standing_body()
    lo, hi = PROP_KINDS[kind]
    for seed in range(20):
        prop = attached_prop(np.random.default_rng(seed), body, CAMERA_HEIGHT, PropConfig(), kind)
        tops = [b.height for b in prop.boxes] + [c.top for c in prop.cylinders]
        assert all(c.bottom >= 0 and c.top > c.bottom for c in prop.cylinders)
        assert all(b.x_min < b.x_max and b.z_min < b.z_max for b in prop.boxes)
        if kind == "chair":  # the seat at a chair's height, wider than the hips, behind them
            seat = max(t for t in tops if t <= hi * 1.7 + 1e-6)
            assert lo * 1.7 - 1e-6 <= seat
            widest = [c for c in prop.cylinders if c.radius >= 0.2] + [
                b for b in prop.boxes if b.x_max - b.x_min >= 0.4
            ]
            assert widest
            legs = [c for c in prop.cylinders if c.radius < 0.05]
            assert legs and all(leg.bottom == 0.0 for leg in legs)
            seat_z = [getattr(w, "z", None) or (w.z_min + w.z_max) / 2 for w in widest]
            assert min(seat_z) >= 2.45  # at or behind the hips' middle
        else:
            (box,) = prop.boxes
            assert lo * 1.7 - 1e-6 <= box.height <= hi * 1.7 + 1e-6 and not prop.cylinders
            assert 0.3 <= box.z_max - box.z_min <= 0.6
        if kind == "bench":  # wider than the body on both sides
            assert box.x_min < -0.15 and box.x_max > 0.15
        if kind == "table":  # beside the body, reaching at most 10 cm under its edge
            assert not (box.x_min < -0.1 and box.x_max > 0.1)
            assert -0.3 < box.x_min < 0.3 or -0.3 < box.x_max < 0.3


def test_person_clutter_labels_and_pixel_heights():
    labels = np.array([[0, 3, 0], [0, 0, 5]], np.uint8)
    depth = np.array([[1000, 1000, 0], [1000, 1000, 1000]], np.uint16)
    prop = np.array([[True, True, True], [False, True, True]])
    heights = np.array([[1.0, 1.0, 1.0], [1.0, 0.01, 1.0]])
    out = person_clutter_labels(depth, labels, prop, heights)
    # the body wins over the prop; no reading, the floor band and off-prop pixels are 0
    np.testing.assert_array_equal(out, [[2, 1, 0], [0, 0, 1]])
    assert CLUTTER_CLASSES[out[0, 0]] == "clutter"
    intr = Intrinsics(5, 3, 2.0, 2.0, 2.0, 1.0)
    z = np.full((3, 5), 2.0)
    z[0, 0] = 0.0
    h = pixel_heights(z, intr, np.eye(3), 1.5)
    # level camera: the principal row is at the camera's height; a row below, z / fy lower
    np.testing.assert_allclose(h[1], 1.5)
    np.testing.assert_allclose(h[2, 1:], 1.5 - 1.0)
    assert np.isnan(h[0, 0])


def test_clutter_sets_have_their_own_class_names(tmp_path):
    cfg = load_config(SynthConfig, "configs/synth_tiny.yaml")
    assert class_names(cfg) == PART_NAMES
    on = replace(cfg, scene=replace(cfg.scene, props=PropConfig(0.5, True)))
    assert class_names(on) == CLUTTER_CLASSES
    # sets made before props existed keep their fingerprint; props change it
    assert "props" not in json.dumps(_config_fingerprint(cfg))
    assert _config_fingerprint(on) != _config_fingerprint(cfg)
    with pytest.raises(ValueError, match="floor"):
        replace(on, scene=replace(on.scene, floor=False)).validate()
    with pytest.raises(ValueError, match="probability"):
        PropConfig(1.5).validate()
    intr = Intrinsics(8, 6, 6.0, 6.0, 3.5, 2.5)
    sh = Shard(np.ones((1, 6, 8), np.uint16), np.ones((1, 6, 8), np.uint8),
               np.zeros((1, 16, 3), np.float32), np.zeros((1, 34), np.float32),
               np.zeros(1, np.int32), np.array([6.0, 6.0, 3.5, 2.5]))  # fmt: skip
    entry = {"file": "s.npz", "frames": 1, "sha256": write_shard(tmp_path / "s.npz", sh)}
    write_manifest(tmp_path, intr, [entry], np.array([0, 48, 0]), 0, {},
                   class_names=CLUTTER_CLASSES)  # fmt: skip
    assert TrainSet(tmp_path).class_names == list(CLUTTER_CLASSES)
    write_manifest(tmp_path, intr, [entry], np.array([0, 48]), 0, {},
                   class_names=("background", "thing"))  # fmt: skip
    with pytest.raises(TrainSetError, match="class names"):
        TrainSet(tmp_path)


def test_a_seated_body_gets_a_chair_under_its_hips():
    rng = np.random.default_rng(3)
    q = np.zeros(34)
    q[5] = 0.3  # some root rotation the seat must keep
    seated = sitting_pose(q, rng)
    changed = np.nonzero(seated != q)[0]
    names = {sk.DOF_NAMES[i].split("_", 1)[1] for i in changed}
    assert names <= {"femur_flex", "femur_abd", "femur_twist", "tibia_flex"}
    for side in "lr":
        assert 1.2 <= seated[sk.DOF_NAMES.index(f"{side}_femur_flex")] <= 1.75
        assert 1.2 <= seated[sk.DOF_NAMES.index(f"{side}_tibia_flex")] <= 1.9
    # a seated "body": buttocks 0.45 m above the floor at the pelvis, feet on the floor ahead
    rng = np.random.default_rng(0)
    buttocks = np.stack(
        [rng.uniform(-0.15, 0.15, 500), np.full(500, CAMERA_HEIGHT - 0.45),
         2.5 + rng.uniform(-0.1, 0.1, 500)], -1,
    )  # fmt: skip
    feet = np.array([[0.1, CAMERA_HEIGHT, 2.0], [-0.1, CAMERA_HEIGHT, 2.0]])
    torso = np.array([[0.0, CAMERA_HEIGHT - 1.2, 2.5]])
    body = np.concatenate([buttocks, feet, torso])
    pelvis = np.array([0.0, CAMERA_HEIGHT - 0.55, 2.5])
    for seed in range(10):
        chair = chair_under(np.random.default_rng(seed), body, pelvis)
        seat = max(
            [c.top for c in chair.cylinders] + [b.height for b in chair.boxes if b.height < 0.5]
        )
        assert 0.43 <= seat <= 0.45  # just under the buttocks
        wide = [c for c in chair.cylinders if c.radius >= 0.2] + [
            b for b in chair.boxes if b.x_max - b.x_min >= 0.4
        ]
        assert wide
