"""``python -m depthmocap.train.evaluation.real_benchmark``: the shipped system on real depth
recordings that carry a reference skeleton (``train-import --utd-mhad``), scored as agreement.

    python -m depthmocap.train.evaluation.real_benchmark --data DIR --out OUT
        [--select 'a05_*'] [--limit N] [--threads 1] [--sheet PNG] [--typical-sheet PNG]
        [--refuted-sheet PNG] [--config AB.yaml]

For every recording under ``--data`` with a ``reference.npz``, runs ``runtime-track`` in a
subprocess (``train`` never imports ``runtime``) fully automatic: the default mode (hybrid),
the shipped forest and settings, the average body; no ``--body`` or ``--preset``, and no
``--config`` unless one is given to compare settings (the reported run has none; the settings
are recorded in ``OUT/settings.yaml`` and results made with others are never reused).
Nothing of the reference reaches the run (``runtime-track`` reads only ``groundtruth.npz``, for
a start pose, and these recordings have none). Each result is scored with
:func:`train.evaluation.evaluate` against the reference, then pooled by action (the name's
prefix before the first ``_``: ``a05``) and over all data: offset-normalized mean joint
distance, share of joints within 10 cm after normalization, share of frames with a joint
beyond 20 cm after normalization (frames without a pose count as such), the shares of detector
and lost frames and the processing rate. Pooling is over joint estimates and frames, not a mean
of per-recording means; each recording keeps its own offsets (Helten IV-C normalizes per
sequence).

The reference is another tracker (the Kinect SDK's skeleton): the figures say how far the two
trackers agree, not how accurate either is.

Writes ``OUT/results/NAME`` (each run, with ``--save-overlays``), ``OUT/report.json`` and
contact sheets: the worst frames (each recording's frame with the largest normalized joint
distance, the largest first, one per recording) and, with ``--typical-sheet``, one frame per
action at its median. A result already complete in ``OUT/results`` is reused unless
``--retrack``.

Where the two trackers disagree, the depth image can say which one is wrong: a joint off the
person's pixels, or in the space in front of the surface the camera sees, cannot be right
(:mod:`.depth_refutation`). The report counts, at each failed frame's worst joint, whose
joint is refuted, the shares of all joints refuted on each side, and, as a diagnostic beside
the table (never in its place), the agreement with the reference's refuted joints left out;
``--refuted-sheet`` draws the largest such disagreements.
"""

from __future__ import annotations

import argparse
import fnmatch
import hashlib
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from depthmocap.shared.recording import Recording, RecordingError, mapped_reference
from depthmocap.train.importers.utd_mhad import ACTION_NAMES

from . import depth_refutation as dr
from . import metrics as m
from . import overlay_sheet as sheet
from .dev_benchmark import _run as run_command
from .evaluate import EvalConfig, EvaluationError, evaluate
from .result_io import ResultFileError, load_result

__all__ = [
    "Scored",
    "pooled",
    "per_joint",
    "worst_frames",
    "typical_frames",
    "refuted_frames",
    "refuted_joints",
    "main",
]

TILE = (150, 200)  # (width, height) cut around the person: a standing person is ~170 px tall
TILE_SCALE = 2


