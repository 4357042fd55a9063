"""Moving finished runs to other joint offsets (train.evaluation.reapply_offsets)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from depthmocap.runtime.estimator_setup import POPULATION_BODY
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.joint_offsets import NUM_POSE_FEATURES, JointOffsets, save_joint_offsets
from depthmocap.shared.poses_format import pose_record
from depthmocap.train.evaluation.reapply_offsets import fitted_scales, joints_with_offsets, main

J = len(sk.JOINT_NAMES)


def _run(tmp_path, old, interim=(1.0, 1.0)):
    """A run of 5 frames: the population body for frame 0, ``interim`` sizes of it for frames
    1 and 2 (the size search's interim sizes), the scaled body after (its body.json), frame
    3 lost; joints written under ``old``."""
    rng = np.random.default_rng(0)
    population = BodyShape.load(POPULATION_BODY)
    scaled = population.scaled(1.08)
    q = np.zeros((5, sk.NUM_DOFS))
    q[:, 2], q[:, 3] = 3.0, np.pi
    q[:, 6:] = rng.normal(0, 0.2, (5, sk.NUM_DOFS - 6))
    run = tmp_path / "runs" / "take" / "result"
    run.mkdir(parents=True)
    scaled.save(run / "body.json")
    (run / "summary.json").write_text("{}")
    lines = []
    for i in range(5):
        body = population if i == 0 else population.scaled(interim[i - 1]) if i < 3 else scaled
        if i == 3:
            lines.append(pose_record(i, i / 30, "lost", None, None))
            continue
        joints = joints_with_offsets(q[i : i + 1], body, old)[0]
        lines.append(pose_record(i, i / 30, "tracked", joints, q[i], {"overlap": 0.8}))
    (run / "poses.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    return run, q, population, scaled


@pytest.mark.parametrize("interim", [(1.0, 1.0), (1.0003, 1.0517)])
def test_runs_move_to_new_offsets_on_the_body_of_each_frame(tmp_path, capsys, interim):
    """Each frame moves on the body it was tracked with: the population body, the result's
    body.json, or an interim size between them (1.0003: within a millimetre of the
    population body's joints, which must not be taken for it)."""
    rng = np.random.default_rng(1)
    old = JointOffsets(rng.normal(0, 0.02, (J, 3)), 1.78)
    new = JointOffsets(
        rng.normal(0, 0.02, (J, 3)), 1.78,
        pose_coefficients_m=rng.normal(0, 0.005, (J, NUM_POSE_FEATURES, 3)),
    )  # fmt: skip
    save_joint_offsets(tmp_path / "old.json", old)
    save_joint_offsets(tmp_path / "new.json", new)
    run, q, population, scaled = _run(tmp_path, old, interim)
    args = ["--results", str(tmp_path / "runs"), "--old-offsets", str(tmp_path / "old.json")]
    assert main([*args, "--offsets", str(tmp_path / "new.json"), "--out", str(tmp_path / "o")]) == 0
    assert "4 posed frames" in capsys.readouterr().out
    out = tmp_path / "o" / "take" / "result"
    lines = [json.loads(x) for x in (out / "poses.jsonl").read_text().splitlines()]
    assert lines[3]["joints"] is None and lines[0]["errors"] == {"overlap": 0.8}
    first, second = (population.scaled(f) for f in interim)
    for i, body in ((0, population), (1, first), (2, second), (4, scaled)):
        want = joints_with_offsets(q[i : i + 1], body, new)[0]
        got = np.array([lines[i]["joints"][n] for n in sk.JOINT_NAMES])
        np.testing.assert_allclose(got, want, atol=2e-6)
    assert (out / "summary.json").is_file() and (out / "body.json").is_file()


def test_a_run_made_with_other_offsets_is_refused(tmp_path, capsys):
    old = JointOffsets(np.full((J, 3), 0.01), 1.78)
    save_joint_offsets(tmp_path / "old.json", old)
    _run(tmp_path, JointOffsets(np.full((J, 3), 0.03), 1.78))  # not the old file's
    args = ["--results", str(tmp_path / "runs"), "--old-offsets", str(tmp_path / "old.json")]
    assert main([*args, "--offsets", "none", "--out", str(tmp_path / "o")]) == 2
    assert "from every candidate body" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--results", str(tmp_path / "no"), "--old-offsets", "none", "--offsets", "none",
              "--out", str(tmp_path / "o")])  # fmt: skip


