"""``python -m depthmocap.train.mocap.fit_pose_prior``: writes the prior of the clips' poses;
no clips is a message and exit 2; the real training split when ../shared is there."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from depthmocap.shared.pose_prior import load_pose_prior
from depthmocap.train.mocap import fit_pose_prior as cli


def test_writes_the_prior_of_the_poses(tmp_path, monkeypatch):
    q = np.random.default_rng(1).normal(0.0, 0.2, (50, 34))
    monkeypatch.setattr(cli, "training_poses", lambda folders, fps: (q, 4))
    out = tmp_path / "prior.json"
    assert cli.main(["--mocap", str(tmp_path), "--out", str(out)]) == 0
    prior = load_pose_prior(out)
    assert np.allclose(prior.mean, q[:, 6:].mean(0)) and prior.clips == 4
    assert prior.fitted_on.startswith("4 clips of")


def test_no_clips_is_a_clear_error(tmp_path, capsys):
    out = tmp_path / "prior.json"
    assert cli.main(["--mocap", str(tmp_path), "--out", str(out)]) == 2
    assert "no .bvh or .amc clips" in capsys.readouterr().err
    assert not out.exists()


SHARED_CMU = Path(__file__).resolve().parents[3] / "../shared/data/mocap/cmu"


@pytest.mark.skipif(not SHARED_CMU.is_dir(), reason="needs ../shared/data/mocap")
def test_real_clips_give_a_plausible_prior(tmp_path):
    """Two real CMU clips retargeted at 5 frames/s: knees bent on average, a proper
    covariance."""
    folder = tmp_path / "clips"
    folder.mkdir()
    for name in sorted(p.name for p in SHARED_CMU.glob("*.bvh"))[:2]:
        (folder / name).symlink_to((SHARED_CMU / name).resolve())
    out = tmp_path / "prior.json"
    assert cli.main(["--mocap", str(folder), "--fps", "5", "--out", str(out)]) == 0
    prior = load_pose_prior(out)
    assert prior.clips == 2 and prior.frames > 20
    assert np.linalg.eigvalsh(prior.covariance).min() > -1e-9
