"""``python -m depthmocap.train.evaluation.part_agreement``: the forest's body parts against parts
drawn from a skeleton, the forest's check on real depth, where no part labels exist.

Every person pixel is given the part group of the skeleton bone on whose surface it lies: its
distance from each bone's axis, less a radius typical of that bone, is its cost, and a pixel
counts only when one group is clearly cheapest (by ``margin_m``) and close (``max_cost_m``).
The forest's 19 parts are pooled into the same 10 groups (clavicles with the torso, the neck
with the head, each thigh and shank whole) and compared pixel by pixel. The skeleton is the
reference's on an imported real recording (UTD-MHAD: the Kinect SDK's joints, hands and feet
included) and the ground truth's on a synthetic one; on a synthetic recording the drawn groups
are also scored against the rendered labels, which says how far the drawing itself can be
trusted.

It found what breaks first on real depth (docs/real_data.md): the shipped forest agrees on 93%
of the torso's pixels but on 34-35% of the thighs' and 13-18% of the shanks' (93-95% and
84-92% on rendered bodies): it labels trousered legs as abdomen and thighs.

    python -m depthmocap.train.evaluation.part_agreement --data /work/data/utd \\
        --model models/forest.npz [--select 'a2*'] [--every 4]
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import sys
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared.camera import depth_to_points
from depthmocap.shared.forest_format import ForestFormatError, load_forest
from depthmocap.shared.labels import PART_NAMES
from depthmocap.shared.posterior_smoothing import smooth_posteriors
from depthmocap.shared.recording import Recording, RecordingError
from depthmocap.train.forest.predict import predict_posteriors

__all__ = [
    "PART_GROUPS",
    "PART_GROUP",
    "skeleton_bones",
    "groups_from_bones",
    "agreement",
    "main",
]

PART_GROUPS: tuple[str, ...] = (
    "torso", "head", "l_upper_arm", "r_upper_arm", "l_forearm", "r_forearm",
    "l_thigh", "r_thigh", "l_shank", "r_shank",
)  # fmt: skip
# Typical surface distance from each group's bone axis (m): a pixel on the bone's surface costs
# about nothing, one on a neighbouring bone's surface its distance from that surface.
GROUP_RADIUS_M = np.array([0.11, 0.08, 0.045, 0.045, 0.035, 0.035, 0.07, 0.07, 0.05, 0.05])


def _group_of_part(name: str) -> int:
    if name in ("pelvis", "abdomen", "chest", "l_clavicle", "r_clavicle"):
        return PART_GROUPS.index("torso")
    if name in ("neck", "head"):
        return PART_GROUPS.index("head")
    for group in PART_GROUPS[2:]:
        if name.startswith(group):
            return PART_GROUPS.index(group)
    raise ValueError(f"part {name!r} has no group")


# (C,) group of each forest class; -1 for the background.
PART_GROUP = np.array([-1] + [_group_of_part(n) for n in PART_NAMES[1:]], dtype=np.int64)


def _bone_table(torso: list[tuple[str, str]], head: tuple[str, str], sides, limbs) -> list:
    """(from, to, group) for the torso bones, the head and each side's limb chains."""
    table = [(a, b, "torso") for a, b in torso] + [(*head, "head")]
    for side, s in sides:
        for group, chain in limbs:
            table += [(f"{side}_{a}", f"{side}_{b}", f"{s}_{group}") for a, b in chain]
    return table


# Bones as (from, to, group) in the two joint vocabularies: ours (shared.skeleton) and the
# Kinect SDK v1's (train.importers.utd_mhad). A hand or foot beyond the wrist or ankle extends
# the forearm or shank; ours has none, so an 8 cm hand is added along the forearm.
_LIMBS = (
    ("upper_arm", [("shoulder", "elbow")]),
    ("forearm", [("elbow", "wrist"), ("wrist", "hand")]),
    ("thigh", [("hip", "knee")]),
    ("shank", [("knee", "ankle"), ("ankle", "foot")]),
)
_OURS = _bone_table(
    [("pelvis", "spine"), ("spine", "neck"), ("neck", "l_shoulder"), ("neck", "r_shoulder"),
     ("pelvis", "l_hip"), ("pelvis", "r_hip")],
    ("neck", "head"),
    (("l", "l"), ("r", "r")),
    [(g, [(a, b) for a, b in chain if b != "foot"]) for g, chain in _LIMBS],
)  # fmt: skip
_SDK = _bone_table(
    [("hip_center", "spine"), ("spine", "shoulder_center"), ("shoulder_center", "left_shoulder"),
     ("shoulder_center", "right_shoulder"), ("hip_center", "left_hip"),
     ("hip_center", "right_hip")],
    ("shoulder_center", "head"),
    (("left", "l"), ("right", "r")),
    _LIMBS,
)  # fmt: skip
HAND_LENGTH_M = 0.08


