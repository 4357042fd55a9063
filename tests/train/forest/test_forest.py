"""Forest training: features, pixel sampling, tree growing, a separable toy problem, the CLIs."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import load_config
from depthmocap.shared.forest_format import load_forest
from depthmocap.train.forest.config import ForestConfig
from depthmocap.train.forest.evaluate import confusion_image, evaluate_forest
from depthmocap.train.forest.features import (
    depth_features_mm,
    pad_with_background,
    person_depth_mm,
    sample_offset_pairs,
    sample_pixels,
)
from depthmocap.train.forest.grow import GrowParams, grow_tree
from depthmocap.train.forest.predict import predict_posteriors
from depthmocap.train.forest.trainer import train_forest
from depthmocap.train.synth.trainset import (
    Shard,
    TrainSet,
    TrainSetError,
    open_trainsets,
    write_manifest,
    write_shard,
)

REPO = Path(__file__).resolve().parents[3]
TOY_INTR = Intrinsics(64, 48, 50.0, 50.0, 31.5, 23.5)


def toy_frames(n: int, seed: int):
    """Class 1: 5x5 squares; class 2: 24x24 squares; at 1.5-2.5 m before a wall at 4 m.

    Separable by depth-difference features: a probe about 8 px (16 pixel*m at 2 m) left or
    right of a pixel stays on a big square on at least one side, never on a small one.
    """
    rng = np.random.default_rng(seed)
    depth = np.full((n, 48, 64), 4000, np.uint16)
    labels = np.zeros((n, 48, 64), np.uint8)
    for i in range(n):
        z = int(rng.uniform(1500, 2500))
        r, c = rng.integers(5, 38), rng.integers(3, 20)
        depth[i, r : r + 5, c : c + 5] = z
        labels[i, r : r + 5, c : c + 5] = 1
        r, c = rng.integers(2, 22), rng.integers(32, 38)
        depth[i, r : r + 24, c : c + 24] = z + 100
        labels[i, r : r + 24, c : c + 24] = 2
    depth[:, 0, 0] = 0  # a pixel without a reading
    return depth, labels


def write_toy_set(root: Path, n: int = 40, seed: int = 0, per_shard: int = 20):
    root.mkdir(parents=True, exist_ok=True)
    depth, labels = toy_frames(n, seed)
    shards = []
    for k, s in enumerate(range(0, n, per_shard)):
        m = min(per_shard, n - s)
        shard = Shard(
            depth[s : s + m], labels[s : s + m], np.zeros((m, 16, 3), np.float32),
            np.zeros((m, 34), np.float32), np.zeros(m, np.int32),
            np.array([TOY_INTR.fx, TOY_INTR.fy, TOY_INTR.cx, TOY_INTR.cy]),
        )  # fmt: skip
        name = f"shard_{k:05d}.npz"
        shards.append({"file": name, "frames": m, "sha256": write_shard(root / name, shard)})
    write_manifest(root, TOY_INTR, shards, np.bincount(labels.ravel(), minlength=20), seed, {})
    return depth, labels


def tiny_config(**kw) -> ForestConfig:
    cfg = load_config(ForestConfig, REPO / "configs" / "forest_tiny.yaml")
    cfg.pixels_per_frame = 1000  # every person pixel of the toy frames
    cfg.threads = 1
    cfg.device = "cpu"
    for k, v in kw.items():
        setattr(cfg, k, v)
    return cfg


@pytest.fixture(scope="module")
def toy_set(tmp_path_factory):
    root = tmp_path_factory.mktemp("toy") / "set"
    depth, labels = write_toy_set(root)
    return root, depth, labels


@pytest.fixture(scope="module")
def toy_forest(toy_set):
    return train_forest(TrainSet(toy_set[0]), tiny_config(), log=None)


def _reference_features(padded, frame, row, col, u, v):
    """The runtime's formula, written plainly: clamp into the one-pixel border, then floor."""
    f, hp, wp = padded.shape
    flat = padded.reshape(-1)
    invd = 1.0 / (flat[(frame * hp + row + 1) * wp + col + 1].float() / 1000.0)
    probes = []
    for off in (u, v):
        x = off[None, :, 0] * invd[:, None] + (col.float() + 1.5)[:, None]
        y = off[None, :, 1] * invd[:, None] + (row.float() + 1.5)[:, None]
        x = torch.minimum(x.clamp(min=0), torch.tensor(wp - 1.0)).floor()
        y = torch.minimum(y.clamp(min=0), torch.tensor(hp - 1.0)).floor()
        probes.append(flat[(y * wp + x).long() + (frame * hp * wp)[:, None]])
    return (probes[0] - probes[1]).to(torch.int16)


