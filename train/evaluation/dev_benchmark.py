"""``python -m depthmocap.train.evaluation.dev_benchmark``: the accuracy table on the dev recordings
(``make bench``).

For every recording under ``--recordings`` (``make dev-recordings``) and every requested
configuration, runs ``runtime-track`` in a subprocess (``train`` never imports ``runtime``),
evaluates the result with :func:`train.evaluation.evaluate`, and prints one row per
configuration averaged over the recordings (frame-weighted), as a Markdown table. Rows:

- ``tracker`` (ground-truth start, ground-truth body), its ablations (``no occlusion``,
  ``no silhouette``, ``no extra depth``) and ``tracker, default body``;
- ``hybrid``, ``detector`` and ``shotton`` (no ground truth at run time; need the forest);
  ``hybrid, default body`` is plain ``runtime-track`` (no body given, nothing calibrated);
  ``hybrid, calibrated body`` is Wei's whole system: the body from ``runtime-calibrate`` on
  the same person's T-pose recording, the pose from the forest, no ground truth anywhere;
  ``hybrid, ground-truth labels`` is a diagnostic, not a system: the recording's own part
  labels instead of the forest's (what the forest's label errors cost).

The tracker is chaotic where a limb is hidden: a small change anywhere moves a few frames of
a far arm across the 20 cm system-failure line, so one run's system failure varies by about
half a percent. ``--trust-regions 0.18 0.2 0.22`` runs every hybrid configuration once per
tracker trust region (``max_step_rad``) and adds the runs' mean as a row of its own.

``--protocol broad`` evaluates the frozen broad dev protocol (``make dev-protocol``,
:mod:`train.evaluation.protocol`, ``docs/protocol.md``): the recordings of
``data/dev_broad/manifest.json`` (all of them, unless ``--limit``), by default only the
headline row, ``hybrid, default body`` (the fully automatic system); rows that use the
recording's true body or labels are marked as diagnostics. After the table come the same
figures per motion class, per camera (frontal, side), per cut (uncut, feet, arm) and per
body (sex, height class), frame-weighted within each group.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from depthmocap.shared.config import load_settings
from depthmocap.shared.recording import Recording
from depthmocap.train.evaluation.body_lengths import bone_length_errors, format_bone_length_errors
from depthmocap.train.evaluation.evaluate import evaluate, format_failed_frames
from depthmocap.train.evaluation.protocol import PROTOCOL_VERSION, load_manifest, manifest_groups

# name -> (mode, body, settings overriding the mode's config). Bodies: "gt" (the rendered
# body's skeleton), "default" (average adult), "personalized" (runtime-personalize on the same
# anny body's two calibration views, Helten III), "calibrated" (runtime-calibrate, Wei 6, on
# the body holding the T-pose: data/dev_calib, forest labels). A setting equal to RECORDING
# is replaced by the recording's directory.
RECORDING = "<recording>"
CONFIGS: dict[str, tuple[str, str, dict]] = {
    "tracker": ("tracker", "gt", {}),
    "tracker, no occlusion handling": ("tracker", "gt", {"occlusion_handling": False}),
    "tracker, no silhouette term": ("tracker", "gt", {"use_silhouette": False}),
    "tracker, no extra depth term": ("tracker", "gt", {"use_extra_depth": False}),
    "tracker, default body": ("tracker", "default", {}),
    "tracker, personalized body": ("tracker", "personalized", {}),
    "tracker, calibrated body": ("tracker", "calibrated", {}),
    "hybrid": ("hybrid", "gt", {}),
    "hybrid, default body": ("hybrid", "default", {}),
    "hybrid, personalized body": ("hybrid", "personalized", {}),
    "hybrid, calibrated body": ("hybrid", "calibrated", {}),
    "hybrid, ground-truth labels": ("hybrid", "gt", {"labels_from_recording": RECORDING}),
    "detector": ("detector", "gt", {}),
    "shotton": ("shotton", "gt", {}),
}
METRICS = (
    "mean_joint_error_mm",
    "mean_joint_error_offset_normalized_mm",
    "precision_10cm",
    "surface_error_q97_mm",
    "tracking_failure_pct",
    "detector_frames_pct",
    "system_failure_pct",
    "system_failure_visible_pct",
    "system_failure_observed_pct",
    "observed_joints_pct",
    "observed_flag_recall_pct",
    "observed_flag_precision_pct",
    "fps",
    "frame_time_p50_ms",
    "frame_time_p95_ms",
    "latency_mean_ms",
)


def _run(cmd: list[str]) -> None:
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stderr.strip()[-2000:]}")


def body_file(kind: str, rec: Path, bodies: Path, model: str) -> Path:
    """The body file of ``kind`` for recording ``rec``, made (once) when missing."""
    if kind == "gt":
        return rec / "body.json"
    out = bodies / kind / rec.name
    path = out / "body.json"
    if path.is_file():
        return path
    out.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    if kind == "personalized":
        _run([py, "-m", "depthmocap.train.synth.calibration_views", "--out", str(out / "views"),
              "--seed", "7",
              "--phenotype-from", str(rec), "--overwrite"])  # fmt: skip
        _run([py, "-m", "depthmocap.runtime.personalize_cli", "--input", str(out / "views"),
              "--output", str(path)])  # fmt: skip
    elif kind == "calibrated":
        # Beside the recordings' folder: data/dev -> data/dev_calib, data/dev_all ->
        # data/dev_all_calib (the same clip names hold other bodies there).
        calib = rec.parent.with_name(rec.parent.name + "_calib") / rec.name
        if not calib.is_dir():
            raise RuntimeError(f"{calib}: no calibration recording (run make dev-recordings)")
        # The recording is known to hold the pose: skip the automatic pose check. Labels come
        # from runtime-calibrate's default, the calibration-pose forest.
        _run([py, "-m", "depthmocap.runtime.calibrate_cli", "--input", str(calib),
              "--output", str(path),
              "--no-pose-check", "-q"])  # fmt: skip
    else:
        raise ValueError(f"unknown body kind {kind}")
    return path


def run_config(
    name: str,
    rec: Path,
    out: Path,
    model: str,
    device: str,
    mode_config: Path | None,
    tracker: dict | None = None,
    reuse: bool = False,
    realtime: bool = False,
    segmentation: Path | None = None,
) -> dict:
    """Track ``rec`` with configuration ``name`` and evaluate; returns the report.

    ``tracker``: settings merged into the hybrid's tracker settings (e.g. ``max_step_rad``).
    ``reuse``: evaluate a complete result already in ``out`` instead of tracking again (to
    resume an interrupted run of the same code and settings).
    ``realtime``: track as a live camera delivers the recording (``runtime-track
    --realtime``: paced, the newest frame wins), each skipped frame scored with the last pose.
    ``segmentation``: ``runtime-track --segmentation-config`` (e.g. the person/clutter forest).
    """
    if reuse and _complete_result(out / "result"):
        return evaluate(rec, out / "result", hold_skipped=realtime).report
    import yaml

    mode, body, overrides = CONFIGS[name]
    overrides = {k: str(rec) if v == RECORDING else v for k, v in overrides.items()}
    if mode == "hybrid" and tracker:
        base = load_settings(mode_config) if mode_config else {}
        overrides = {**overrides, "tracker": {**base.get("tracker", {}), **tracker}}
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "depthmocap.runtime.track_cli", "--input", str(rec), "-q",
           "--output", str(out / "result"), "--mode", mode, "--model", model,
           "--device", device] + (["--realtime"] if realtime else [])  # fmt: skip
    if body != "default":
        cmd += ["--body", str(body_file(body, rec, out.parent.parent / "bodies", model))]
    cfg_path = mode_config if mode == "hybrid" else None  # the hybrid's thresholds preset
    if overrides:
        base = load_settings(cfg_path) if cfg_path else {}
        cfg_path = out / "mode_config.yaml"
        cfg_path.write_text(yaml.safe_dump({**base, **overrides}))
    if cfg_path is not None:
        cmd += ["--config", str(cfg_path)]
    if segmentation is not None:
        cmd += ["--segmentation-config", str(segmentation)]
    _run(cmd)
    return evaluate(rec, out / "result", hold_skipped=realtime).report


def run_row(label: str, live: bool = False, trust_region: float | None = None) -> str:
    """A run's row name: the configuration's ``label``, ", live" with ``--realtime``, and
    " @ X rad" for one of ``--trust-regions``."""
    return label + (", live" if live else "") + (f" @ {trust_region:g} rad" if trust_region else "")


def run_folder(row: str) -> str:
    """The folder under ``--out`` that a run's results go to, from its row name."""
    return row.replace(", ", "_").replace(" @ ", "_").replace(" ", "_")


