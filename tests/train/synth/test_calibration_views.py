"""depthmocap.train.synth.calibration_views (the two calibration views with ground truth) and the
helpers of train.evaluation.personalization. Rendering needs anny and EGL and skips without them."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.recording import Recording
from depthmocap.shared.so3 import rotvec_to_matrix
from depthmocap.train.evaluation.personalization import subject_phenotypes, vertex_errors
from depthmocap.train.synth.calibration_views import (
    CALIBRATION_POSE_DEG,
    CalibrationViewConfig,
    calibration_world_pose,
)


def test_calibration_pose_matches_the_runtime_reference():
    from depthmocap.runtime.personalize.reference_pose import CALIBRATION_POSE_DEG as RUNTIME_POSE

    assert CALIBRATION_POSE_DEG == RUNTIME_POSE


def test_world_pose_faces_front_or_back_within_limits():
    cfg = CalibrationViewConfig(pose_jitter_deg=30.0, yaw_jitter_deg=0.0, offset_m=0.0)
    rng = np.random.default_rng(0)
    for view, forward_z in (("front", 1.0), ("back", -1.0)):
        q = calibration_world_pose(view, rng, cfg)
        lim = sk.DOF_LIMITS[6:]  # radians
        assert (q[6:] >= lim[:, 0] - 1e-9).all() and (q[6:] <= lim[:, 1] + 1e-9).all()
        rot = rotvec_to_matrix(torch.as_tensor(q[3:6]))
        assert float(rot[2, 2]) == pytest.approx(forward_z, abs=1e-9)


def test_subject_phenotypes_alternate_gender_and_spread_height():
    subjects = subject_phenotypes(6, seed=1)
    assert [s["gender"] < 0.5 for s in subjects] == [True, False] * 3
    heights = sorted(s["height"] for s in subjects)
    assert heights[0] == pytest.approx(0.25) and heights[-1] == pytest.approx(0.6)
    assert subject_phenotypes(6, seed=1) == subjects


def test_vertex_errors_raw_and_aligned():
    gt = np.random.default_rng(0).normal(size=(50, 3))
    keep = np.ones(50, bool)
    keep[:5] = False
    err = vertex_errors(gt + [0.003, 0.0, 0.004], gt, keep)
    assert err["raw"]["mean_mm"] == pytest.approx(5.0)
    assert err["aligned"]["max_mm"] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.slow
def test_render_calibration_views(tmp_path):
    pytest.importorskip("anny")
    pytest.importorskip("pyrender")
    from depthmocap.train.synth.calibration_views import render_calibration_views

    try:
        out = render_calibration_views(tmp_path / "v", seed=3, cfg=CalibrationViewConfig(width=160))
    except RuntimeError as err:  # EGL unavailable
        pytest.skip(f"EGL rendering unavailable: {err}")
    gt = np.load(out / "groundtruth_body.npz")
    assert gt["rest_vertices"].shape[1] == 3 and gt["faces"].max() < len(gt["rest_vertices"])
    assert len(gt["phenotype"]) == len(gt["phenotype_keys"]) == 6
    for view, q_key, facing in (("front", "q_front", -1.0), ("back", "q_back", 1.0)):
        rec = Recording(out / view)
        assert len(rec) == 1 and rec.intrinsics.width == 160
        depth = rec.read_depth(0)
        person = rec.read_labels(0) > 0
        assert person.sum() > 500
        z = float(np.median(depth[person]))
        assert 2.4 < z < 3.2
        q = gt[q_key]
        assert np.allclose(q, rec.groundtruth()["q"][0], atol=1e-5)
        # Body forward (z) seen from the camera: towards it in front, away from it in back.
        rot = rotvec_to_matrix(torch.as_tensor(q[3:6]))
        assert math.copysign(1.0, float(rot[2, 2])) == facing
