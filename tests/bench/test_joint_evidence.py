"""Recording the hybrid's per-joint evidence (bench.joint_evidence)."""

from __future__ import annotations

import numpy as np
import pytest
from depthmocap.bench import joint_evidence
from depthmocap.runtime.tracker import TrackerConfig


def test_evidence_of_each_posed_frame_is_written_once(two_demo_recordings, tmp_path, monkeypatch):
    out = tmp_path / "evidence"
    assert joint_evidence.main(["--recordings", str(two_demo_recordings), "--out", str(out)]) == 0
    files = sorted(p.name for p in out.iterdir())
    assert files == ["a.npz", "b.npz"]
    with np.load(out / "a.npz") as data:
        assert list(data["frame"]) == [0, 1]
        assert data["support"].shape == (2, 16) and data["visibility"].shape == (2, 4)
        assert data["joints"].shape == (2, 16, 3) and np.isfinite(data["joints"]).all()
        assert data["fit"].shape == (2, 5) and data["cut_m"].shape == (2, 16)
        assert (data["fit"][:, 0] > 0.5).all()  # the demo's fits overlap its silhouette
        assert (data["cut_m"] > 0).all()  # a distance, or inf where the person is whole
        parts = data["parts"]
        assert parts.shape == (2, 16, 2) and (parts[..., 1] >= 0).all()
        # the demo's forest sees most joints' parts, and near the fitted joints
        assert np.median(parts[..., 0]) < 0.1 and (parts[..., 1] > 0).mean() > 0.5
        # the flags beside the evidence are the tracker's own area test, not the confidence's
        area = TrackerConfig().observed_joint_area_cm2
        np.testing.assert_array_equal(data["observed"], data["support"] >= area)
    # A second run keeps what is there (an interrupted run resumes at the next recording).
    monkeypatch.setattr(joint_evidence, "track_evidence", lambda *a: pytest.fail("tracked again"))
    joint_evidence.main(["--recordings", str(two_demo_recordings / "a"), "--out", str(out)])


def test_a_missing_recording_is_a_usage_error(tmp_path):
    with pytest.raises(SystemExit):
        joint_evidence.main(["--recordings", str(tmp_path / "none"), "--out", str(tmp_path)])


@pytest.mark.parametrize("frames", ["-1", "61"])
def test_a_look_back_out_of_range_is_a_usage_error(tmp_path, frames, capsys):
    with pytest.raises(SystemExit):
        joint_evidence.main(["--recordings", str(tmp_path), "--out", str(tmp_path),
                             "--look-back", frames])  # fmt: skip
    assert "--look-back must be 0-60" in capsys.readouterr().err