@dataclass
class Scored:
    """One recording's evaluation, kept for pooling.

    Attributes:
        name: recording name (``a05_s1_t1``); group: its action (``a05``).
        report: :func:`train.evaluation.evaluate`'s report.
        norm_errors_m: (F, J) offset-normalized joint distances, metres, NaN without a pose.
        frame_errors_mm: (F,) raw mean joint distance per frame, NaN without a pose.
        joint_names: the J joints.
        reference_refuted, ours_refuted: (F, J) bool, the joints the depth image refutes
            (:func:`depth_refutation.refuted`; ours False without a pose); None: none.
        observed: (F, J) the result's observed flags (1, 0, NaN where the frame has none);
            None: not kept.
    """

    name: str
    group: str
    report: dict
    norm_errors_m: np.ndarray
    frame_errors_mm: np.ndarray
    joint_names: tuple[str, ...]
    reference_refuted: np.ndarray | None = None
    ours_refuted: np.ndarray | None = None
    observed: np.ndarray | None = None

    def refuted(self, which: str) -> np.ndarray:
        """``reference`` or ``ours``: (F, J) bool, all False when not measured."""
        flags = getattr(self, f"{which}_refuted")
        return np.zeros(self.norm_errors_m.shape, bool) if flags is None else flags

    def sides(self, beyond_m: float) -> dict[str, int]:
        """Of the frames with a pose and a joint beyond ``beyond_m`` after normalization, how
        many fall in each :data:`depth_refutation.SIDES` class at their worst joint."""
        counts = dict.fromkeys(dr.SIDES, 0)
        worst, joint = _frame_worst(self)
        frames = np.flatnonzero(np.nan_to_num(worst) > beyond_m)
        ref = self.refuted("reference")[frames, joint[frames]]
        ours = self.refuted("ours")[frames, joint[frames]]
        for r, o in zip(ref, ours):
            counts[dr.classify(r, o)] += 1
        return counts


def _stack(scored: list[Scored], attr: str) -> np.ndarray:
    names = {s.joint_names for s in scored}
    if len(names) > 1:
        raise EvaluationError(f"recordings evaluate different joints: {sorted(names)}")
    return np.concatenate([getattr(s, attr) for s in scored], 0)


def pooled(scored: list[Scored], cfg: EvalConfig | None = None) -> dict:
    """The table's figures over a group of recordings (module docstring), None where a figure
    has nothing to count."""
    cfg = EvalConfig() if cfg is None else cfg
    norm = _stack(scored, "norm_errors_m")
    counts = {k: sum(s.report["status_counts"].get(k, 0) for s in scored) for k in
              ("tracked", "detected", "lost")}  # fmt: skip
    written = sum(counts.values())
    seconds = sum(
        sum(s.report["status_counts"].values()) / s.report["fps"]
        for s in scored
        if s.report.get("fps")
    )

    def share(n: float) -> float | None:
        return 100.0 * n / written if written else None

    def finite(v: float) -> float | None:
        return float(v) if np.isfinite(v) else None

    raw = _stack(scored, "frame_errors_mm")
    beyond = cfg.failure_threshold_m
    per = [s.sides(beyond) for s in scored]
    sides = {k: sum(c[k] for c in per) for k in dr.SIDES}
    ref_bad = np.concatenate([s.refuted("reference") for s in scored], 0)
    ours_bad = np.concatenate([s.refuted("ours") for s in scored], 0)
    posed = np.isfinite(norm)
    kept = np.where(ref_bad, np.nan, norm)  # the reference's refuted joints left out
    flags = [s.observed if s.observed is not None else np.full(s.norm_errors_m.shape, np.nan)
             for s in scored]  # fmt: skip
    observed = np.concatenate(flags, 0)
    said = np.isfinite(observed) & posed
    # As on synthetic recordings: a joint without a flag counts, only one called inferred
    # is left out.
    counted = np.where(np.isfinite(observed), observed > 0.5, True)
    return {
        "recordings": len(scored),
        "frames": int(len(norm)),
        "raw_mean_mm": finite(np.nanmean(raw)) if np.isfinite(raw).any() else None,
        "normalized_mean_mm": finite(m.mean_error_mm(norm)),
        "within_10cm_pct": finite(100.0 * m.precision_at(norm, cfg.precision_threshold_m)),
        "frames_beyond_20cm_pct": finite(
            m.percent(m.system_failures(norm, cfg.failure_threshold_m))
        ),
        "detected_pct": share(counts["detected"]),
        "lost_pct": share(counts["lost"]),
        "fps": written / seconds if seconds > 0 else None,
        "beyond_20cm_frames_by_side": sides,
        "reference_refuted_joints_pct": finite(100.0 * ref_bad[posed].mean())
        if posed.any()
        else None,
        "ours_refuted_joints_pct": finite(100.0 * ours_bad[posed].mean()) if posed.any() else None,
        "normalized_mean_mm_reference_not_refuted": finite(m.mean_error_mm(kept))
        if np.isfinite(kept).any()
        else None,
        "frames_beyond_20cm_pct_reference_not_refuted": finite(
            m.percent(m.system_failures(norm, beyond, counted=~ref_bad))
        ),
        "observed_joints_pct": finite(100.0 * (observed[said] > 0.5).mean())
        if said.any()
        else None,
        "frames_beyond_20cm_observed_pct": finite(
            m.percent(m.system_failures(norm, beyond, counted=counted))
        )
        if said.any()
        else None,
    }