def test_features_match_the_clamped_reference(toy_set):
    _, depth, labels = toy_set
    d = torch.from_numpy(depth[:6].astype(np.int32))
    lab = torch.from_numpy(labels[:6])
    padded = pad_with_background(person_depth_mm(d, lab > 0, 10000), 10000)
    g = torch.Generator().manual_seed(1)
    u, v = sample_offset_pairs(50, (200.0, 120.0), 0.3, g)  # many probes off the image
    assert (v == 0).all(1).any() and (v != 0).any()
    w = torch.tensor([0.0, 1.0, 1.0] + [0.0] * 17)
    fr, r, c = sample_pixels(lab, (lab > 0) & (d > 0), 40, w, g)
    got = depth_features_mm(padded, fr, r, c, u, v)
    assert torch.equal(got, _reference_features(padded, fr, r, c, u, v))
    # A probe off the person reads the background constant.
    assert int(got.max()) >= 10000 - 2600


def test_sample_pixels_respects_validity_count_and_weights():
    g = torch.Generator().manual_seed(0)
    labels = torch.zeros(3, 10, 10, dtype=torch.uint8)
    labels[:, :5] = 1
    labels[:, 5:] = 2
    labels[2, :, :] = 0
    labels[2, 0, :4] = 1  # frame 2: only 4 valid pixels
    valid = labels > 0
    w = torch.tensor([0.0, 1.0, 0.0])  # class 2 never drawn
    fr, r, c = sample_pixels(labels, valid, 7, w, g)
    assert torch.equal(torch.bincount(fr, minlength=3), torch.tensor([7, 7, 4]))
    assert (labels[fr, r, c] == 1).all()
    assert len({(int(a), int(b), int(x)) for a, b, x in zip(fr, r, c)}) == len(fr)


def test_grow_separates_a_binned_toy_problem():
    g = torch.Generator().manual_seed(0)
    n, p = 400, 8
    labels = torch.randint(0, 3, (n,), generator=g)
    bins = torch.randint(0, 16, (n, p), generator=g, dtype=torch.uint8)
    bins[:, 5] = (labels * 5 + torch.randint(0, 4, (n,), generator=g)).to(torch.uint8)
    tree = grow_tree(bins, labels, 3, 16, GrowParams(4, 1, 1e-6, 8), g)
    assert tree.feature[0] == 5 and tree.depth.max() == 2
    leaves = tree.left < 0
    assert ((tree.counts[leaves] > 0).sum(1) == 1).all()  # pure leaves


def test_tiny_forest_learns_separable_toy_problem_exactly(toy_set, toy_forest):
    _, depth, labels = toy_set
    d = torch.from_numpy(depth.astype(np.float32) / 1000.0)
    lab = torch.from_numpy(labels)
    pix, post = predict_posteriors(toy_forest, d, lab > 0)
    truth = lab[pix[:, 0], pix[:, 1], pix[:, 2]].long()
    assert len(truth) == int(((lab > 0) & (d > 0)).sum())
    assert torch.equal(post.argmax(1), truth)
    assert torch.allclose(post.sum(1), torch.ones(len(post)), atol=2e-3)
    f = toy_forest
    assert f.num_trees == 2 and f.camera["fx"] == 50.0 and f.class_names[0] == "background"
    assert f.max_depth <= 8 and f.stats["trees"][0]["pixels"] > 0


def test_training_is_deterministic_for_a_seed(toy_set, toy_forest):
    again = train_forest(TrainSet(toy_set[0]), tiny_config(), log=None)
    for name in ("u", "v", "threshold", "left", "right", "leaf", "leaf_dist", "roots"):
        assert np.array_equal(getattr(again, name), getattr(toy_forest, name)), name
    one_by_one = train_forest(TrainSet(toy_set[0]), tiny_config(trees_per_pass=1), log=None)
    assert np.array_equal(one_by_one.threshold, toy_forest.threshold)
    assert np.array_equal(one_by_one.leaf_dist, toy_forest.leaf_dist)
    other = train_forest(TrainSet(toy_set[0]), tiny_config(seed=5), log=None)
    assert not np.array_equal(other.u, toy_forest.u)


def _split_toy_set(root: Path, out: Path, intr: Intrinsics = TOY_INTR) -> list[Path]:
    """Each shard of the toy set as a training set of its own (the same files, in order)."""
    full = TrainSet(root)
    roots = []
    for k, s in enumerate(full.manifest["shards"]):
        part = out / f"part{k}"
        part.mkdir(parents=True)
        (part / s["file"]).write_bytes((root / s["file"]).read_bytes())
        labels = full.shard(k).labels
        write_manifest(part, intr, [s], np.bincount(labels.ravel(), minlength=20), k, {})
        roots.append(part)
    return roots