def _complete_result(result: Path) -> bool:
    """Whether ``result`` holds a finished runtime-track result: its summary.json complete and
    the run not stopped early (a run stopped by a signal closes its files cleanly, so they are
    complete, but hold only the frames before the stop: ``extra.stopped``)."""
    try:
        summary = json.loads((result / "summary.json").read_text())
        stopped = (summary.get("extra") or {}).get("stopped")
        return summary.get("complete") is True and not stopped
    except (OSError, ValueError, AttributeError):
        return False


def aggregate(reports: list[dict]) -> dict:
    """Frame-weighted means of the metrics over recordings (None where all are None)."""
    out = {}
    for key in METRICS:
        vals = [(r.get(key), r.get("frames") or 1) for r in reports]
        vals = [(v, w) for v, w in vals if v is not None]
        out[key] = (
            float(np.average([v for v, _ in vals], weights=[w for _, w in vals])) if vals else None
        )
    return out


def mean_of_runs(aggs: list[dict]) -> dict:
    """The mean of several runs' :func:`aggregate` results (None where any run has None)."""
    return {
        key: None
        if any(a.get(key) is None for a in aggs)
        else float(np.mean([a[key] for a in aggs]))
        for key in METRICS
    }


HEADLINE = "hybrid, default body"  # the fully automatic system: the broad protocol's headline


