"""depthmocap.shared.anny_rig: the anny facts shared by synthesis and personalization agree."""

from __future__ import annotations

import os

import numpy as np
import pytest
from depthmocap.shared import anny_rig as rig
from depthmocap.shared.skeleton import JOINT_NAMES, SEGMENT_NAMES


def test_anny_to_body_is_a_proper_rotation_onto_our_axes():
    r = rig.ANNY_TO_BODY
    assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
    # anny left (+X) stays left, anny up (+Z) becomes our up (+y), anny -Y (facing) our +z.
    assert np.allclose(r @ [1, 0, 0], [1, 0, 0])
    assert np.allclose(r @ [0, 0, 1], [0, 1, 0])
    assert np.allclose(r @ [0, -1, 0], [0, 0, 1])


def test_segment_bones_inverts_bone_segment():
    assert tuple(rig.SEGMENT_BONES) == SEGMENT_NAMES
    pairs = {(b, s) for s, bones in rig.SEGMENT_BONES.items() for b in bones}
    assert pairs == set(rig.BONE_SEGMENT.items())
    # The first bone of each arm segment runs along it (personalization's rest corrections).
    assert rig.SEGMENT_BONES["l_forearm"][0] == "LeftForeArm"
    assert rig.SEGMENT_BONES["r_upper_arm"][0] == "RightArm"


def test_joint_recipes_cover_the_named_joints_with_unit_weights():
    assert tuple(rig.JOINT_RECIPES) == JOINT_NAMES
    for name, recipe in rig.JOINT_RECIPES.items():
        assert sum(w for _, _, w in recipe) == pytest.approx(1.0), name
        assert all(bone in rig.BONE_SEGMENT and end in ("head", "tail") for bone, end, _ in recipe)
    assert {b for b, _, _ in rig.JOINT_RECIPES["pelvis"]} == set(rig.HIP_BONES)


def test_forbidden_topologies():
    assert rig.is_forbidden_topology("smpl") and rig.is_forbidden_topology("smplx-something")
    assert not rig.is_forbidden_topology(rig.DEFAULT_TOPOLOGY)
    assert not rig.is_forbidden_topology("notoes_collapse10pc")


def test_cache_dir_from_environment(monkeypatch, tmp_path):
    monkeypatch.delenv("ANNY_CACHE_DIR", raising=False)
    monkeypatch.setenv("DEPTHMOCAP_CACHE", str(tmp_path / "cache"))
    assert rig.default_cache_dir() == tmp_path / "cache" / "anny"
    assert rig.export_cache_dir(tmp_path) == tmp_path
    assert os.environ["ANNY_CACHE_DIR"] == str(tmp_path)  # published for anny's import
    assert rig.default_cache_dir() == tmp_path
    # An explicit directory never overrides a variable that is already set.
    assert rig.export_cache_dir(tmp_path / "other") == tmp_path / "other"
    assert os.environ["ANNY_CACHE_DIR"] == str(tmp_path)
