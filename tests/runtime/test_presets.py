"""The named hybrid settings: the default is the shipped system, wei2012 the paper's."""

from __future__ import annotations

import json

import depthmocap.runtime.track_cli as cli
import numpy as np
import pytest
from depthmocap.runtime.estimator import PoseEstimate
from depthmocap.runtime.hybrid import FailureThresholds, HybridConfig, hybrid_config
from depthmocap.runtime.presets import DEFAULT_PRESET, PRESETS, PresetError, preset_settings
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.recording import RecordingWriter


def test_the_default_preset_is_what_hybrid_config_defaults_to():
    assert DEFAULT_PRESET == "shipped"
    assert hybrid_config(preset_settings("shipped")) == HybridConfig()


def test_wei2012_is_the_paper():
    cfg = hybrid_config(preset_settings("wei2012"))
    assert cfg.failure == FailureThresholds(2.5, 0.9, None) and cfg.failure.lost_overlap is None
    assert cfg.keep_better is None and cfg.arm_search is None and cfg.body_scale is None
    assert cfg.behind_model is None and cfg.joint_confidence is None
    assert not cfg.tracker.use_labels and not cfg.tracker.use_collision
    assert cfg.detector.label_smoothing_window == 1 and cfg.detector.reset_limbs == "none"


def test_a_partial_config_changes_only_what_it_names():
    cfg = hybrid_config({"failure": {"epsilon1_cm": 4.0}, "arm_search": None})
    shipped = HybridConfig()
    assert cfg.failure == FailureThresholds(4.0, shipped.failure.epsilon2, 80.0, lost_overlap=0.3)
    assert cfg.arm_search is None and cfg.keep_better == shipped.keep_better


def test_unknown_preset():
    with pytest.raises(PresetError, match="shipped"):
        preset_settings("nope")
    assert set(PRESETS) == {"shipped", "wei2012"}


class Recorder:
    """Stands in for the estimator; keeps the settings it was built with."""

    def __init__(self, cfg):
        self.cfg = cfg

    def reset(self):
        pass

    def estimate(self, frame):
        return PoseEstimate(None, None, "lost", {})


@pytest.mark.parametrize(
    "extra, epsilon1",
    [([], 3.0), (["--preset", "wei2012"], 2.5), (["--preset", "wei2012", "--config", "C"], 5.0)],
)
def test_runtime_track_runs_the_shipped_system_unless_told(
    tmp_path, monkeypatch, capsys, extra, epsilon1
):
    intr = Intrinsics.kinect_v1(80)
    rec = tmp_path / "rec"
    with RecordingWriter(rec, intr) as w:
        w.write_frame(np.full((intr.height, intr.width), 2000, np.uint16))
    (tmp_path / "c.yaml").write_text("failure:\n  epsilon1_cm: 5.0\n")
    built = {}

    def make(mode, model, body, intrinsics, device="cpu", config=None):
        built["cfg"] = hybrid_config(config)
        return Recorder(built["cfg"])

    monkeypatch.setattr(cli, "make_estimator", make)
    extra = [str(tmp_path / "c.yaml") if a == "C" else a for a in extra]
    out = tmp_path / "out"
    assert cli.main(["-i", str(rec), "-o", str(out), "-q", *extra]) == 0
    assert built["cfg"].failure.epsilon1_cm == epsilon1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["extra"]["settings"]["failure"]["epsilon1_cm"] == epsilon1


def test_a_preset_is_for_the_hybrid_only(tmp_path, capsys):
    code = cli.main(["-i", "demo", "-o", str(tmp_path / "o"), "--mode", "detector",
                     "--preset", "wei2012"])  # fmt: skip
    assert code == 2
    assert "--preset names hybrid settings" in capsys.readouterr().err