def per_joint(scored: list[Scored], cfg: EvalConfig | None = None) -> dict[str, dict]:
    """Per joint over all ``scored``: normalized mean mm, % within 10 cm, % beyond 20 cm."""
    cfg = EvalConfig() if cfg is None else cfg
    norm = _stack(scored, "norm_errors_m")
    mean = m.per_joint_error_mm(norm)
    within = 100.0 * m.per_joint_precision_at(norm, cfg.precision_threshold_m)
    beyond = m.per_joint_failure_pct(norm, cfg.failure_threshold_m)

    def finite(v: float) -> float | None:
        return float(v) if np.isfinite(v) else None

    return {
        n: {"normalized_mean_mm": finite(a), "within_10cm_pct": finite(b),
            "beyond_20cm_pct": finite(c)}
        for n, a, b, c in zip(scored[0].joint_names, mean, within, beyond)
    }  # fmt: skip


def _frame_worst(s: Scored) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: the largest normalized distance (NaN without a pose) and its joint index."""
    e = np.where(np.isfinite(s.norm_errors_m), s.norm_errors_m, -1.0)
    joint = e.argmax(1)
    worst = e[np.arange(len(e)), joint]
    return np.where(worst >= 0, worst, np.nan), joint


def _pick(s: Scored, frame: int, worst: np.ndarray, joint: np.ndarray) -> dict:
    return {
        "recording": s.name,
        "frame": int(frame),
        "joint": s.joint_names[int(joint[frame])],
        "distance_mm": float(worst[frame] * 1e3),
    }


def worst_frames(scored: list[Scored], count: int) -> list[dict]:
    """Each recording's frame with the largest normalized joint distance, largest first, at
    most ``count``: ``{recording, frame, joint, distance_mm}``."""
    picks = []
    for s in scored:
        worst, joint = _frame_worst(s)
        if np.isfinite(worst).any():
            picks.append(_pick(s, int(np.nanargmax(worst)), worst, joint))
    return sorted(picks, key=lambda p: -p["distance_mm"])[:count]


def refuted_frames(scored: list[Scored], count: int, beyond_m: float) -> list[dict]:
    """Each recording's largest disagreement beyond ``beyond_m`` whose worst joint the depth
    image refutes on the reference's side only (:mod:`.depth_refutation`), largest first, at
    most ``count``: where the reference, not our result, is wrong."""
    picks = []
    for s in scored:
        worst, joint = _frame_worst(s)
        rows = np.arange(len(worst))
        theirs = s.refuted("reference")[rows, joint] & ~s.refuted("ours")[rows, joint]
        candidates = np.where(theirs & (np.nan_to_num(worst) > beyond_m), worst, np.nan)
        if np.isfinite(candidates).any():
            picks.append(_pick(s, int(np.nanargmax(candidates)), worst, joint))
    return sorted(picks, key=lambda p: -p["distance_mm"])[:count]


def typical_frames(scored: list[Scored]) -> list[dict]:
    """For each action, the frame whose largest normalized joint distance is the action's
    median of those: what agreement usually looks like."""
    out = []
    for group in sorted({s.group for s in scored}):
        members = [(s, *_frame_worst(s)) for s in scored if s.group == group]
        values = np.concatenate([w for _, w, _ in members])
        if not np.isfinite(values).any():
            continue
        median = np.nanmedian(values)
        s, worst, joint = min(members, key=lambda t: np.nanmin(np.abs(t[1] - median)))
        out.append(_pick(s, int(np.nanargmin(np.abs(worst - median))), worst, joint))
    return out


def _track(
    rec: Path,
    result: Path,
    threads: int,
    device: str | None,
    config: Path | None = None,
    model: Path | None = None,
    segmentation: Path | None = None,
) -> None:
    cmd = [sys.executable, "-m", "depthmocap.runtime.track_cli", "--input", str(rec),
           "--output", str(result), "--threads", str(threads), "--save-overlays", "-q"]  # fmt: skip
    if config is not None:
        cmd += ["--config", str(config)]
    if model is not None:
        cmd += ["--model", str(model)]
    if segmentation is not None:
        cmd += ["--segmentation-config", str(segmentation)]
    if device:
        cmd += ["--device", device]
    run_command(cmd)  # RuntimeError with the end of stderr if it fails


def _complete(result: Path, frames: int) -> bool:
    try:
        summary = json.loads((result / "summary.json").read_text())
    except (OSError, ValueError):
        return False
    return bool(summary.get("complete")) and summary.get("frames") == frames


def refuted_joints(
    rec_dir: Path, result_dir: Path, joint_names: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Every frame's reference joints and our joints that the depth image refutes
    (:mod:`.depth_refutation`): two (F, J) bool in ``joint_names`` order; ours False on frames
    without a pose."""
    rec = Recording(rec_dir)
    reference, names = mapped_reference(rec.reference())
    result = load_result(result_dir)
    ref_j = reference[:, [names.index(n) for n in joint_names]]
    ours_j = np.full_like(ref_j, np.nan)
    rows = result.frame < len(ref_j)
    ours_j[result.frame[rows]] = result.joints[rows][:, [result.joint_names.index(n)
                                                        for n in joint_names]]  # fmt: skip
    posed = np.isfinite(ours_j).all((1, 2))
    J = len(joint_names)
    # Both skeletons in one call per frame: the depth image is read and padded once.
    flags = np.zeros((len(ref_j), 2 * J), bool)
    for i in range(len(ref_j)):
        both = np.concatenate([ref_j[i], ours_j[i]])
        flags[i] = dr.refuted(rec.read_depth(i), both, rec.intrinsics)
    return flags[:, :J], flags[:, J:] & posed[:, None]


