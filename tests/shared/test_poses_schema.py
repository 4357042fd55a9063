"""The shipped JSON Schemas of ``poses.jsonl`` lines and ``summary.json`` (docs/format.md)
hold for real ``runtime-track`` outputs in every mode, including lost frames, and reject
broken lines. The runs also check that every ``errors`` key the code writes is in the
schema and the docs, and that each documented key is actually written by some run."""

from __future__ import annotations

import copy
import json
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

jsonschema = pytest.importorskip("jsonschema")

import depthmocap.runtime.track_cli as cli  # noqa: E402
from depthmocap.runtime.raycast import part_labels, render_body  # noqa: E402
from depthmocap.shared import skeleton as sk  # noqa: E402
from depthmocap.shared.body import BodyShape  # noqa: E402
from depthmocap.shared.camera import Intrinsics  # noqa: E402
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions, rest_pose  # noqa: E402
from depthmocap.shared.poses_format import pose_record  # noqa: E402
from depthmocap.shared.recording import RecordingWriter  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
MODEL = REPO / "models" / "forest.npz"
INTR = Intrinsics.kinect_v1(160)
FRAMES = 8
EMPTY = 7  # no depth at all: lost in every mode
NO_LABELS = 6  # the recording's labels are all zero: lost for a hybrid reading them


def _schema(name: str) -> dict:
    return json.loads((resources.files("shared") / name).read_text(encoding="utf-8"))


POSES_SCHEMA = _schema("poses.schema.json")
SUMMARY_SCHEMA = _schema("summary.schema.json")
POSES = jsonschema.Draft202012Validator(POSES_SCHEMA)
SUMMARY = jsonschema.Draft202012Validator(SUMMARY_SCHEMA)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A rendered person whose arms jump between frames (so the hybrid's tests fail now and
    then), with labels and ground truth; frame EMPTY has no depth, frame NO_LABELS no labels."""
    body = BodyShape.default()
    q = rest_pose(FRAMES, dtype=torch.float32)
    q[:, sk.DOF_NAMES.index("l_humerus_flex")] = torch.tensor([0, 0, 1.5, 1.5, 0.2, 1.6, 0, 1.4])
    q[:, sk.DOF_NAMES.index("r_humerus_abd")] = torch.tensor([0, 0, 0, 1.4, 1.4, 0, 1.5, 0])
    render = render_body(q, body, INTR)
    labels = part_labels(render, body)
    path = tmp_path_factory.mktemp("schema") / "rec"
    with RecordingWriter(path, INTR, fps=30.0, source="test") as w:
        for i in range(FRAMES):
            depth = (render.depth[i].numpy() * 1000).round().astype(np.uint16)
            lab = labels[i].numpy().astype(np.uint8)
            if i == EMPTY:
                depth = np.zeros_like(depth)
            if i in (EMPTY, NO_LABELS):
                lab = np.zeros_like(lab)
            w.write_frame(depth, lab)
        qd = q.double()
        joints = named_joint_positions(forward_kinematics(qd, body.to(torch.float64))).numpy()
        w.write_groundtruth(joints, list(sk.JOINT_NAMES), q=qd.numpy())
    return path


# name -> (mode, hybrid settings or None). The hybrid variants make it write every key:
# failed tracks (tracker_*), keep_better, rechecks, arm searches, a detection finding nobody
# (without keep_better, which would keep the failed track instead).
RUNS = {
    "tracker": ("tracker", None),
    "detector": ("detector", None),
    "shotton": ("shotton", None),
    "hybrid": ("hybrid", None),
    "hybrid-shipped-preset": ("hybrid", "configs/hybrid.yaml"),
    "hybrid-keep-better": (
        "hybrid",
        {"failure": {"epsilon1_cm": 0.001}, "keep_better": {"compare_all_tests": False}},
    ),
    "hybrid-recheck": ("hybrid", {"keep_better": {"recheck_badness": 0.001}}),
    "hybrid-confirm": (
        "hybrid",
        {"keep_better": {"recheck_badness": 0.001, "confirm_within_m": 1.0}},
    ),
    "hybrid-unsupported": ("hybrid", {"failure": {"lost_overlap": 0.9}}),
    "hybrid-recording-labels": (
        "hybrid",
        {"labels_from_recording": "REC", "arm_search": {"badness": 0.001}, "keep_better": None},
    ),
}
# Runs given the rendered (built-in) body by file: the population body tracked without one is
# another body, whose fits of this person never reach the unsupported run's overlap bound.
WITH_RENDERED_BODY = {"hybrid-unsupported"}


@pytest.fixture(scope="module")
def outputs(recording, tmp_path_factory) -> dict[str, tuple[list[dict], dict]]:
    """Each run's poses.jsonl records and summary.json."""
    if not MODEL.exists():
        pytest.skip("models/forest.npz is not in this checkout")
    root = tmp_path_factory.mktemp("runs")
    results = {}
    for name, (mode, settings) in RUNS.items():
        argv = ["-i", recording, "-o", root / name, "--mode", mode, "--model", MODEL]
        if isinstance(settings, str):
            argv += ["--config", REPO / settings]
        elif settings is not None:
            text = yaml.safe_dump(settings).replace("REC", str(recording))
            (root / f"{name}.yaml").write_text(text)
            argv += ["--config", root / f"{name}.yaml"]
        if name in WITH_RENDERED_BODY:
            BodyShape.default().save(root / "body.json")
            argv += ["--body", root / "body.json"]
        code = cli.main([str(a) for a in [*argv, "--device", "cpu", "--quiet"]])
        assert code == 0, name
        lines = (root / name / "poses.jsonl").read_text().splitlines()
        summary = json.loads((root / name / "summary.json").read_text())
        results[name] = ([json.loads(line) for line in lines], summary)
    return results


