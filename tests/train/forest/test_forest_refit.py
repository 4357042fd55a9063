"""Leaf re-estimation: counts against a plain per-pixel tree walk, the re-estimate formula, and
training with it on the separable toy problem."""

import numpy as np
import torch
from depthmocap.shared.forest_format import Forest
from depthmocap.train.forest.predict import predict_posteriors
from depthmocap.train.forest.refit import leaf_class_counts, refit_leaves
from depthmocap.train.forest.trainer import train_forest
from depthmocap.train.synth.trainset import TrainSet
from test_forest import tiny_config, toy_forest, toy_set  # noqa: F401  (fixtures)


def _walk_one(forest: Forest, depth_m: np.ndarray, person: np.ndarray, f, r, c, tree) -> int:
    """Leaf row of one pixel, walked node by node with the probe rule written out."""
    h, w = depth_m.shape[1:]
    bg = forest.background_m
    seen = np.where(person[f], depth_m[f], bg)
    d = depth_m[f, r, c]
    node = int(forest.roots[tree])
    while forest.left[node] >= 0:
        probes = []
        for off in (forest.u[node], forest.v[node]):
            # Padded coordinates (x + 1, y + 1) rounded to nearest, clamped to the border.
            x = int(np.floor(min(max(np.float32(off[0]) / np.float32(d) + c + 1.5, 0), w + 1)))
            y = int(np.floor(min(max(np.float32(off[1]) / np.float32(d) + r + 1.5, 0), h + 1)))
            inside = 1 <= x <= w and 1 <= y <= h
            probes.append(seen[y - 1, x - 1] if inside else bg)
        go_right = probes[0] - probes[1] > forest.threshold[node]
        node = int(forest.right[node] if go_right else forest.left[node])
    return int(forest.leaf[node])


def test_leaf_counts_match_a_plain_walk(toy_set, toy_forest):  # noqa: F811
    root, depth, labels = toy_set
    shards = list(TrainSet(root))
    weights = torch.tensor([0.0, 1.0, 1.0] + [0.0] * 17)
    counts = leaf_class_counts(
        toy_forest, shards[:1], weights, 10_000, torch.Generator().manual_seed(0),
        torch.device("cpu"), log=None,
    )  # fmt: skip
    n = len(shards[0])
    d = depth[:n].astype(np.float32) / 1000.0
    person = (labels[:n] > 0) & (depth[:n] > 0)
    expected = np.zeros((toy_forest.num_leaves, toy_forest.num_classes))
    for f, r, c in zip(*np.nonzero(person)):
        for t in range(toy_forest.num_trees):
            expected[_walk_one(toy_forest, d, person, f, r, c, t), labels[f, r, c]] += 1
    assert np.array_equal(counts.numpy(), expected)


def test_refit_formula_keeps_unreached_leaves():
    grown = np.array([[0.0, 1.0, 0.0], [0.5, 0.5, 0.0], [0.0, 0.0, 1.0]], np.float16)
    forest = Forest(
        u=np.zeros((5, 2)), v=np.zeros((5, 2)), threshold=np.zeros(5),
        left=np.array([1, -1, 3, -1, -1]), right=np.array([2, -1, 4, -1, -1]),
        leaf=np.array([-1, 0, -1, 1, 2]), leaf_dist=grown, roots=np.array([0]),
        class_names=("background", "a", "b"), camera={"fx": 1, "fy": 1, "cx": 0, "cy": 0,
                                                      "width": 4, "height": 3},
    )  # fmt: skip
    counts = torch.tensor([[0.0, 0.0, 6.0], [0.0, 0.0, 0.0], [0.0, 3.0, 1.0]])
    out = refit_leaves(forest, counts, prior=2.0)
    want = np.array([[0, 2 / 8, 6 / 8], [0.5, 0.5, 0], [0, 3 / 6, 3 / 6]])
    assert np.allclose(out.leaf_dist.astype(np.float64), want, atol=1e-3)
    assert out.stats["leaf_refit"]["leaves_reached"] == round(2 / 3, 4)
    assert np.array_equal(forest.leaf_dist, grown)  # the input is left alone
    exact = refit_leaves(forest, counts, prior=0.0)
    assert np.allclose(exact.leaf_dist[0].astype(np.float64), [0, 0, 1])


def test_training_with_refit_still_separates_the_toy_problem(toy_set, toy_forest):  # noqa: F811
    root, depth, labels = toy_set
    forest = train_forest(TrainSet(root), tiny_config(refit_pixels_per_frame=50), log=None)
    assert np.array_equal(forest.threshold, toy_forest.threshold)  # same splits
    assert forest.stats["leaf_refit"]["pixels_per_tree"] == 40 * 50
    d = torch.from_numpy(depth.astype(np.float32) / 1000.0)
    lab = torch.from_numpy(labels)
    pix, post = predict_posteriors(forest, d, lab > 0)
    assert torch.equal(post.argmax(1), lab[pix[:, 0], pix[:, 1], pix[:, 2]].long())