def score(rec: Path, result: Path) -> Scored:
    """Evaluate one result against its recording's reference."""
    ev = evaluate(rec, result)
    if ev.report["truth"] != "reference":
        raise EvaluationError(f"{rec}: has ground truth; this benchmark is for references")
    group = rec.name.split("_")[0]
    ref_bad, ours_bad = refuted_joints(rec, result, ev.joint_names)
    return Scored(rec.name, group, ev.report, ev.norm_errors_m, ev.frame_errors_mm,
                  ev.joint_names, ref_bad, ours_bad, ev.observed)  # fmt: skip


def _tile(data: Path, results: Path, pick: dict) -> np.ndarray | None:
    import cv2

    path = results / pick["recording"] / "overlays" / f"{pick['frame']:06d}.png"
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        return None
    rec = Recording(data / pick["recording"])
    joints, names = mapped_reference(rec.reference())
    ref_px = sheet.project(joints[pick["frame"]], rec.intrinsics)
    result = load_result(results / pick["recording"])
    row = np.flatnonzero(result.frame == pick["frame"])
    ours = None
    if len(row) and all(n in result.joint_names for n in names):
        pred = result.joints[row[0], [result.joint_names.index(n) for n in names]]
        ours = sheet.project(pred, rec.intrinsics)
    image = sheet.draw_reference(image, ref_px, names, pick["joint"], ours)
    around = ref_px if ours is None else np.concatenate([ref_px, ours])
    group = pick["recording"].split("_")[0]
    action = ACTION_NAMES.get(int(group[1:]), "") if group[1:].isdigit() else ""
    lines = [
        f"{pick['recording']} #{pick['frame']} {action}",
        f"{pick['joint']} {pick['distance_mm'] / 10:.0f} cm off",
    ]
    return sheet.caption(sheet.crop_around(image, around, TILE), lines, TILE_SCALE)