def test_a_smoothed_run_is_refused(tmp_path, capsys):
    old = JointOffsets(np.full((J, 3), 0.01), 1.78)
    save_joint_offsets(tmp_path / "old.json", old)
    run, *_ = _run(tmp_path, old)
    (run / "summary.json").write_text(json.dumps({"extra": {"fixed_lag_frames": 2}}))
    args = ["--results", str(tmp_path / "runs"), "--old-offsets", str(tmp_path / "old.json")]
    assert main([*args, "--offsets", "none", "--out", str(tmp_path / "o")]) == 2
    assert "--fixed-lag 0" in capsys.readouterr().err
    (run / "summary.json").write_text(json.dumps({"extra": {"fixed_lag_frames": 0}}))
    assert main([*args, "--offsets", "none", "--out", str(tmp_path / "o")]) == 0


def test_no_offsets_gives_the_model_joints():
    body = BodyShape.default(torch.float64)
    q = np.zeros((1, sk.NUM_DOFS))
    q[0, 2] = 2.0
    plain = joints_with_offsets(q, body, None)
    moved = joints_with_offsets(q, body, JointOffsets(np.zeros((J, 3)), 1.7))
    np.testing.assert_allclose(plain, moved, atol=1e-12)


def test_the_population_body_is_the_runtimes():
    from depthmocap.shared.resources import CONFIGS_DIR

    assert POPULATION_BODY == CONFIGS_DIR / "body_template.json"  # reapply_offsets reads it there


def test_bad_input_is_a_clear_error_and_a_torn_last_line_is_dropped(tmp_path, capsys):
    old = JointOffsets(np.full((J, 3), 0.01), 1.78)
    save_joint_offsets(tmp_path / "old.json", old)
    run, *_ = _run(tmp_path, old)
    args = ["--results", str(tmp_path / "runs"), "--old-offsets", str(tmp_path / "old.json")]
    (tmp_path / "bad.json").write_text("{not json")
    assert main([*args, "--offsets", str(tmp_path / "bad.json"), "--out", str(tmp_path / "o")]) == 2
    assert "not a readable joint-offsets file" in capsys.readouterr().err
    lines = (run / "poses.jsonl").read_text()
    (run / "poses.jsonl").write_text(lines + '{"frame": 5, "stat')  # an interrupted run
    assert main([*args, "--offsets", "none", "--out", str(tmp_path / "o")]) == 0
    moved = (tmp_path / "o" / "take" / "result" / "poses.jsonl").read_text().splitlines()
    assert len(moved) == 5
    (run / "poses.jsonl").write_text("garbage\n" + lines)
    assert main([*args, "--offsets", "none", "--out", str(tmp_path / "o")]) == 2
    assert "line 1 is not JSON" in capsys.readouterr().err
    (run / "poses.jsonl").write_text(lines)
    (run / "body.json").write_text("{}")
    assert main([*args, "--offsets", "none", "--out", str(tmp_path / "o")]) == 2
    assert "take" in capsys.readouterr().err


def test_the_fitted_scale_is_the_one_the_joints_were_made_at():
    rng = np.random.default_rng(2)
    body = BodyShape.load(POPULATION_BODY)
    offsets = JointOffsets(
        rng.normal(0, 0.02, (J, 3)), 1.78,
        pose_coefficients_m=rng.normal(0, 0.005, (J, NUM_POSE_FEATURES, 3)),
    )  # fmt: skip
    q = np.zeros((3, sk.NUM_DOFS))
    q[:, 2] = 2.5
    q[:, 6:] = rng.normal(0, 0.3, (3, sk.NUM_DOFS - 6))
    truth = np.array([0.86, 1.0, 1.137])
    joints = np.concatenate(
        [joints_with_offsets(q[i : i + 1], body.scaled(s), offsets) for i, s in enumerate(truth)]
    )
    np.testing.assert_allclose(fitted_scales(q, joints, body, offsets), truth, atol=1e-9)
