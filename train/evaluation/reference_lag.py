"""How far a reference skeleton's stream is out of step with its depth frames, from the depth
alone.

    python -m depthmocap.train.evaluation.reference_lag --data DIR [--lags -1 0 1 2 3 4]
                                                        [--select 'a2*']

A joint of the body can neither lie off the person's pixels nor in the empty space the camera
sees in front of them (:mod:`depth_refutation`). Pairing each reference skeleton ``k`` with the
depth frame ``k + lag`` for a range of lags, the lag at which the depth refutes the fewest of
the reference's joints is the one at which the two streams show the same moment. No tracker
of ours is involved, so the lag found cannot favour our results. It matters for fast motion:
a wrist swung at 3 m/s moves 10 cm a frame.

Prints, per action (the recording name's prefix before ``_``) and over all recordings, the
refuted joints at each lag, the best lag and a parabola's vertex through the best and its two
neighbours (sub-frame). On recordings imported with ``train-import --skeleton-lag L`` the
lags printed are relative to ``L`` (0 is as imported).
"""

from __future__ import annotations

import argparse
import fnmatch
import sys
from pathlib import Path

import numpy as np
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.recording import Recording, RecordingError, mapped_reference

from . import depth_refutation as dr

__all__ = ["refuted_by_lag", "lag_vertex", "main"]


def refuted_by_lag(
    depth_m: list[np.ndarray] | np.ndarray,
    reference: np.ndarray,
    intr: Intrinsics,
    lags: list[int] | tuple[int, ...],
) -> np.ndarray:
    """Reference joints the depth refutes when skeleton ``k`` is paired with depth ``k + lag``.

    Only the skeletons that have a partner at every lag are counted, so every lag is scored
    on the same skeletons.

    Args:
        depth_m: T frames (H, W) of the person's depth in metres, 0 elsewhere.
        reference: (T, J, 3) camera-frame joints, index by index with ``depth_m``.
        intr: the depth camera.
        lags: L lags in frames.
    Returns:
        (L,) int counts of refuted joints.
    """
    T = len(reference)
    lo, hi = max(0, -min(lags)), T - max(0, max(lags))  # skeletons with a partner at every lag
    counts = np.zeros(len(lags), dtype=np.int64)
    for k in range(lo, hi):
        for i, lag in enumerate(lags):
            counts[i] += int(dr.refuted(depth_m[k + lag], reference[k], intr).sum())
    return counts


def lag_vertex(lags: list[int] | tuple[int, ...], counts: np.ndarray) -> float:
    """Sub-frame lag: the vertex of the parabola through the fewest refutations and its two
    neighbours; the best lag itself at the end of the range, the middle of a flat minimum
    (several lags equally best, as on a take too slow for the lag to show).

    Args:
        lags: L consecutive integer lags, ascending; counts: (L,) refuted joints at each.
    """
    counts = np.asarray(counts, dtype=np.float64)
    best = np.flatnonzero(counts == counts.min())
    if len(best) > 1:
        return float(np.mean(np.asarray(lags, dtype=np.float64)[best]))
    b = int(best[0])
    if b == 0 or b == len(counts) - 1:
        return float(lags[b])
    left, mid, right = counts[b - 1 : b + 2]
    curvature = left - 2 * mid + right
    if curvature <= 0:
        return float(lags[b])
    return float(lags[b] + 0.5 * (left - right) / curvature)


def _recordings(data: Path, select: str | None) -> list[Path]:
    found = sorted(p for p in data.iterdir() if (p / "reference.npz").is_file())
    return [p for p in found if select is None or fnmatch.fnmatch(p.name, select)]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.reference_lag",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument(
        "--data", required=True, type=Path, help="folder of recordings with reference.npz"
    )
    p.add_argument("--lags", type=int, nargs="+", default=[-1, 0, 1, 2, 3, 4],
                   help="lags to score, consecutive integers (frames)")  # fmt: skip
    p.add_argument("--select", help="only recordings whose name matches this glob")
    args = p.parse_args(argv)
    lags = sorted(set(args.lags))
    if lags != list(range(lags[0], lags[-1] + 1)):
        print("error: --lags must be consecutive integers", file=sys.stderr)
        return 2
    try:
        recs = _recordings(args.data, args.select) if args.data.is_dir() else []
        if not recs:
            raise RecordingError(f"{args.data}: no recording with a reference.npz")
        by_group: dict[str, np.ndarray] = {}
        for path in recs:
            rec = Recording(path)
            reference, _ = mapped_reference(rec.reference())
            if len(reference) <= lags[-1] - lags[0]:
                continue  # too short to score every lag
            depth = [rec.read_depth(i) for i in range(len(rec))]
            counts = refuted_by_lag(depth, reference, rec.intrinsics, lags)
            group = path.name.split("_")[0]
            by_group[group] = by_group.get(group, 0) + counts
    except (RecordingError, OSError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if not by_group:
        print(f"error: every recording is shorter than {lags[-1] - lags[0] + 1} frames",
              file=sys.stderr)  # fmt: skip
        return 2
    print("| recordings | " + " | ".join(f"lag {g}" for g in lags) + " | best | vertex |")
    print("|---" * (len(lags) + 3) + "|")
    total = sum(by_group.values())
    for name, counts in [*sorted(by_group.items()), ("all", total)]:
        cells = " | ".join(str(int(c)) for c in counts)
        best = lags[int(np.argmin(counts))]
        print(f"| {name} | {cells} | {best} | {lag_vertex(lags, counts):.2f} |")
    best = lags[int(np.argmin(total))]
    print(
        f"refuted reference joints by lag over {len(recs)} recordings; "
        f"best lag {best}, vertex {lag_vertex(lags, total):.2f} frames"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