def write_sheet(path: Path, data: Path, results: Path, picks: list[dict], columns: int) -> int:
    """The contact sheet of ``picks`` as a PNG; returns the number of tiles drawn."""
    import cv2

    tiles = [t for t in (_tile(data, results, p) for p in picks) if t is not None]
    if tiles:
        path.parent.mkdir(parents=True, exist_ok=True)
        image = sheet.tile_sheet(tiles, columns)
        if not cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
            raise OSError(f"could not write {path}")
    return len(tiles)


def _fmt(v: float | None, digits: int = 1, unit: str = "") -> str:
    return "n/a" if v is None else f"{v:.{digits}f}{unit}"


HEADER = (
    "| action | takes | frames | normalized mm | raw mm | joints within 10 cm | "
    "frames with a joint > 20 cm | joints called observed | frames with an observed joint "
    "> 20 cm | detector frames | lost frames | frames/s |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|"
)


def format_row(label: str, p: dict) -> str:
    """One row of :data:`HEADER`."""
    return (
        f"| {label} | {p['recordings']} | {p['frames']} | {_fmt(p['normalized_mean_mm'])} | "
        f"{_fmt(p['raw_mean_mm'])} | {_fmt(p['within_10cm_pct'], 1, '%')} | "
        f"{_fmt(p['frames_beyond_20cm_pct'], 1, '%')} | "
        f"{_fmt(p.get('observed_joints_pct'), 1, '%')} | "
        f"{_fmt(p.get('frames_beyond_20cm_observed_pct'), 1, '%')} | "
        f"{_fmt(p['detected_pct'], 1, '%')} | "
        f"{_fmt(p['lost_pct'], 1, '%')} | {_fmt(p['fps'])} |"
    )


SIDES_HEADER = (
    "| action | frames with a joint > 20 cm | reference's joint refuted | ours refuted | "
    "both | neither | reference joints refuted | our joints refuted | normalized mm without "
    "the reference's refuted joints | frames with a joint > 20 cm, the same |\n"
    "|---|---|---|---|---|---|---|---|---|---|"
)


def format_sides_row(label: str, p: dict) -> str:
    """One row of :data:`SIDES_HEADER`: the failed frames with a pose, split by which
    tracker's worst joint the depth image refutes (% of them); the shares of all joints each
    tracker has refuted; and the agreement with the reference's refuted joints left out."""
    sides = p["beyond_20cm_frames_by_side"]
    n = sum(sides.values())

    def pct(key: str) -> str:
        return f"{100 * sides[key] / n:.1f}%" if n else "n/a"

    return (
        f"| {label} | {n} | {pct('reference_refuted')} | {pct('ours_refuted')} | "
        f"{pct('both_refuted')} | {pct('neither_refuted')} | "
        f"{_fmt(p['reference_refuted_joints_pct'], 1, '%')} | "
        f"{_fmt(p['ours_refuted_joints_pct'], 1, '%')} | "
        f"{_fmt(p['normalized_mean_mm_reference_not_refuted'])} | "
        f"{_fmt(p['frames_beyond_20cm_pct_reference_not_refuted'], 1, '%')} |"
    )


