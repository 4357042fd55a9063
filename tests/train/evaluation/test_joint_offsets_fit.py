"""Fitting the output-joint offsets (train.evaluation.joint_offsets_fit)."""

from __future__ import annotations

import numpy as np
import pytest
from depthmocap.shared import skeleton as sk
from depthmocap.train.evaluation.joint_offsets_fit import fit_offsets, main

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