def test_union_of_sets_reads_and_trains_as_one(toy_set, toy_forest, tmp_path):
    roots = _split_toy_set(toy_set[0], tmp_path)
    assert len(roots) == 2
    union = open_trainsets(roots, verify=True)
    full = TrainSet(toy_set[0])
    assert union.frames == full.frames == 40 and union.num_shards == 2
    assert union.manifest["content_hash"] == full.manifest["content_hash"]
    assert union.manifest["class_pixel_counts"] == full.manifest["class_pixel_counts"]
    assert [s["frames"] for s in union.manifest["sets"]] == [20, 20]
    picked = np.array([3, 25, 39])
    assert np.array_equal(union.load_frames(picked).depth, full.load_frames(picked).depth)
    forest = train_forest(union, tiny_config(), log=None)
    for name in ("u", "v", "threshold", "left", "right", "leaf", "leaf_dist", "roots"):
        assert np.array_equal(getattr(forest, name), getattr(toy_forest, name)), name
    assert type(open_trainsets(roots[:1])) is TrainSet


def test_union_refuses_sets_from_other_cameras(toy_set, tmp_path):
    a = _split_toy_set(toy_set[0], tmp_path / "a")[0]
    b = _split_toy_set(toy_set[0], tmp_path / "b", Intrinsics(64, 48, 60.0, 60.0, 31.5, 23.5))[1]
    with pytest.raises(TrainSetError, match="intrinsics"):
        open_trainsets([a, b])
    with pytest.raises(TrainSetError, match="no training sets"):
        open_trainsets([])


def test_evaluation_and_confusion_png(toy_set, toy_forest):
    res = evaluate_forest(toy_forest, toy_set[0])
    assert res["frames"] == 40 and res["pixel_accuracy"] == 1.0
    assert res["mean_class_accuracy"] == 1.0
    assert res["per_class_accuracy"]["pelvis"] == 1.0  # class 1 of the part set
    conf = np.array(res["confusion"])
    assert conf.shape == (20, 20) and conf[0].sum() == 0
    img = confusion_image(conf, toy_forest.class_names)
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[0] > 300


def test_train_and_eval_clis(toy_set, tmp_path, capsys):
    from depthmocap.train.forest.eval_cli import main as eval_main
    from depthmocap.train.forest.train_cli import main as train_main

    out = tmp_path / "m" / "forest.npz"
    rc = train_main(
        ["--data", str(toy_set[0]), str(toy_set[0]), "--out", str(out), "--preset", "tiny",
         "--quiet",
         "--pixels-per-frame", "300", "--eval-data", str(toy_set[0]), "--onnx",
         str(tmp_path / "f.onnx")]
    )  # fmt: skip
    assert rc == 0
    forest = load_forest(out)
    assert forest.onnx_graph is not None and forest.config["pixels_per_frame"] == 300
    assert out.with_suffix(".yaml").is_file() and (tmp_path / "f.onnx").is_file()
    metrics = json.loads(out.with_suffix(".metrics.json").read_text())
    assert metrics["evaluation"]["mean_class_accuracy"] > 0.9
    assert "train-forest" in metrics["training"]["command"]
    assert metrics["training"]["data"] == f"{toy_set[0]} {toy_set[0]}"
    assert out.with_suffix(".confusion.png").is_file()
    rc = eval_main(["--model", str(out), "--data", str(toy_set[0]), "--out", str(tmp_path / "e")])
    assert rc == 0 and (tmp_path / "e" / "confusion.png").is_file()
    assert "mean per-class accuracy" in capsys.readouterr().out


def test_clis_fail_cleanly(tmp_path, capsys):
    from depthmocap.train.forest.eval_cli import main as eval_main
    from depthmocap.train.forest.train_cli import main as train_main

    assert train_main(["--data", str(tmp_path), "--out", str(tmp_path / "f.npz")]) == 2
    assert "no manifest.json" in capsys.readouterr().err
    (tmp_path / "bad.npz").write_text("x")
    assert eval_main(["--model", str(tmp_path / "bad.npz"), "--data", str(tmp_path)]) == 2
    assert "not an .npz" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("trees: many\n")
    assert train_main(["--data", ".", "--out", "x.npz", "--config", str(bad)]) == 2
    assert "expected an integer" in capsys.readouterr().err
