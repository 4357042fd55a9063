"""The tracker's settings (runtime.tracker.config): what TrackerConfig rejects, and the hybrid
preset's tracker terms."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
from depthmocap.runtime.tracker import TrackerConfig, TrackerConfigError
from depthmocap.shared.config import load_config

REPO = Path(__file__).resolve().parents[3]

pytestmark = pytest.mark.usefixtures("one_thread")


class TestTrackerConfig:
    def test_hybrid_preset_sets_the_tracker_terms(self):
        from depthmocap.runtime.hybrid import HybridConfig

        cfg = load_config(HybridConfig, REPO / "configs" / "hybrid.yaml")
        assert cfg.tracker.use_labels and cfg.tracker.use_collision
        assert cfg.tracker == TrackerConfig(use_labels=True, use_collision=True)

    def test_errors(self):
        """Bad settings are rejected clearly, by the constructor and by replace."""
        for bad in ({"downsample": -1}, {"person_pixels": 0}):
            with pytest.raises(TrackerConfigError, match="downsample must be >= 0"):
                TrackerConfig(**bad)
        for bad in (0.0, -0.04, math.nan):
            with pytest.raises(TrackerConfigError, match="sigma_extra_m"):
                TrackerConfig(sigma_extra_m=bad)
        with pytest.raises(TrackerConfigError, match="sigma_prior_rad"):  # replace checks too
            dataclasses.replace(TrackerConfig(), sigma_prior_rad=-1.0)
        for bad in (-1.0, math.inf, math.nan):
            with pytest.raises(TrackerConfigError, match="pose_prior_weight"):
                TrackerConfig(pose_prior_weight=bad)
        assert TrackerConfig(pose_prior_weight=0.0).pose_prior_weight == 0.0
