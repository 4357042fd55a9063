"""Tests of train.bodies (anny_body, skinning, measurements): anny bodies in our body frame,
labels, LBS posing, joints.

Tests that need the anny model are marked slow: the first build on a machine takes about a
minute (later loads about 2 s); one body is built per test session.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from depthmocap.shared.labels import NUM_CLASSES, PART_NAMES
from depthmocap.shared.skeleton import JOINT_NAMES, SEGMENT_NAMES
from depthmocap.train.bodies import anny_body as ab
from depthmocap.train.bodies import measurements, skinning

REPO = Path(__file__).resolve().parents[3]
PHENOTYPE = {"gender": 0.1, "age": 0.8, "muscle": 0.6, "weight": 0.4, "height": 0.45,
             "proportions": 0.5}  # fmt: skip


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking direction a to direction b (Rodrigues)."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    axis, cos = np.cross(a, b), float(a @ b)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + cos)


def _identity(body: ab.AnnyBody, *batch: int) -> np.ndarray:
    return np.broadcast_to(np.eye(3), (*batch, body.num_bones, 3, 3)).copy()


@pytest.fixture(scope="module")
def body() -> ab.AnnyBody:
    pytest.importorskip("anny")
    return ab.make_body(PHENOTYPE)


# --- no anny needed ------------------------------------------------------------------------


def test_import_is_cheap():
    # anny (and its minute-long first build) must load only when a body is asked for.
    code = "import sys, train.bodies.anny_body; print('anny' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                         check=True)  # fmt: skip
    assert out.stdout.strip() == "False"


def test_sample_phenotype_deterministic_and_in_range():
    a = [ab.sample_phenotype(np.random.default_rng(7)) for _ in range(2)]
    assert a[0] == a[1]
    rng = np.random.default_rng(7)
    many = [ab.sample_phenotype(rng) for _ in range(200)]
    assert many[0] == a[0]
    assert len({tuple(p.values()) for p in many}) == 200  # all distinct
    values = np.array([[p[k] for k in ab.PHENOTYPE_KEYS] for p in many])
    assert set(many[0]) == set(ab.PHENOTYPE_KEYS)
    assert values.min() >= 0.0 and values.max() <= 1.0
    height = values[:, ab.PHENOTYPE_KEYS.index("height")]
    assert height.min() >= ab.SAFE_HEIGHT_RANGE[0] and height.max() <= ab.SAFE_HEIGHT_RANGE[1]
    gender = values[:, ab.PHENOTYPE_KEYS.index("gender")]
    assert (gender < 0.5).sum() > 60 and (gender > 0.5).sum() > 60  # both genders
    assert values[:, ab.PHENOTYPE_KEYS.index("age")].min() >= 0.7  # adults


def test_phenotype_validation():
    with pytest.raises(ValueError, match="height"):
        ab._check_phenotype({"height": 0.9})
    with pytest.raises(ValueError, match="unknown"):
        ab._check_phenotype({"size": 0.5})
    with pytest.raises(ValueError, match="non-free"):
        ab.load_anny_model(topology="smplx")


def test_every_cmu_bone_has_a_segment_and_left_means_left():
    seg = ab.bone_segments(tuple(ab.BONE_SEGMENT))
    assert set(seg) == set(range(len(SEGMENT_NAMES)))
    for bone, s in ab.BONE_SEGMENT.items():
        if s == "pelvis":  # LHipJoint/RHipJoint belong to the pelvis
            continue
        if bone.startswith(("Left", "L")) and bone != "LowerBack":
            assert s.startswith("l_"), bone
        if bone.startswith(("Right", "R")):
            assert s.startswith("r_"), bone


def test_chain_matrices_paths():
    # root 0 -> 1 -> 2, root -> 3
    lever, path = skinning._chain_matrices((-1, 0, 1, 0))
    assert lever.tolist() == [0, 0, 1, 0]
    assert path.tolist() == [[1, 0, 0, 0], [1, 1, 0, 0], [1, 1, 1, 0], [1, 0, 0, 1]]


# --- anny bodies (slow) ----------------------------------------------------------------------


@pytest.mark.slow
def test_body_arrays(body):
    v, n = body.num_vertices, body.num_bones
    assert body.vertices.shape == (v, 3) and body.faces.shape[1] == 3
    assert body.faces.min() == 0 and body.faces.max() == v - 1
    assert n == 31 and body.bone_names[0] == "Hips" and body.bone_parents[0] == -1
    assert body.skin_weights.shape == (v, n)
    np.testing.assert_allclose(body.skin_weights.sum(1), 1.0, atol=1e-9)
    assert body.labels.shape == (v,) and body.labels.dtype == np.uint8


@pytest.mark.slow
def test_body_frame(body):
    joints = dict(zip(JOINT_NAMES, measurements.anatomical_joints(body)))
    np.testing.assert_allclose(joints["pelvis"], 0.0, atol=1e-12)  # origin at the hip centre
    np.testing.assert_allclose(joints["l_hip"][1:], 0.0, atol=1e-9)  # hips level, on x
    assert joints["head"][1] > joints["neck"][1] > joints["spine"][1] > 0 > joints["l_knee"][1]
    toe, foot = body.bone_index("LeftToeBase"), body.bone_index("LeftFoot")
    assert body.bone_tails[toe][2] > body.bone_heads[foot][2] + 0.08  # toes point forward (+z)
    stature = np.ptp(body.vertices[:, 1])
    assert 1.5 < stature < 2.1


@pytest.mark.slow
def test_labels_cover_all_parts_and_left_is_plus_x(body):
    counts = np.bincount(body.labels, minlength=NUM_CLASSES)
    assert counts[0] == 0 and (counts[1:] > 0).all()
    x = body.vertices[:, 0]
    for p, name in enumerate(PART_NAMES[1:], start=1):
        xs = x[body.labels == p]
        if name.startswith("l_"):
            assert xs.min() > 0.0, name
        elif name.startswith("r_"):
            assert xs.max() < 0.0, name
    hand = body.bone_heads[body.bone_index("LeftHand")]
    assert hand[0] > 0.3  # the person's left hand is at +x
    # Upper/lower leg parts: the upper part lies above the lower one.
    for side in "lr":
        for seg in ("thigh", "shank"):
            y_up = body.vertices[body.labels == PART_NAMES.index(f"{side}_{seg}_upper"), 1]
            y_lo = body.vertices[body.labels == PART_NAMES.index(f"{side}_{seg}_lower"), 1]
            assert y_up.mean() > y_lo.mean()
    # Foot vertices (below the ankle) are lower shank.
    ankle = dict(zip(JOINT_NAMES, measurements.anatomical_joints(body)))["l_ankle"]
    foot = (body.vertices[:, 1] < ankle[1] - 0.03) & (x > 0)
    assert (body.labels[foot] == PART_NAMES.index("l_shank_lower")).all()


@pytest.mark.slow
def test_identity_pose_reproduces_rest(body):
    for dtype, tol in ((np.float64, 1e-12), (np.float32, 1e-6)):
        posed = skinning.pose_body(body, _identity(body).astype(dtype), np.zeros(3, dtype))
        assert posed.vertices.dtype == dtype
        np.testing.assert_allclose(posed.vertices, body.vertices, atol=tol)
        np.testing.assert_allclose(posed.bone_heads, body.bone_heads, atol=tol)
        np.testing.assert_allclose(posed.bone_tails, body.bone_tails, atol=tol)
    # Batched, with a root translation per pose.
    root = np.array([[0.0, 0.0, 0.0], [0.1, -0.2, 2.5]])
    posed = skinning.pose_body(body, _identity(body, 2), root)
    assert posed.vertices.shape == (2, body.num_vertices, 3)
    np.testing.assert_allclose(posed.vertices[1], body.vertices + root[1], atol=1e-12)


@pytest.mark.slow
def test_forearm_rotation_moves_wrist(body):
    joints = dict(zip(JOINT_NAMES, measurements.anatomical_joints(body)))
    elbow, wrist = joints["l_elbow"], joints["l_wrist"]
    # Point the left forearm straight forward (+z): the wrist lands one forearm length in
    # front of the elbow.
    rot = _identity(body)
    turn = _rotation_between(wrist - elbow, np.array([0.0, 0.0, 1.0]))
    rot[body.bone_index("LeftForeArm")] = turn
    posed = skinning.pose_body(body, rot, np.zeros(3))
    got = dict(zip(JOINT_NAMES, measurements.anatomical_joints(body, posed)))
    length = np.linalg.norm(wrist - elbow)
    np.testing.assert_allclose(got["l_wrist"], elbow + [0.0, 0.0, length], atol=1e-9)
    for name in ("l_elbow", "l_shoulder", "r_wrist", "pelvis", "head"):
        np.testing.assert_allclose(got[name], joints[name], atol=1e-12)
    # A 90 degree turn about x of the whole forearm+hand subtree moves vertices that only the
    # subtree skins rigidly about the elbow.
    subtree = [i for i, n in enumerate(body.bone_names)
               if ab.BONE_SEGMENT[n] == "l_forearm"]  # fmt: skip
    rot = _identity(body)
    rot[subtree] = _rot_x(math.pi / 2)
    posed = skinning.pose_body(body, rot, np.zeros(3))
    rigid = body.skin_weights[:, subtree].sum(1) > 1.0 - 1e-9
    assert rigid.sum() > 500
    expected = elbow + (body.vertices[rigid] - elbow) @ _rot_x(math.pi / 2).T
    np.testing.assert_allclose(posed.vertices[rigid], expected, atol=1e-9)
    got = dict(zip(JOINT_NAMES, measurements.anatomical_joints(body, posed)))
    np.testing.assert_allclose(got["l_wrist"], elbow + _rot_x(math.pi / 2) @ (wrist - elbow),
                               atol=1e-9)  # fmt: skip


@pytest.mark.slow
def test_matches_anny_forward_pass(body):
    """Our LBS equals anny's own forward pass ('world-orient' parameterization)."""
    import torch

    model = ab.load_anny_model()
    rng = np.random.default_rng(3)
    rotvec = rng.normal(0.0, 0.4, (body.num_bones, 3))
    angle = np.linalg.norm(rotvec, axis=1, keepdims=True)[..., None]
    k = np.zeros((body.num_bones, 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -rotvec[:, 2], rotvec[:, 1], -rotvec[:, 0]
    k = (k - k.transpose(0, 2, 1)) / angle
    rot = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    root = np.array([0.2, 0.9, 2.0])
    posed = skinning.pose_body(body, rot, root)

    c = ab.ANNY_TO_BODY
    with torch.no_grad():
        rest = model(phenotype_kwargs=body.phenotype)["rest_bone_poses"][0, :, :3, :3].numpy()
        delta = np.tile(np.eye(4), (body.num_bones, 1, 1))
        delta[:, :3, :3] = c.T @ rot @ c @ rest  # posed world orientation, anny frame
        delta[0, :3, 3] = c.T @ posed.bone_heads[0] + body.hip_centre_anny
        out = model(pose_parameters=torch.as_tensor(delta)[None], phenotype_kwargs=body.phenotype,
                    pose_parameterization="world-orient")  # fmt: skip
    verts = (out["vertices"][0].numpy() - body.hip_centre_anny) @ c.T
    np.testing.assert_allclose(posed.vertices, verts, atol=1e-9)


@pytest.mark.slow
def test_segment_rotations_and_measurements(body):
    seg_rot = np.broadcast_to(np.eye(3), (len(SEGMENT_NAMES), 3, 3)).copy()
    seg_rot[SEGMENT_NAMES.index("head")] = _rot_x(0.3)
    rot = skinning.segment_to_bone_rotations(body, seg_rot)
    assert rot.shape == (body.num_bones, 3, 3)
    np.testing.assert_allclose(rot[body.bone_index("Head")], _rot_x(0.3))
    np.testing.assert_allclose(rot[body.bone_index("Neck1")], np.eye(3))

    m = measurements.body_measurements(body)
    lengths = measurements.segment_lengths(body)
    assert lengths.shape == (len(SEGMENT_NAMES),)
    assert m["l_thigh"] == pytest.approx(m["r_thigh"]) and 0.35 < m["l_thigh"] < 0.55
    assert 0.2 < m["l_forearm"] < 0.32 and 0.08 < m["hip_half_width"] < 0.16
    assert 0.14 < m["hand_length"] < 0.25 and 0.05 < m["ankle_height"] < 0.12


@pytest.mark.slow
def test_distinct_phenotypes_give_distinct_bodies(body):
    other = ab.make_body({**PHENOTYPE, "gender": 0.95, "height": 0.3})
    assert other.vertices.shape == body.vertices.shape
    assert (
        measurements.body_measurements(other)["stature"]
        < measurements.body_measurements(body)["stature"] - 0.05
    )
