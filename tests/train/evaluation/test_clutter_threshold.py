"""The person/clutter threshold's evaluation (train/evaluation/clutter_threshold.py): golden
shares and the choice rule; end to end on a tiny set with a tiny forest."""

import numpy as np
import pytest
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.forest_format import save_forest
from depthmocap.shared.labels import CLUTTER_CLASSES
from depthmocap.train.evaluation.clutter_threshold import (
    THRESHOLDS,
    choose_threshold,
    main,
    set_calls,
    threshold_table,
)
from depthmocap.train.forest.config import ForestConfig
from depthmocap.train.forest.trainer import train_forest
from depthmocap.train.synth.trainset import TrainSet

INTR = Intrinsics(40, 30, 31.0, 31.0, 19.5, 14.5)


def test_shares_and_the_choice():
    # two frames, two thresholds: (person taken out, furniture taken out)
    called = np.array([[[10, 50], [2, 40]], [[4, 0], [0, 0]]])
    person, clutter = np.array([1000, 400]), np.array([100, 0])
    table = threshold_table(called, person, clutter, thresholds=(0.5, 0.8))
    assert table[0]["person_called"] == pytest.approx(14 / 1400)
    assert table[0]["person_called_bare"] == pytest.approx(4 / 400)  # the frame without furniture
    assert table[1]["person_called_bare"] == 0.0
    assert table[0]["clutter_caught"] == pytest.approx(0.5) and table[1]["clutter_caught"] == 0.4
    assert choose_threshold(table, max_person_loss=0.001) == 0.8
    assert choose_threshold(table, max_person_loss=0.02) == 0.5
    strict = [dict(r, person_called_bare=0.5) for r in table]
    assert choose_threshold(strict) == 0.8  # none qualifies: the highest


def test_end_to_end_on_a_tiny_set(tmp_path, capsys, write_trainset):
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:30, 0:40]
    depth = np.zeros((8, 30, 40), np.uint16)
    labels = np.zeros((8, 30, 40), np.uint8)
    for i in range(8):
        person = ((xx - 15) / 6) ** 2 + ((yy - 15) / 10) ** 2 < 1
        box = (xx >= 21) & (xx < 30) & (yy > 15) & (yy < 26) & (i % 2 == 0)  # odd frames bare
        d = np.where(person, 2.4 - 0.08 * np.cos((xx - 15) / 4), 2.5) + 0.005 * rng.random((30, 40))
        depth[i] = np.where(person | box, d * 1000, 0).astype(np.uint16)
        labels[i] = np.where(person, 1, np.where(box, 2, 0))
    write_trainset(tmp_path, depth, labels, INTR, CLUTTER_CLASSES)
    cfg = ForestConfig(trees=1, max_depth=6, min_samples=2, feature_pool=32,
                       candidates_per_node=16, thresholds_per_candidate=8, pixels_per_frame=200,
                       threads=1, device="cpu")  # fmt: skip
    model = tmp_path / "clutter.npz"
    save_forest(model, train_forest(TrainSet(tmp_path), cfg, log=None))
    called, person, clutter = set_calls(model, tmp_path)
    assert called.shape == (8, len(THRESHOLDS), 2)
    assert (person == (labels == 1).reshape(8, -1).sum(1)).all()
    assert (clutter[1::2] == 0).all() and (clutter[::2] > 0).all()
    taken = called.sum(0)
    assert (np.diff(taken[:, 0]) <= 0).all() and (np.diff(taken[:, 1]) <= 0).all()  # stricter
    assert taken[0, 1] > 0.5 * clutter.sum()
    assert main(["--model", str(model), "--data", str(tmp_path)]) == 0
    assert "threshold:" in capsys.readouterr().out