def row_label(name: str) -> str:
    """Configuration ``name`` as the broad protocol's tables show it: a row that reads the
    recording's ground truth (its true body or its part labels) is marked as a diagnostic."""
    _, body, overrides = CONFIGS[name]
    if "labels_from_recording" in overrides:
        return f"{name} (diagnostic: true body and labels)"
    if body == "gt":
        return f"{name} (diagnostic: true body)"
    return name


def group_aggregates(
    per_recording: dict[str, dict], groups: dict[str, str]
) -> dict[str, tuple[dict, int, int]]:
    """Per group of ``groups`` (recording -> group): the frame-weighted :func:`aggregate` of
    its recordings' reports, their number and their frames, groups sorted by name.
    Recordings without a group, or not run, are left out."""
    members: dict[str, list[dict]] = {}
    for rec, report in per_recording.items():
        if rec in groups:
            members.setdefault(groups[rec], []).append(report)
    return {
        g: (aggregate(reps), len(reps), sum(int(r.get("frames") or 0) for r in reps))
        for g, reps in sorted(members.items())
    }


def format_group_table(
    grouping: str, row: str, mode: str, per_recording: dict[str, dict], groups: dict[str, str]
) -> str:
    """The table of table row ``row`` (a configuration of ``mode``) per group of
    ``grouping``: one row per group."""
    head = HEADER.replace("| configuration |", f"| {grouping} (recordings, frames) |", 1)
    lines = [f"{row}, per {grouping}:", "", head]
    for group, (agg, n, frames) in group_aggregates(per_recording, groups).items():
        lines.append(format_row(f"{group} ({n}, {frames})", agg, mode))
    return "\n".join(lines)