def format_joint_table(joints: dict[str, dict]) -> str:
    lines = [
        "| joint | normalized mm | within 10 cm | beyond 20 cm |",
        "|---|---|---|---|",
    ]
    for name, v in joints.items():
        lines.append(
            f"| {name} | {_fmt(v['normalized_mean_mm'])} | {_fmt(v['within_10cm_pct'], 1, '%')}"
            f" | {_fmt(v['beyond_20cm_pct'], 1, '%')} |"
        )
    return "\n".join(lines)


def _label(group: str) -> str:
    name = ACTION_NAMES.get(int(group[1:])) if group[1:].isdigit() else None
    return f"{group} {name}" if name else group


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train-real-benchmark", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, type=Path, help="folder of imported recordings")
    p.add_argument("--out", required=True, type=Path, help="results, report.json")
    p.add_argument("--select", default="*", help="only recordings whose name matches this glob")
    p.add_argument("--limit", type=int, help="only the first N recordings (by name)")
    p.add_argument("--threads", type=int, default=1, help="runtime-track --threads")
    p.add_argument("--device", choices=("cpu", "cuda"), help="runtime-track --device")
    p.add_argument(
        "--config", type=Path, help="runtime-track --config (settings over the shipped preset)"
    )
    p.add_argument(
        "--model", type=Path, help="runtime-track --model (another forest than the shipped one)"
    )
    p.add_argument(
        "--segmentation-config",
        type=Path,
        help="runtime-track --segmentation-config (e.g. the person/clutter forest)",
    )
    p.add_argument("--retrack", action="store_true", help="track again even if a result is there")
    p.add_argument(
        "--sheet", type=Path, help="worst-frames contact sheet PNG (default OUT/worst_frames.png)"
    )
    p.add_argument("--worst", type=int, default=12, help="tiles on the worst-frames sheet")
    p.add_argument("--typical-sheet", type=Path, help="also a sheet of each action's median frame")
    p.add_argument(
        "--refuted-sheet",
        type=Path,
        help="also a sheet of the largest disagreements where the depth image refutes the "
        "reference's joint (one per recording, --worst tiles)",
    )
    return p


