"""The person/clutter forest's threshold, chosen on a held-out rendered set.

``segmentation.clutter_threshold`` decides how sure the forest must be before a mask pixel
leaves as furniture. A pixel of the person taken out costs the tracker data (on the broad
tuning set a forest at 0.5, which calls 1.1% of a furniture-free person clutter, cost 2.4 mm);
a seat left in costs less. So the threshold is the lowest of :data:`THRESHOLDS` at which the
forest calls at most :data:`MAX_PERSON_LOSS` of the person's pixels clutter on the held-out
frames *without* furniture, the case of every user without a chair.

Per threshold the table gives, on a person/clutter set (``make synth-clutter``'s
``data/synth_clutter_eval``: seed 6, not trained on): the share of person pixels called
clutter over all frames and over the frames without furniture, and the share of furniture
pixels caught. What is taken out as the runtime takes it: the forest's posteriors smoothed
over :data:`~shared.labels.CLUTTER_SMOOTH_WINDOW` pixels at the same depth, then only the
clutter reaching the mask's outline (``shared.mask_outline``)::

    python -m depthmocap.train.evaluation.clutter_threshold --model models/clutter_forest.npz \\
        --data data/synth_clutter_eval
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared.forest_format import load_forest
from depthmocap.shared.labels import CLUTTER_CLASSES, CLUTTER_SMOOTH_WINDOW
from depthmocap.shared.mask_outline import reaching_outline
from depthmocap.shared.posterior_smoothing import smooth_posteriors
from depthmocap.train.forest.predict import predict_posteriors
from depthmocap.train.synth.trainset import TrainSet

__all__ = ["MAX_PERSON_LOSS", "THRESHOLDS", "choose_threshold", "threshold_table"]

THRESHOLDS = (0.5, 0.6, 0.7, 0.8, 0.9)
# At most this share of a furniture-free person's pixels may be called clutter.
MAX_PERSON_LOSS = 0.001
# Neighbours farther in depth than this are not averaged in (the runtime's default, m).
SMOOTH_DEPTH_GATE_M = 0.05
PERSON, CLUTTER = CLUTTER_CLASSES.index("person"), CLUTTER_CLASSES.index("clutter")


def threshold_table(
    called: np.ndarray, person: np.ndarray, clutter: np.ndarray,
    thresholds: tuple[float, ...] = THRESHOLDS,
) -> list[dict]:  # fmt: skip
    """Per threshold: ``person_called`` (share of person pixels taken out), ``person_called_bare``
    (the same over the frames without furniture), ``clutter_caught``.

    Args:
        called: (F, T, 2) per frame and threshold, the person and the furniture pixels taken
            out.
        person, clutter: (F,) each frame's person and furniture pixels.
    """
    called = np.asarray(called, dtype=np.float64)
    person, clutter = np.asarray(person, np.float64), np.asarray(clutter, np.float64)
    bare = clutter == 0

    def share(num: np.ndarray, den: np.ndarray) -> float:
        return float(num.sum() / den.sum()) if den.sum() > 0 else float("nan")

    return [
        {"threshold": t, "person_called": share(called[:, k, 0], person),
         "person_called_bare": share(called[bare, k, 0], person[bare]),
         "clutter_caught": share(called[:, k, 1], clutter)}
        for k, t in enumerate(thresholds)
    ]  # fmt: skip


def choose_threshold(table: list[dict], max_person_loss: float = MAX_PERSON_LOSS) -> float:
    """The lowest threshold whose ``person_called_bare`` is at most ``max_person_loss``
    (the highest in the table if none is)."""
    ok = [row["threshold"] for row in table if row["person_called_bare"] <= max_person_loss]
    return min(ok) if ok else max(row["threshold"] for row in table)


def set_calls(
    model: Path, data: Path, every: int = 1, thresholds: tuple[float, ...] = THRESHOLDS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the filter takes out of every ``every``-th frame of the set ``data`` at each
    threshold, as the runtime does it (smoothed posteriors, clutter reaching the outline):
    :func:`threshold_table`'s ``called`` (F, T, 2), ``person`` (F,), ``clutter`` (F,)."""
    forest = load_forest(model, CLUTTER_CLASSES)
    ts = TrainSet(data)
    if tuple(ts.class_names) != CLUTTER_CLASSES:
        raise ValueError(f"{data}: not a person/clutter set (make synth-clutter)")
    scale = forest.offset_scale(ts.intrinsics.fx, ts.intrinsics.fy)
    called, person, clutter = [], [], []
    shard, first, index = None, 0, 0
    for i in range(0, ts.frames, every):
        while shard is None or i >= first + len(shard.labels):  # each shard read once
            first += 0 if shard is None else len(shard.labels)
            shard, index = ts.shard(index), index + 1
        lab = shard.labels[i - first]
        depth = torch.from_numpy(shard.depth[i - first][None].astype(np.float32) / 1000.0)
        mask = torch.from_numpy(lab[None] > 0)
        pix, post = predict_posteriors(forest, depth, mask, scale)
        post = smooth_posteriors(pix, post, depth, CLUTTER_SMOOTH_WINDOW, SMOOTH_DEPTH_GATE_M)
        dense = torch.zeros(lab.shape)
        dense[pix[:, 1], pix[:, 2]] = post[:, CLUTTER]
        is_person, is_clutter = lab == PERSON, lab == CLUTTER
        row = []
        for t in thresholds:
            out = reaching_outline((dense >= t) & mask[0], mask[0]).numpy()
            row.append(((out & is_person).sum(), (out & is_clutter).sum()))
        called.append(row)
        person.append(is_person.sum())
        clutter.append(is_clutter.sum())
    return np.array(called), np.array(person), np.array(clutter)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.clutter_threshold",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("--model", type=Path, required=True, help="person/clutter forest (.npz)")
    p.add_argument("--data", type=Path, required=True, help="held-out person/clutter set")
    p.add_argument("--every", type=int, default=1, help="every N-th frame only")
    args = p.parse_args(argv)
    table = threshold_table(*set_calls(args.model, args.data, args.every))
    print("| threshold | person pixels called clutter | the same, frames without furniture "
          "| furniture pixels caught |")  # fmt: skip
    print("|---|---|---|---|")
    for row in table:
        shares = (row["person_called"], row["person_called_bare"], row["clutter_caught"])
        print(f"| {row['threshold']:.1f} | " + " | ".join(f"{100 * x:.2f}%" for x in shares) + " |")
    print(f"threshold: {choose_threshold(table)} (the lowest calling at most "
          f"{100 * MAX_PERSON_LOSS:.1f}% of a furniture-free person clutter)")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
