"""Fitting the output-joint offsets (train.evaluation.joint_offsets_fit)."""

from __future__ import annotations

import numpy as np
import pytest
from depthmocap.shared import skeleton as sk
from depthmocap.train.evaluation.joint_offsets_fit import fit_offsets, fit_pose_offsets, main

J = len(sk.JOINT_NAMES)


def _rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, S, 3, 3) random rotations (QR of Gaussian matrices, det +1)."""
    m = rng.normal(size=(n, sk.NUM_SEGMENTS, 3, 3))
    qr, r = np.linalg.qr(m)
    qr = qr * np.sign(np.diagonal(r, axis1=-2, axis2=-1))[..., None, :]
    return qr * np.sign(np.linalg.det(qr))[..., None, None]


def test_recovers_offsets_despite_failed_frames():
    """Truth = model + s R o with a little noise; a fifth of the frames are failures far off
    in random directions: the median still finds o."""
    rng = np.random.default_rng(0)
    n = 400
    true = rng.normal(0, 0.05, (J, 3))
    rot = _rotations(n, rng)
    scale = rng.uniform(0.85, 1.15, n)
    model = rng.normal(0, 1, (n, J, 3))
    seg_rot = rot[:, np.asarray(sk.JOINT_SEGMENT)]
    truth = model + scale[:, None, None] * np.einsum("njab,jb->nja", seg_rot, true)
    truth += rng.normal(0, 0.005, truth.shape)
    failed = rng.random(n) < 0.2
    truth[failed] += rng.normal(0, 0.4, (failed.sum(), J, 3))
    np.testing.assert_allclose(fit_offsets(model, truth, rot, scale), true, atol=0.006)


def test_cli_errors(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--results", str(tmp_path / "no"), "--recordings", str(tmp_path), "--out", "o"])
    (tmp_path / "results" / "a").mkdir(parents=True)
    args = ["--results", str(tmp_path / "results"), "--recordings", str(tmp_path)]
    assert main([*args, "--out", str(tmp_path / "o.json")]) == 2
    assert "no results" in capsys.readouterr().err
    assert not (tmp_path / "o.json").exists()


def test_cli_fits_offsets_from_tracked_results(tmp_path, capsys):
    """A recording whose ground truth is the model's joints moved by known offsets, and a
    result holding the poses and the run's body: the CLI recovers the offsets (scaled by the
    body's stature) and writes a file the runtime reads."""
    import json

    import torch
    from depthmocap.shared.body import BodyShape
    from depthmocap.shared.camera import Intrinsics
    from depthmocap.shared.joint_offsets import load_joint_offsets, offset_joints
    from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
    from depthmocap.shared.recording import RecordingWriter

    rng = np.random.default_rng(1)
    body = BodyShape.default(torch.float64).scaled(1.1)
    q = torch.zeros(6, sk.NUM_DOFS, dtype=torch.float64)
    q[:, 2], q[:, 3] = 2.5, np.pi
    q[:, 6:] = torch.from_numpy(rng.normal(0, 0.2, (6, sk.NUM_DOFS - 6)))
    kin = forward_kinematics(q, body)
    true = torch.from_numpy(rng.normal(0, 0.04, (J, 3)))
    reference = float(BodyShape.default(torch.float64).stature())
    scale = float(body.stature()) / reference
    truth = offset_joints(named_joint_positions(kin), kin.rotations, true, torch.tensor(scale))
    intr = Intrinsics.kinect_v1(80)
    with RecordingWriter(tmp_path / "recs" / "take", intr, fps=30.0, source="t") as w:
        for _ in range(6):
            w.write_frame(np.zeros((intr.height, intr.width), np.uint16))
        w.write_groundtruth(truth.numpy(), list(sk.JOINT_NAMES), q=q.numpy())
    result = tmp_path / "results" / "take" / "result"
    result.mkdir(parents=True)
    body.save(result / "body.json")
    lines = [{"frame": i, "status": "tracked", "q": q[i].tolist()} for i in range(6)]
    lines.append({"frame": 6, "status": "lost", "q": None})
    (result / "poses.jsonl").write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    out = tmp_path / "offsets.json"
    args = ["--results", str(tmp_path / "results"), "--recordings", str(tmp_path / "recs")]
    assert main([*args, "--out", str(out), "--constant"]) == 0
    assert "1 recordings, 6 frames" in capsys.readouterr().out
    fitted = load_joint_offsets(out)
    np.testing.assert_allclose(fitted.offsets_m, true.numpy(), atol=2e-4)
    assert fitted.reference_stature_m == pytest.approx(reference) and fitted.frames == 6


def test_recovers_pose_dependent_offsets_despite_failed_frames():
    """Truth = model + s R (o + features(q) C): the ridge fit over the frames within the gate
    finds o and C; failed frames far off are left out; the runtime's offsets_at agrees."""
    import torch
    from depthmocap.shared.joint_offsets import NUM_POSE_FEATURES, offsets_at, pose_features

    rng = np.random.default_rng(2)
    n = 1500
    q = rng.normal(0, 0.5, (n, sk.NUM_DOFS))
    o = rng.normal(0, 0.03, (J, 3))
    C = rng.normal(0, 0.01, (J, NUM_POSE_FEATURES, 3))
    local = o + np.einsum("np,jpc->njc", pose_features(torch.from_numpy(q)).numpy(), C)
    np.testing.assert_allclose(
        offsets_at(torch.from_numpy(q), torch.from_numpy(o), torch.from_numpy(C)).numpy(), local
    )
    rot = _rotations(n, rng)
    scale = rng.uniform(0.85, 1.15, n)
    model = rng.normal(0, 1, (n, J, 3))
    seg_rot = rot[:, np.asarray(sk.JOINT_SEGMENT)]
    truth = model + scale[:, None, None] * np.einsum("njab,njb->nja", seg_rot, local)
    failed = rng.random(n) < 0.1
    truth[failed] += rng.normal(0, 0.1, (failed.sum(), J, 3)) + 1.0  # all beyond the gate
    fit_o, fit_c = fit_pose_offsets(model, truth, rot, scale, q, ridge=1e-6, gate_m=0.2)
    np.testing.assert_allclose(fit_o, o, atol=1e-4)
    np.testing.assert_allclose(fit_c, C, atol=1e-4)
    with pytest.raises(ValueError, match="frames within"):
        fit_pose_offsets(model[:20], truth[:20], rot[:20], scale[:20], q[:20])
