"""Skeleton calibration (Wei section 6) from ray-cast reference poses with exact labels."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depthmocap.runtime import calibrate_cli
from depthmocap.runtime.calibrate_cli import main
from depthmocap.runtime.calibration import (
    CalibrationConfig,
    ReferencePoseWatcher,
    calibrate_body,
    fit_cylinder,
    is_reference_pose,
    reference_pose,
)
from depthmocap.runtime.raycast import part_labels, render_body
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import rest_pose
from depthmocap.shared.labels import PART_NAMES
from depthmocap.shared.recording import RecordingWriter

INTR = Intrinsics.kinect_v1(320)
TEMPLATE = BodyShape.default()
FAST = CalibrationConfig(samples=384, length_scale="per_bone")


def render_labels(q: torch.Tensor, body: BodyShape):
    r = render_body(q[None], body, INTR)
    return r.depth[0], part_labels(r, body)[0]


def subject() -> BodyShape:
    """A body unlike the template: taller legs, shorter forearms, broader, wider hips."""
    f = torch.tensor([1.08, 1.0, 1.1, 1.0, 0.95, 1.1, 1.1, 1.06, 1.06, 0.92, 0.92, 1.1, 1.1, 1.04,
                      1.04])  # fmt: skip
    t = TEMPLATE
    return BodyShape(t.lengths * f, t.radii * 1.1, t.extents * 1.05, t.hip_half_width * 1.1)


def test_calibrated_lengths_within_2cm():
    body = subject()
    q = reference_pose(root_position=(0.05, 0.1, 2.7))
    q[sk.DOF_NAMES.index("l_humerus_abd")] += math.radians(6)  # not held perfectly
    depth, labels = render_labels(q, body)
    cal = calibrate_body([depth], [labels], INTR, TEMPLATE, FAST)
    err = (cal.lengths - body.lengths).abs()
    assert float(err.max()) < 0.02, err
    assert float((cal.radii - body.radii).abs().max()) < 0.02
    assert abs(float(cal.hip_half_width - body.hip_half_width)) < 0.02
    # Symmetric: left and right bones are the same.
    assert torch.allclose(cal.lengths[7], cal.lengths[8]) and torch.allclose(
        cal.lengths[13], cal.lengths[14]
    )
    cal.validate()


def test_consensus_scale_gives_every_length_one_factor():
    body = subject()
    depth, labels = render_labels(reference_pose(root_position=(0.05, 0.1, 2.7)), body)
    cfg = CalibrationConfig(samples=384)
    assert cfg.length_scale == "consensus"
    cal = calibrate_body([depth], [labels], INTR, TEMPLATE, cfg)
    ratio = cal.lengths / TEMPLATE.lengths
    assert torch.allclose(ratio, ratio[0].expand_as(ratio), rtol=1e-5)
    # The median of the subject's per-bone factors (1.0 to 1.1): the body's overall size.
    assert 1.0 < float(ratio[0]) < 1.1
    per_bone = calibrate_body([depth], [labels], INTR, TEMPLATE, FAST)
    assert torch.allclose(cal.radii, per_bone.radii)  # radii stay per bone either way
    # The clavicles rest as the template's (a T-pose cannot show it).
    template = BodyShape(**{**TEMPLATE.__dict__, "clavicle_rest": torch.tensor([-0.4, 0.1])})
    rested = calibrate_body([depth], [labels], INTR, template, cfg)
    assert torch.allclose(rested.clavicle_rest, template.clavicle_rest)
    with pytest.raises(ValueError, match="length_scale"):
        CalibrationConfig(length_scale="global")


def test_fit_cylinder_of_a_forearm():
    body = TEMPLATE
    depth, labels = render_labels(reference_pose(root_position=(0.0, 0.0, 2.5)), body)
    forearm = labels == PART_NAMES.index("l_forearm")
    g = torch.Generator().manual_seed(0)
    fit = fit_cylinder(depth.double(), forearm, INTR, (0.02, 0.08), 384, generator=g)
    assert fit.found
    assert fit.radius == pytest.approx(0.04, abs=0.01)
    # Visible: forearm plus hand (0.26 + 0.10 m) minus the overlap at the elbow.
    assert 0.28 < fit.length < 0.40
    none = fit_cylinder(depth.double(), torch.zeros_like(forearm), INTR, (0.02, 0.08))
    assert not none.found


def test_reference_pose_detection():
    cfg = CalibrationConfig(hold_frames=3)
    assert is_reference_pose(reference_pose(cfg), cfg)
    assert not is_reference_pose(rest_pose()[0], cfg)
    turned = reference_pose(cfg)
    turned[3:6] = torch.tensor([0.0, 0.0, math.pi])  # back to the camera
    assert not is_reference_pose(turned, cfg)
    watcher = ReferencePoseWatcher(cfg)
    d = torch.zeros(2, 2)
    ref = reference_pose(cfg)
    assert [watcher.update(ref, d, d) for _ in range(2)] == [False, False]
    for _ in range(cfg.hold_misses + 1):  # out of the pose for longer than a glitch
        watcher.update(None, d, d)
    assert [watcher.update(ref, d, d) for _ in range(3)] == [False, False, True]
    assert len(watcher.frames) == 3
    # A miss or two (a detector glitch) neither counts nor breaks the hold.
    glitch = ReferencePoseWatcher(cfg)
    got = [glitch.update(q, d, d) for q in (ref, None, None, ref, ref)]
    assert got == [False, False, False, False, True] and len(glitch.frames) == 3


def _write_recording(path, poses, body):
    with RecordingWriter(path, INTR) as w:
        for q in poses:
            depth, labels = render_labels(q, body)
            w.write_frame(
                (depth.numpy() * 1000).round().astype(np.uint16), labels.numpy().astype(np.uint8)
            )


@pytest.mark.slow
def test_cli_calibrates_from_a_recording(tmp_path, monkeypatch):
    body = subject()
    ref = reference_pose(root_position=(0.0, 0.1, 2.6))
    _write_recording(tmp_path / "rec", [rest_pose(1, (0.0, 0.1, 2.6))[0], ref, ref], body)
    out = tmp_path / "body.json"
    TEMPLATE.save(tmp_path / "template.json")  # the subject is a scaled built-in adult
    args = ["--input", str(tmp_path / "rec"), "--output", str(out), "--labels", "recording",
            "--template", str(tmp_path / "template.json")]  # fmt: skip
    assert main([*args, "--frames", "2", "--quiet", "--length-scale", "per_bone"]) == 0
    cal = BodyShape.load(out)
    assert float((cal.lengths - body.lengths).abs().max()) < 0.02
    assert main([*args, "--frames", "2", "--quiet"]) == 0  # consensus: one factor
    ratio = BodyShape.load(out).lengths / TEMPLATE.lengths
    assert float(ratio.max() - ratio.min()) < 1e-5
    # Without the shipped template the built-in adult stands in (here: the same as TEMPLATE).
    monkeypatch.setattr(calibrate_cli, "DEFAULT_TEMPLATE", tmp_path / "missing.json")
    plain = [a for a in args if a not in ("--template", str(tmp_path / "template.json"))]
    assert main([*plain, "--frames", "2", "--quiet"]) == 0
    assert torch.allclose(BodyShape.load(out).lengths, TEMPLATE.lengths * ratio[0], rtol=1e-5)
    missing = ["--template", str(tmp_path / "nope.json")]  # named but missing: an error
    assert main([*plain, "--frames", "2", "--quiet", *missing]) == 2


def test_cli_errors(tmp_path, capsys):
    _write_recording(tmp_path / "rec", [rest_pose(1, (0.0, 0.1, 2.6))[0]], TEMPLATE)
    out = tmp_path / "body.json"
    base = ["--input", str(tmp_path / "rec"), "--output", str(out), "--quiet"]
    assert main([*base, "--model", str(tmp_path / "none.npz")]) == 2
    assert "model file not found" in capsys.readouterr().err
    # The pose check labels with the general forest, which must exist too.
    assert main([*base, "--detect-model", str(tmp_path / "general.npz")]) == 2
    assert "general.npz" in capsys.readouterr().err
    assert main([*base, "--labels", "recording", "--frames", "1"]) == 2
    assert "reference pose" in capsys.readouterr().err
    assert main(["--input", str(tmp_path / "nothing"), "--output", str(out)]) == 2
    assert not out.exists()


def test_shipped_template_is_the_cli_default():
    """configs/body_template.json (python -m depthmocap.train.bodies.template_body) loads and has
    anny's
    proportions: a chest (top of the lumbar spine to the base of the neck) of some 30 cm."""
    from depthmocap.runtime.calibrate_cli import DEFAULT_TEMPLATE, build_parser

    assert build_parser().parse_args(["--input", "x", "--output", "y"]).template == DEFAULT_TEMPLATE
    template = BodyShape.load(DEFAULT_TEMPLATE)
    assert 0.27 < float(template.lengths[2]) < 0.36
    assert float(template.clavicle_rest[0]) < 0


def test_hips_offsets_and_feet_follow_the_torso_and_template():
    """What a front view cannot measure comes from the template, scaled: the sections' offsets
    from the joint axis (radius scale), the feet (the shank's scales); the pelvis's radius and
    the hip width follow the abdomen's and chest's width, not the pelvis's own pixels."""
    from depthmocap.runtime.calibrate_cli import DEFAULT_TEMPLATE

    template = BodyShape.load(DEFAULT_TEMPLATE)
    t = template
    body = BodyShape(
        t.lengths * 1.05, t.radii * 1.1, t.extents * 1.05, t.hip_half_width * 1.1,
        t.offsets * 1.1, t.feet * torch.tensor([1.05, 1.1]), t.chest_tilt, t.clavicle_rest,
    )  # fmt: skip
    depth, labels = render_labels(reference_pose(root_position=(0.0, 0.05, 2.6)), body)
    cal = calibrate_body([depth], [labels], INTR, template, FAST)
    assert bool((template.offsets.abs() > 0.01).any())
    torso_scale = cal.radii[1:3, 0] / template.radii[1:3, 0]
    scale = cal.radii[:, 0] / template.radii[:, 0]
    assert torch.allclose(cal.offsets, template.offsets * scale[:, None], atol=1e-6)
    assert float((cal.offsets - body.offsets).abs().max()) < 0.01
    assert float(scale[0]) == pytest.approx(float(torso_scale.mean()), rel=1e-5)
    assert float(cal.hip_half_width / template.hip_half_width) == pytest.approx(
        float(torso_scale.mean()), rel=1e-5
    )
    assert abs(float(cal.hip_half_width - body.hip_half_width)) < 0.01
    assert float((cal.feet - body.feet).abs().max()) < 0.02
    cal.validate()


def test_hips_fall_back_to_the_thigh_gap_without_a_torso():
    """No abdomen or chest pixels (covered, or mislabelled): the hip width comes from the gap
    between the thigh axes, the pelvis's radius from the overall scale; the body is valid."""
    from depthmocap.shared.labels import PART_SEGMENT

    body = subject()
    depth, labels = render_labels(reference_pose(root_position=(0.0, 0.05, 2.6)), body)
    seg = torch.as_tensor(PART_SEGMENT)[labels]
    labels = torch.where((seg == 1) | (seg == 2), torch.zeros_like(labels), labels)
    cal = calibrate_body([depth], [labels], INTR, TEMPLATE, FAST)
    cal.validate()
    assert abs(float(cal.hip_half_width - body.hip_half_width)) < 0.02
    overall = (cal.lengths / TEMPLATE.lengths).median()
    assert torch.allclose(cal.radii[0], TEMPLATE.radii[0] * overall, rtol=1e-5)