def skeleton_bones(joints: np.ndarray, names) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bones of one skeleton, ours or the Kinect SDK's (chosen by its joint names).

    Args:
        joints: (J, 3) positions; names: the J joint names.
    Returns:
        a, b: (S, 3) bone ends; group: (S,) int64 index into :data:`PART_GROUPS`.
    """
    index = {str(n): i for i, n in enumerate(names)}
    table = _SDK if "hip_center" in index else _OURS
    pos = {n: np.asarray(joints[i], np.float64) for n, i in index.items()}
    for s in "lr":  # our hands: the forearm carried on past the wrist
        if f"{s}_wrist" in pos and f"{s}_elbow" in pos and f"{s}_hand" not in pos:
            fore = pos[f"{s}_wrist"] - pos[f"{s}_elbow"]
            pos[f"{s}_hand"] = pos[f"{s}_wrist"] + HAND_LENGTH_M * fore / max(
                float(np.linalg.norm(fore)), 1e-9
            )
    missing = sorted({n for a, b, _ in table for n in (a, b)} - set(pos))
    if missing:
        raise ValueError(f"skeleton lacks joints {', '.join(missing)}")
    a = np.stack([pos[x] for x, _, _ in table])
    b = np.stack([pos[y] for _, y, _ in table])
    return a, b, np.array([PART_GROUPS.index(g) for _, _, g in table], dtype=np.int64)


def groups_from_bones(
    points: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    group: np.ndarray,
    margin_m: float = 0.03,
    max_cost_m: float = 0.06,
) -> tuple[np.ndarray, np.ndarray]:
    """The part group of each point, from the bone surface it lies on.

    Args:
        points: (N, 3); a, b: (S, 3) bone ends; group: (S,) group index of each bone.
        margin_m: the cheapest group must beat the next by this much to count (m).
        max_cost_m: and lie at most this far from its typical surface (m).
    Returns:
        group: (N,) int64 cheapest group; confident: (N,) bool.
    """
    ab = b - a  # (S, 3)
    t = np.einsum("nsk,sk->ns", points[:, None] - a[None], ab) / np.maximum(
        np.einsum("sk,sk->s", ab, ab), 1e-12
    )
    closest = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]  # (N, S, 3)
    cost = np.abs(np.linalg.norm(points[:, None] - closest, axis=-1) - GROUP_RADIUS_M[group])
    per_group = np.full((points.shape[0], len(PART_GROUPS)), np.inf)
    for g in np.unique(group):
        per_group[:, g] = cost[:, group == g].min(1)
    order = np.sort(per_group, axis=1)
    confident = (order[:, 1] - order[:, 0] > margin_m) & (order[:, 0] < max_cost_m)
    return per_group.argmin(1), confident


def agreement(confusion: np.ndarray) -> dict:
    """Per group and overall share of the drawn group's pixels the forest gives that group.

    Args:
        confusion: (G, G) pixel counts, rows the drawn group, columns the forest's.
    """
    rows = confusion.sum(1)
    per = {
        g: (float(confusion[i, i] / rows[i]) if rows[i] else None)
        for i, g in enumerate(PART_GROUPS)
    }
    total = confusion.sum()
    return {
        "pixels": int(total),
        "overall": float(np.trace(confusion) / total) if total else None,
        "per_group": per,
    }


def _skeleton(rec: Recording) -> tuple[np.ndarray, list[str]]:
    source = rec.reference() if rec.has_reference else rec.groundtruth()
    return source["joints"], [str(n) for n in source["joint_names"]]


def score_recordings(
    recs: list[Path], forest, every: int, smooth_window: int, smooth_gate_m: float
) -> dict[str, np.ndarray]:
    """Confusions over every ``every``-th frame: ``forest`` (drawn against the forest's) and,
    where rendered labels exist, ``forest_vs_labels`` and ``drawn_vs_labels``."""
    n = len(PART_GROUPS)
    out = {k: np.zeros((n, n), np.int64) for k in ("forest", "forest_vs_labels", "drawn_vs_labels")}
    for path in recs:
        rec = Recording(path)
        joints, names = _skeleton(rec)
        scale = forest.offset_scale(rec.intrinsics.fx, rec.intrinsics.fy)
        for i in range(0, len(rec), every):
            if not np.all(np.isfinite(joints[i])):
                continue
            depth = torch.from_numpy(rec.read_depth(i).astype(np.float32))[None]
            truth = rec.read_labels(i) if rec.has_labels else None
            # A real recording's stored depth is the person (its background removed).
            mask = depth > 0 if truth is None else torch.from_numpy(truth > 0)[None] & (depth > 0)
            pix, post = predict_posteriors(forest, depth, mask, scale)
            post = smooth_posteriors(pix, post, depth, smooth_window, smooth_gate_m)
            forest_group = PART_GROUP[post.argmax(1).numpy()]
            v, u = pix[:, 1].numpy(), pix[:, 2].numpy()
            points = depth_to_points(depth[0], rec.intrinsics).numpy()[v, u].astype(np.float64)
            drawn, confident = groups_from_bones(points, *skeleton_bones(joints[i], names))
            keep = confident & (forest_group >= 0)
            np.add.at(out["forest"], (drawn[keep], forest_group[keep]), 1)
            if truth is not None:
                true_group = PART_GROUP[truth[v, u]]
                keep &= true_group >= 0
                np.add.at(out["forest_vs_labels"], (true_group[keep], forest_group[keep]), 1)
                np.add.at(out["drawn_vs_labels"], (true_group[keep], drawn[keep]), 1)
    return out


def _short(model: Path) -> str:
    """A forest's name for the table: its file name, with its folder when that is generic."""
    return model.name if model.name != "forest.npz" else f"{model.parent.name}/{model.name}"


def _table(name: str, result: dict) -> str:
    cells = " ".join(
        f"{'-' if a is None else f'{100 * a:.1f}':>11}" for a in result["per_group"].values()
    )
    overall = "-" if result["overall"] is None else f"{100 * result['overall']:.1f}"
    return f"{name:<24}{cells} {overall:>8}"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.part_agreement",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("--data", required=True, type=Path, help="folder of recordings")
    p.add_argument("--model", action="append", type=Path, help="forest(s) to score")
    p.add_argument("--select", default="*", help="only recordings whose name matches this glob")
    p.add_argument("--every", type=int, default=4, help="every N-th frame")
    p.add_argument(
        "--smooth-window", type=int, default=5, help="posterior smoothing, as the hybrid"
    )
    p.add_argument("--smooth-gate", type=float, default=0.05, help="its depth gate (m)")
    p.add_argument("--out", type=Path, help="also write the figures to this JSON file")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    models = args.model or [Path("models/forest.npz")]
    recs = sorted(
        d for d in args.data.glob("*")
        if d.is_dir() and (d / "meta.json").is_file() and fnmatch.fnmatch(d.name, args.select)
    )  # fmt: skip
    if not recs:
        print(f"error: {args.data}: no recording matches", file=sys.stderr)
        return 2
    if args.every < 1:
        print("error: --every must be at least 1", file=sys.stderr)
        return 2
    header = f"{'':<24}" + " ".join(f"{g:>11}" for g in PART_GROUPS) + f" {'all':>8}"
    print(f"{len(recs)} recordings from {args.data}; share of each drawn group's pixels")
    print(header)
    report = {}
    for model in models:
        try:
            forest = load_forest(model, PART_NAMES)
            counts = score_recordings(
                recs, forest, args.every, args.smooth_window, args.smooth_gate
            )
        except (ForestFormatError, RecordingError, ValueError, OSError) as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
        # A frame set with no confidently drawn pixel still gets its row ("-" throughout).
        results = {k: agreement(c) for k, c in counts.items() if k == "forest" or c.sum()}
        report[str(model)] = results
        print(_table(_short(model), results["forest"]))
        if "forest_vs_labels" in results:
            print(_table("  against rendered labels", results["forest_vs_labels"]))
            print(_table("  drawn groups' own", results["drawn_vs_labels"]))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
