"""The person/clutter forest in the segmentation (runtime/segmentation/clutter.py): a forest
trained on a tiny set of a curved "person" with a flat box against it takes the box out of the
mask and keeps the person; the stream's segmenter applies it; bad models are refused."""

import numpy as np
import pytest
import torch
from depthmocap.runtime.segmentation import PersonSegmenter, SegmentationConfig
from depthmocap.runtime.segmentation.clutter import ClutterFilter, clutter_model_path
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.forest_format import ForestFormatError, save_forest
from depthmocap.shared.labels import CLUTTER_CLASSES
from depthmocap.shared.resources import MODELS_DIR
from depthmocap.train.forest.config import ForestConfig
from depthmocap.train.forest.trainer import train_forest
from depthmocap.train.synth.trainset import TrainSet

INTR = Intrinsics(80, 60, 62.0, 62.0, 39.5, 29.5)


def person_with_box(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 60, 80) uint16 mm depth and CLUTTER_CLASSES labels: a rounded blob (the person,
    its surface bulging towards the camera) with a flat box flush against one side."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:60, 0:80]
    depth = np.zeros((n, 60, 80), np.uint16)
    labels = np.zeros((n, 60, 80), np.uint8)
    for i in range(n):
        z = rng.uniform(2.0, 2.8)
        cx, cy = rng.uniform(30, 50), rng.uniform(25, 35)
        r2 = ((xx - cx) / 10) ** 2 + ((yy - cy) / 20) ** 2
        person = r2 < 1
        side = rng.choice([-1, 1])
        x0 = cx + side * 9
        box = (np.abs(xx - (x0 + side * 8)) < 8) & (yy > cy) & (yy < cy + 22) & ~person
        d = np.where(person, z - 0.12 * np.sqrt(np.clip(1 - r2, 0, 1)), z + 0.002 * (yy - cy))
        depth[i] = np.where(person | box, d * 1000, 0).astype(np.uint16)
        labels[i] = np.where(person, 1, np.where(box, 2, 0))
    return depth, labels


@pytest.fixture(scope="module")
def clutter_forest(tmp_path_factory, write_trainset):
    depth, labels = person_with_box(24, 0)
    root = write_trainset(tmp_path_factory.mktemp("clutter_set"), depth, labels, INTR,
                          CLUTTER_CLASSES)  # fmt: skip
    cfg = ForestConfig(
        trees=2, max_depth=10, min_samples=2, feature_pool=64, candidates_per_node=32,
        thresholds_per_candidate=16, pixels_per_frame=300, threads=1, device="cpu",
        offset_max_m=0.5,
    )  # fmt: skip
    forest = train_forest(TrainSet(root), cfg, log=None)
    path = tmp_path_factory.mktemp("model") / "clutter.npz"
    save_forest(path, forest)
    return path


def test_the_box_leaves_the_mask_and_the_person_stays(clutter_forest):
    depth, labels = person_with_box(6, 99)
    depth_m = torch.from_numpy(depth.astype(np.float32) / 1000)
    mask = torch.from_numpy(labels > 0)
    keep = ClutterFilter(clutter_forest)(depth_m, mask, INTR)
    assert keep.shape == mask.shape and keep.dtype == torch.bool
    assert not bool((keep & ~mask).any())  # only ever removes
    person, box = labels == 1, labels == 2
    kept = keep.numpy()
    assert (kept & person).sum() >= 0.9 * person.sum()
    assert (kept & box).sum() <= 0.2 * box.sum()
    # a single (H, W) frame gives the same as its batch row
    one = ClutterFilter(clutter_forest)(depth_m[2], mask[2], INTR)
    assert torch.equal(one, keep[2])
    # an empty mask stays empty; a threshold of 1 keeps all but the surest clutter
    empty = torch.zeros(60, 80, dtype=torch.bool)
    assert not bool(ClutterFilter(clutter_forest)(depth_m[0], empty, INTR).any())
    lenient = ClutterFilter(clutter_forest, threshold=1.0)(depth_m, mask, INTR)
    assert int(lenient.sum()) >= int(keep.sum())


def test_the_stream_segmenter_applies_it(clutter_forest):
    depth, _ = person_with_box(1, 5)
    depth_m = torch.from_numpy(depth[0].astype(np.float32) / 1000)
    cfg = SegmentationConfig(remove_floor=False, min_area_m2=0.01)
    plain = PersonSegmenter(cfg)(depth_m, INTR)
    filtered = PersonSegmenter(
        SegmentationConfig(remove_floor=False, min_area_m2=0.01, clutter_model=str(clutter_forest))
    )(depth_m, INTR)
    assert bool(plain.any())
    expected = ClutterFilter(clutter_forest)(depth_m, plain, INTR)
    assert torch.equal(filtered, expected) and int(filtered.sum()) < int(plain.sum())


def test_bad_models_are_refused_clearly(tmp_path):
    with pytest.raises(ForestFormatError):
        ClutterFilter(tmp_path / "missing.npz")
    # the body-part forest is not a person/clutter forest
    with pytest.raises(ForestFormatError, match="classes"):
        ClutterFilter(MODELS_DIR / "forest.npz")
    with pytest.raises(ValueError, match="clutter_threshold"):
        ClutterFilter(MODELS_DIR / "forest.npz", threshold=0.0)
    with pytest.raises(ValueError, match="clutter_threshold"):
        SegmentationConfig(clutter_threshold=1.5)
    assert clutter_model_path("clutter_forest.npz") == MODELS_DIR / "clutter_forest.npz"
    assert clutter_model_path(str(tmp_path / "x.npz")) == tmp_path / "x.npz"