def format_row(name: str, agg: dict, mode: str | None = None) -> str:
    """One table row; ``mode`` defaults to configuration ``name``'s."""

    def f(key, digits=1, scale=1.0):
        v = agg.get(key)
        return "n/a" if v is None else f"{v * scale:.{digits}f}"

    # A mode without a tracker has no tracking failures to count: the detector runs always.
    tracking = (
        "(every frame)"
        if (mode or CONFIGS[name][0]) in ("detector", "shotton")
        else (f"{f('tracking_failure_pct')}%")
    )
    return (
        f"| {name} | {f('mean_joint_error_mm')} | {f('mean_joint_error_offset_normalized_mm')} | "
        f"{f('precision_10cm', 1, 100)}% | {f('surface_error_q97_mm')} | "
        f"{tracking} | {f('detector_frames_pct')}% | "
        f"{f('system_failure_pct')}% | {f('fps')} |"
    )


def format_speed(name: str, per_recording: dict[str, dict]) -> str:
    """One line of speed figures of configuration ``name`` over its recordings (issue 38's
    measure): the median over recordings of the median frame rate (1000 / the median frame
    time), the worst recording's 95th-percentile frame time and the frame-weighted mean
    latency from a frame's arrival to its pose written."""
    reports = list(per_recording.values())
    p50 = [r["frame_time_p50_ms"] for r in reports if r.get("frame_time_p50_ms")]
    p95 = [r["frame_time_p95_ms"] for r in reports if r.get("frame_time_p95_ms") is not None]
    lat = [(r["latency_mean_ms"], r.get("frames") or 1) for r in reports
           if r.get("latency_mean_ms") is not None]  # fmt: skip
    if not p50 or not p95 or not lat:
        return f"{name}: speed not recorded (results without frame times)"
    latency = np.average([v for v, _ in lat], weights=[w for _, w in lat])
    return (
        f"{name}: median frame rate {np.median(1000.0 / np.asarray(p50)):.1f} frames/s "
        f"(median over {len(p50)} recordings), 95th-percentile frame time "
        f"{max(p95):.1f} ms (worst recording; median {np.median(p95):.1f}), "
        f"mean latency {latency:.1f} ms"
    )


def format_failures(name: str, per_recording: dict[str, dict], agg: dict | None = None) -> str:
    """The system-failure frames of one configuration, one line per recording that has any:
    frame index and worst joint in cm ("no pose" for frames without one, "(hidden)" for a
    joint the camera did not see); then, given the configuration's ``agg``, the rate counting
    only the joints the camera sees."""
    lines = [f"{name}: system-failure frames (any joint beyond the threshold)"]
    for rec, report in per_recording.items():
        frames = report.get("system_failure_frames") or []
        if frames:
            lines.append(f"  {rec}: {format_failed_frames(frames)}")
    if len(lines) == 1:
        lines.append("  none")
    seen = (agg or {}).get("system_failure_visible_pct")
    if seen is not None:
        lines.append(f"  counting only the joints the camera sees: {seen:.1f}%")
    claimed = (agg or {}).get("system_failure_observed_pct")
    if claimed is not None:
        flags = [agg.get(f"observed_flag_{k}_pct") for k in ("recall", "precision")]
        agreement = (
            f" (the flags cover {flags[0]:.1f}% of the joints the camera sees; "
            f"{flags[1]:.1f}% of the joints flagged are seen)"
            if None not in flags
            else ""
        )
        lines.append(
            f"  counting only the joints the result reports as observed: {claimed:.1f}%{agreement}"
        )
    return "\n".join(lines)


def body_length_reports(
    bodies: Path, recs: list[Path], kinds: set[str]
) -> dict[str, tuple[dict | None, str]]:
    """For each estimated body kind among ``kinds`` (calibrated, personalized) with body files
    under ``bodies``: its bone-length errors against the recordings' own bodies and a line
    to print. An unreadable file gives (None, a line naming it) instead of an error: the
    runs' results are worth more than this comparison."""
    out = {}
    for kind in sorted(kinds & {"calibrated", "personalized"}):
        made = [r for r in recs if (bodies / kind / r.name / "body.json").is_file()]
        if not made:
            continue
        try:
            errors = bone_length_errors(
                [bodies / kind / r.name / "body.json" for r in made],
                [r / "body.json" for r in made],
            )
        except (OSError, ValueError) as err:
            out[kind] = (None, f"{kind} bodies: bone lengths not compared ({err})")
            continue
        out[kind] = (errors, format_bone_length_errors(kind, errors))
    return out