def _settings_check(
    out: Path,
    config: Path | None,
    retrack: bool,
    model: Path | None = None,
    segmentation: Path | None = None,
) -> str | None:
    """Record the settings the results in ``out`` are tracked with (``OUT/settings.yaml``: the
    ``--config`` text, empty for the shipped preset, and a comment naming another forest by its
    content hash) and refuse to reuse results made with others; returns an error message or
    None."""
    if config is not None and not config.is_file():
        return f"--config: no such file {config}"
    if model is not None and not model.is_file():
        return f"--model: no such file {model}"
    if segmentation is not None and not segmentation.is_file():
        return f"--segmentation-config: no such file {segmentation}"
    text = "" if config is None else config.read_text()
    if segmentation is not None:
        text += f"\n# --segmentation-config {segmentation}\n{segmentation.read_text()}"
    if model is not None:
        digest = hashlib.sha256(model.read_bytes()).hexdigest()
        text += f"\n# --model {model} sha256 {digest}\n"
    saved = out / "settings.yaml"
    # Older outputs have no record: they were made with the shipped preset.
    before = saved.read_text() if saved.is_file() else ""
    if before != text and not retrack and (out / "results").is_dir():
        return (
            f"{out}: its results were tracked with other settings than --config gives; "
            "use another --out or --retrack"
        )
    out.mkdir(parents=True, exist_ok=True)
    saved.write_text(text)
    return None


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    problem = _settings_check(
        args.out, args.config, args.retrack, args.model, args.segmentation_config
    )
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    recs = sorted(
        d for d in args.data.glob("*")
        if (d / "reference.npz").is_file() and fnmatch.fnmatch(d.name, args.select)
    )[: args.limit]  # fmt: skip
    if not recs:
        print(f"error: {args.data}: no recording with a reference matches", file=sys.stderr)
        return 2
    results = args.out / "results"
    print(f"{len(recs)} recordings from {args.data}; reference: another tracker, not ground truth")
    scored: list[Scored] = []
    t0 = time.perf_counter()
    for i, rec in enumerate(recs):
        try:
            frames = len(Recording(rec))
            if args.retrack or not _complete(results / rec.name, frames):
                _track(
                    rec, results / rec.name, args.threads, args.device, args.config, args.model,
                    args.segmentation_config,
                )  # fmt: skip
            s = score(rec, results / rec.name)
        except (RecordingError, ResultFileError, EvaluationError, RuntimeError) as err:
            print(f"error: {rec.name}: {str(err).splitlines()[-1]}", file=sys.stderr)
            return 2
        scored.append(s)
        r = s.report
        print(
            f"[{i + 1}/{len(recs)} {time.perf_counter() - t0:.0f} s] {rec.name}: "
            f"{r['frames']} frames, {_fmt(r['mean_joint_error_offset_normalized_mm'])} mm "
            f"normalized, {_fmt(r['system_failure_offset_normalized_pct'])}% frames > 20 cm, "
            f"{_fmt(r['fps'])} frames/s",
            flush=True,
        )
    groups = {g: [s for s in scored if s.group == g] for g in sorted({s.group for s in scored})}
    by_group = {g: pooled(members) for g, members in groups.items()}
    everything = pooled(scored)
    joints = per_joint(scored)
    print("\nAgreement with the reference (Kinect SDK skeleton: another tracker, not ground "
          "truth); distances after offset normalization unless raw\n")  # fmt: skip
    print(HEADER)
    for g, p in by_group.items():
        print(format_row(_label(g), p))
    print(format_row("**all**", everything))
    print(
        "\nWhich side the depth image refutes at the worst joint of those frames (a joint "
        f"more than {dr.SLACK_PX} px off the person, or more than {dr.FREE_SPACE_M * 100:.0f} "
        "cm in front of the surface the camera sees there, is wrong), and the agreement "
        "without the reference's refuted joints (a diagnostic, not the table above)\n"
    )
    print(SIDES_HEADER)
    for g, p in by_group.items():
        print(format_sides_row(_label(g), p))
    print(format_sides_row("**all**", everything))
    print("\n" + format_joint_table(joints))
    worst = worst_frames(scored, args.worst)
    typical = typical_frames(scored)
    sheet_path = args.sheet or args.out / "worst_frames.png"
    drawn = write_sheet(sheet_path, args.data, results, worst, columns=6)
    print(f"\nworst frames: {sheet_path} ({drawn} tiles)")
    for w in worst:
        print(f"  {w['recording']} #{w['frame']}: {w['joint']} {w['distance_mm'] / 10:.0f} cm")
    if args.typical_sheet:
        drawn = write_sheet(args.typical_sheet, args.data, results, typical, columns=6)
        print(f"typical frames: {args.typical_sheet} ({drawn} tiles)")
    refuted = refuted_frames(scored, args.worst, EvalConfig().failure_threshold_m)
    if args.refuted_sheet:
        drawn = write_sheet(args.refuted_sheet, args.data, results, refuted, columns=6)
        print(f"the reference refuted by the depth: {args.refuted_sheet} ({drawn} tiles)")
    report = {
        "data": str(args.data),
        "select": args.select,
        "truth": "reference: Kinect SDK v1 skeleton (another tracker), not ground truth",
        "thresholds": {
            "within_m": EvalConfig().precision_threshold_m,
            "beyond_m": EvalConfig().failure_threshold_m,
        },  # fmt: skip
        "by_action": {_label(g): p for g, p in by_group.items()},
        "all": everything,
        "per_joint": joints,
        "worst_frames": worst,
        "typical_frames": typical,
        "reference_refuted_frames": refuted,
        "per_recording": {s.name: s.report for s in scored},
        "seconds": time.perf_counter() - t0,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "report.json").write_text(json.dumps(report, indent=1, allow_nan=False) + "\n")
    print(f"full report: {args.out / 'report.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