def _errors(validator, instance) -> list[str]:
    return [e.message for e in validator.iter_errors(instance)]


def test_the_schemas_are_valid_and_shipped_with_shared():
    jsonschema.Draft202012Validator.check_schema(POSES_SCHEMA)
    jsonschema.Draft202012Validator.check_schema(SUMMARY_SCHEMA)
    # Package data of depthmocap.shared (the wheel's contents are checked by tests/test_install.py).
    assert '"*.schema.json"' in (REPO / "setup.py").read_text()


@pytest.mark.slow
@pytest.mark.parametrize("name", list(RUNS))
def test_every_line_and_the_summary_of_a_real_run_validate(outputs, name):
    records, summary = outputs[name]
    assert len(records) == FRAMES
    for rec in records:
        assert _errors(POSES, rec) == [], (name, rec["frame"])
    assert _errors(SUMMARY, summary) == [], name
    assert summary["complete"] and summary["frames"] == FRAMES
    lost = records[EMPTY]
    assert lost["status"] == "lost" and lost["errors"] == {}
    assert lost["joints"] is None and lost["q"] is None and lost["observed"] is None
    assert {r["status"] for r in records} > {"lost"}


@pytest.mark.slow
def test_the_runs_cover_every_status_and_every_documented_errors_key(outputs):
    documented = set(POSES_SCHEMA["properties"]["errors"]["properties"])
    seen: dict[str, set[str]] = {}
    for name, (records, _) in outputs.items():
        for rec in records:
            for key in rec["errors"]:
                seen.setdefault(key, set()).add(name)
    assert set(seen) <= documented, f"undocumented errors keys: {set(seen) - documented}"
    assert documented <= set(seen), f"documented keys no run wrote: {documented - set(seen)}"
    statuses = {r["status"] for records, _ in outputs.values() for r in records}
    assert statuses == {"tracked", "detected", "lost"}
    # A detection that finds nobody after a failed track: lost, with the figures behind it.
    lost = outputs["hybrid-recording-labels"][0][NO_LABELS]
    assert lost["status"] == "lost" and lost["errors"]["labelled_pixels"] == 0
    # Mode shotton has joints but no pose.
    shotton = outputs["shotton"][0][0]
    assert shotton["status"] == "detected" and shotton["q"] is None and shotton["joints"]