HEADER = (
    "| configuration | joint error mm | offset-normalized mm | precision 10 cm | "
    "surface q97 mm | tracking failure | detector frames | system failure | frames/s |\n"
    "|---|---|---|---|---|---|---|---|---|"
)


def _protocol_recordings(
    folder: Path, limit: int | None
) -> tuple[list[Path], dict[str, dict[str, str]], str | None]:
    """The broad protocol's recordings in ``folder`` (its manifest's, in order), their
    groupings, and a problem that stops the run (None if none): no or a bad manifest, or
    recordings missing (allowed with ``limit``, which takes the first ``limit`` present)."""
    try:
        manifest = load_manifest(folder)
    except (FileNotFoundError, ValueError) as err:
        return [], {}, str(err)
    names = [r["name"] for r in manifest["recordings"]]
    present = [folder / n for n in names if (folder / n / "groundtruth.npz").is_file()]
    if limit:
        present = present[:limit]
    elif len(present) < len(names):
        missing = len(names) - len(present)
        return (
            [],
            {},
            (
                f"{folder}: {missing} of the manifest's {len(names)} recordings are missing (run "
                "make dev-protocol to finish them, or --limit for a partial run)"
            ),
        )
    return present, manifest_groups(manifest), None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="train-dev-benchmark", description=__doc__.splitlines()[0])
    p.add_argument(
        "--recordings",
        default=None,
        help="folder of dev recordings (default: data/dev; data/dev_broad with --protocol broad)",
    )
    p.add_argument("--out", default=None, help="results and the JSON report (default: "
                   "out/dev_benchmark; out/dev_broad with --protocol broad)")  # fmt: skip
    p.add_argument(
        "--configs",
        nargs="+",
        default=None,
        choices=list(CONFIGS),
        help=f"configurations to run (default: all; with --protocol broad: {HEADLINE!r})",
    )
    p.add_argument(
        "--protocol",
        choices=["dev", "broad"],
        default="dev",
        help="broad: every recording of the broad protocol's manifest, tables per motion "
        "class, camera, cut and body too (docs/protocol.md)",
    )
    p.add_argument("--model", default="models/forest.npz", help="forest for hybrid/detector")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    p.add_argument(
        "--mode-config",
        type=Path,
        default=Path("configs/hybrid.yaml"),
        help="YAML of the hybrid's settings (thresholds)",
    )
    p.add_argument(
        "--segmentation-config",
        type=Path,
        help="runtime-track --segmentation-config (e.g. the person/clutter forest)",
    )
    p.add_argument("--limit", type=int, help="use only the first N recordings")
    p.add_argument(
        "--trust-regions",
        nargs="+",
        type=float,
        metavar="RAD",
        help="run each hybrid configuration once per tracker trust region (max_step_rad, "
        "radians) and add the runs' mean (the README's three-run figures: 0.18 0.2 0.22)",
    )
    p.add_argument(
        "--reuse-results",
        action="store_true",
        help="evaluate the complete results already under --out instead of tracking those "
        "recordings again: resumes an interrupted run (same code and settings only)",
    )
    p.add_argument(
        "--realtime",
        action="store_true",
        help="track each recording as a live camera delivers it (runtime-track --realtime: "
        "paced at its frame rate, the newest frame wins, so slow frames make it skip some); "
        "a skipped frame is scored with the last pose written, as motion.bvh repeats it. Run "
        "one benchmark at a time: a second process on the same cores makes it skip more",
    )
    args = p.parse_args(argv)
    if args.trust_regions and not all(v > 0 and math.isfinite(v) for v in args.trust_regions):
        p.error(f"--trust-regions must be positive radians, got {args.trust_regions}")
    if args.mode_config is not None and not args.mode_config.is_file():
        p.error(f"--mode-config: no such file {args.mode_config}")
    broad = args.protocol == "broad"
    args.recordings = args.recordings or ("data/dev_broad" if broad else "data/dev")
    args.out = args.out or ("out/dev_broad" if broad else "out/dev_benchmark")
    configs = args.configs or ([HEADLINE] if broad else list(CONFIGS))
    if broad:  # the headline row first
        configs = sorted(configs, key=lambda n: n != HEADLINE)
    groupings: dict[str, dict[str, str]] = {}
    if broad:
        recs, groupings, problem = _protocol_recordings(Path(args.recordings), args.limit)
        if problem:
            print(f"error: {problem}", file=sys.stderr)
            return 2
    else:
        recs = sorted(
            d for d in Path(args.recordings).glob("*") if (d / "groundtruth.npz").is_file()
        )
        if args.limit:
            recs = recs[: args.limit]
    if not recs:
        print(f"no dev recordings in {args.recordings}: run `make dev-recordings`", file=sys.stderr)
        return 2
    label = row_label if broad else str
    frames = sum(len(Recording(r)) for r in recs) if broad else None
    extent = f" ({frames} frames, broad protocol version {PROTOCOL_VERSION})" if broad else ""
    print(f"{len(recs)} dev recordings from {args.recordings}{extent}\n")
    print(HEADER)
    results = {}
    for name in configs:
        runs = [(run_row(label(name), args.realtime), None)]
        if CONFIGS[name][0] == "hybrid" and args.trust_regions:
            runs = [
                (run_row(label(name), args.realtime, v), {"max_step_rad": v})
                for v in args.trust_regions
            ]
        for row, tracker in runs:
            t0 = time.perf_counter()
            reports = []
            slug = run_folder(row)
            try:
                for rec in recs:
                    reports.append(
                        run_config(name, rec, Path(args.out) / slug / rec.name, args.model,
                                   args.device, args.mode_config, tracker, args.reuse_results,
                                   args.realtime, args.segmentation_config)
                    )  # fmt: skip
            except RuntimeError as err:
                print(f"| {row} | failed: {str(err).splitlines()[-1][:80]} |||||||")
                continue
            agg = aggregate(reports)
            per_rec = dict(zip([r.name for r in recs], reports))
            results[row] = {"mean": agg, "per_recording": per_rec, "config": name}
            print(format_row(row, agg, CONFIGS[name][0]), flush=True)
            results[row]["seconds"] = time.perf_counter() - t0
            if args.realtime:
                held = sum(r.get("frames_held", 0) for r in reports)
                total = sum(r.get("frames") or 0 for r in reports)
                results[row]["frames_held"] = held
                share = 100 * held / max(total, 1)
                print(f"|   live: {held} of {total} frames skipped ({share:.1f}%), each "
                      "scored with the last pose |")  # fmt: skip
        done = [results[row]["mean"] for row, _ in runs if row in results]
        if len(runs) > 1 and len(done) == len(runs):
            row = f"{label(name)}, mean of {len(done)}"
            results[row] = {"mean": mean_of_runs(done)}
            print(format_row(row, results[row]["mean"], CONFIGS[name][0]), flush=True)
    for row, res in results.items():
        for grouping, groups in groupings.items() if "per_recording" in res else ():
            mode = CONFIGS[res["config"]][0]
            print("\n" + format_group_table(grouping, row, mode, res["per_recording"], groups))
            per_group = group_aggregates(res["per_recording"], groups)
            res.setdefault("per_group", {})[grouping] = {
                g: {"mean": a, "recordings": n, "frames": f} for g, (a, n, f) in per_group.items()
            }
    for row, res in results.items():
        if "per_recording" in res:
            print("\n" + format_failures(row, res["per_recording"], res["mean"]))
    print("\nspeed (runtime-track end to end, per-frame times from summary.json):")
    for row, res in results.items():
        if "per_recording" in res:
            print("  " + format_speed(row, res["per_recording"]))
    kinds = {CONFIGS[n][1] for n in configs}
    for kind, (errors, text) in body_length_reports(Path(args.out) / "bodies", recs, kinds).items():
        results[f"{kind} bodies"] = {"bone_length_errors": errors}
        print("\n" + text)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "report.json").write_text(json.dumps(results, indent=1))
    print(f"\nfull report: {Path(args.out) / 'report.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