def test_the_docs_describe_every_errors_key():
    doc = (REPO / "docs" / "format.md").read_text()
    for key in POSES_SCHEMA["properties"]["errors"]["properties"]:
        assert f"`{key}`" in doc, key


def _good_line() -> dict:
    joints = np.tile([0.0, 0.0, 2.5], (16, 1))
    joints[3] = np.nan  # a joint without a position is null
    q = np.zeros(34)
    q[7] = np.inf  # so is a single non-finite angle
    return pose_record(
        5, 0.2, "tracked", joints, q, {"depth_error_cm": 1.2, "overlap": float("nan")},
        observed=np.ones(16, dtype=bool),
    )  # fmt: skip


def _broken(change) -> dict:
    line = copy.deepcopy(_good_line())
    change(line)
    return line


def test_a_line_with_nulls_validates():
    line = _good_line()
    assert line["joints"]["pelvis"] is None and line["q"][7] is None
    assert line["errors"]["overlap"] is None
    assert _errors(POSES, line) == []
    old = _broken(lambda r: r.pop("observed"))  # files written before the observed flags
    assert _errors(POSES, old) == []


BROKEN = {
    "missing frame": lambda r: r.pop("frame"),
    "missing status": lambda r: r.pop("status"),
    "missing errors": lambda r: r.pop("errors"),
    "frame as a string": lambda r: r.update(frame="5"),
    "negative frame": lambda r: r.update(frame=-1),
    "unknown status": lambda r: r.update(status="found"),
    "a joint with two coordinates": lambda r: r["joints"].update(head=[0.0, 1.0]),
    "a coordinate as a string": lambda r: r["joints"].update(head=["0", 0.0, 2.5]),
    "a joint missing": lambda r: r["joints"].pop("r_ankle"),
    "an unknown joint": lambda r: r["joints"].update(nose=[0.0, 0.0, 2.5]),
    "q too short": lambda r: r.update(q=r["q"][:33]),
    "an errors value as a string": lambda r: r["errors"].update(depth_error_cm="1.2"),
    "errors as a list": lambda r: r.update(errors=[1.2]),
    "observed not a bool": lambda r: r["observed"].update(head=1),
    "an unknown top-level key": lambda r: r.update(depth_mm=11.2),
    "a lost line with a pose": lambda r: r.update(status="lost"),
    "a tracked line without joints": lambda r: r.update(joints=None),
    "a tracked line without q": lambda r: r.update(q=None),
}


@pytest.mark.parametrize("what", list(BROKEN))
def test_broken_lines_fail_validation(what):
    assert _errors(POSES, _broken(BROKEN[what])), what


def test_a_broken_summary_fails_validation(tmp_path):
    good = {
        "format": "depthmocap-result", "version": 1, "complete": True, "frames": 1,
        "first_frame": 0, "last_frame": 0, "fps": None, "stream_fps": 30.0,
        "status_counts": {"tracked": 1, "detected": 0, "lost": 0}, "mode": "hybrid",
        "source": "demo",
        "intrinsics": {"width": 160, "height": 120, "fx": 144.0, "fy": 144.0, "cx": 79.5,
                       "cy": 59.5},
        "timing": {"started": "2025-01-01T00:00:00+00:00", "finished": None, "wall_s": 0.1,
                   "mean_frame_interval_ms": None},
        "files": {"poses": "poses.jsonl", "bvh": "motion.bvh", "summary": "summary.json",
                  "body": "body.json"},
        "bvh": {"frames": 1, "units": "cm", "world_frame": "y up"},
        "extra": {},
    }  # fmt: skip
    assert _errors(SUMMARY, good) == []
    for change in (
        lambda s: s.pop("frames"),
        lambda s: s.update(complete="yes"),
        lambda s: s["status_counts"].pop("lost"),
        lambda s: s["bvh"].update(units="inch"),
    ):
        bad = copy.deepcopy(good)
        change(bad)
        assert _errors(SUMMARY, bad)
