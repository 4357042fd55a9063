"""VMC bones against the project's forward kinematics: composing the sent local transforms
from the root gives every joint position and segment frame (in Unity axes), the T-pose is all
identity, and the OSC bundles carry the documented layouts."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from depthmocap.runtime.export.rotations import quat_to_matrix
from depthmocap.runtime.export.vmc import (
    UNITY_FROM_BVH,
    VMC_BONE_NAMES,
    VMC_BONES,
    camera_to_unity_position,
    vmc_bone_transforms,
    vmc_root_transform,
)
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics, rest_pose

pytest.importorskip("pythonosc")

CAMERA_TO_UNITY = np.diag([-1.0, -1.0, -1.0])  # the documented conversion, written out
# Unity parent of each bone (HumanBodyBones hierarchy without UpperChest).
UNITY_PARENT = {
    "Hips": None, "Spine": "Hips", "Chest": "Spine", "Neck": "Chest", "Head": "Neck",
    "LeftShoulder": "Chest", "LeftUpperArm": "LeftShoulder", "LeftLowerArm": "LeftUpperArm",
    "LeftHand": "LeftLowerArm", "RightShoulder": "Chest", "RightUpperArm": "RightShoulder",
    "RightLowerArm": "RightUpperArm", "RightHand": "RightLowerArm", "LeftUpperLeg": "Hips",
    "LeftLowerLeg": "LeftUpperLeg", "LeftFoot": "LeftLowerLeg", "RightUpperLeg": "Hips",
    "RightLowerLeg": "RightUpperLeg", "RightFoot": "RightLowerLeg",
}  # fmt: skip
# Direction each bone points in the Unity T-pose (its local frame = the world frame there).
TPOSE_DIRECTION = {
    **dict.fromkeys(["Hips", "Spine", "Chest", "Neck", "Head"], (0, 1, 0)),
    **dict.fromkeys(["LeftShoulder", "LeftUpperArm", "LeftLowerArm", "LeftHand"], (-1, 0, 0)),
    **dict.fromkeys(["RightShoulder", "RightUpperArm", "RightLowerArm", "RightHand"], (1, 0, 0)),
    **dict.fromkeys(["LeftUpperLeg", "LeftLowerLeg", "LeftFoot"], (0, -1, 0)),
    **dict.fromkeys(["RightUpperLeg", "RightLowerLeg", "RightFoot"], (0, -1, 0)),
}


def _body() -> BodyShape:
    body = BodyShape.default(torch.float64).scaled(0.95)
    body.lengths[7] *= 1.1
    body.chest_tilt = torch.tensor(0.15, dtype=torch.float64)
    body.clavicle_rest = torch.tensor([-0.35, 0.1], dtype=torch.float64)
    return body


def _random_pose(rng) -> np.ndarray:
    q = np.zeros(sk.NUM_DOFS)
    q[0:3] = rng.uniform([-0.5, -0.5, 1.5], [0.5, 0.5, 3.5])
    q[3:6] = rng.normal(size=3)
    q[6:] = rng.uniform(sk.DOF_LIMITS[6:, 0], sk.DOF_LIMITS[6:, 1])
    return q


def compose(q: np.ndarray, body: BodyShape):
    """World (Unity) position and rotation of every bone from the sent local transforms."""
    root_p, root_r = vmc_root_transform(q)
    pos, rot = {}, {}
    for name, p, r in vmc_bone_transforms(q, body):
        parent = UNITY_PARENT[name]
        p_par, r_par = (root_p, quat_to_matrix(root_r)) if parent is None else (
            pos[parent], rot[parent])  # fmt: skip
        pos[name] = p_par + r_par @ p
        rot[name] = r_par @ quat_to_matrix(r)
    return pos, rot


def test_bone_names_are_unity_humanoid_names():
    assert set(VMC_BONE_NAMES) == set(UNITY_PARENT)
    assert len(VMC_BONE_NAMES) == 19


@pytest.mark.parametrize("seed", range(5))
def test_composed_bones_match_forward_kinematics(seed):
    rng = np.random.default_rng(seed)
    body = _body()
    q = _random_pose(rng)
    kin = forward_kinematics(torch.as_tensor(q)[None], body)
    seg_rot, origin = kin.rotations[0].numpy(), kin.origins[0].numpy()
    length = kin.lengths[0].numpy()
    pos, rot = compose(q, body)
    for name, k, kind in VMC_BONES:
        axis = seg_rot[k] @ sk.SEGMENT_AXIS[k]  # where the segment points, camera frame
        joint = origin[k] + (length[k] * axis if kind == "end" else 0.0)
        np.testing.assert_allclose(pos[name], CAMERA_TO_UNITY @ joint, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(
            rot[name] @ TPOSE_DIRECTION[name], CAMERA_TO_UNITY @ axis, atol=1e-12, err_msg=name
        )
        # The whole frame, twist included: Unity bone frame = N (world_bvh W_k T_k^T) N.
        assert np.linalg.det(rot[name]) == pytest.approx(1.0)
    # The lower arm's frame turns with the upper arm's twist: its palm direction is tracked.
    k = sk.SEGMENT_NAMES.index("l_forearm")
    palm = seg_rot[k] @ [-1.0, 0.0, 0.0]  # medial at rest (arm down): down in the T-pose
    np.testing.assert_allclose(rot["LeftLowerArm"] @ [0, -1, 0], CAMERA_TO_UNITY @ palm, atol=1e-12)


def test_tpose_is_identity_and_rest_pose_has_arms_down():
    body = BodyShape.default(torch.float64)
    q = rest_pose(1, root_position=(0.1, 0.2, 2.5), dtype=torch.float64).numpy()[0]
    q_t = q.copy()
    q_t[[sk.DOF_NAMES.index("l_humerus_abd"), sk.DOF_NAMES.index("r_humerus_abd")]] = np.pi / 2
    for name, _p, r in vmc_bone_transforms(q_t, body):
        np.testing.assert_allclose(r, [0, 0, 0, 1], atol=1e-12, err_msg=name)
    bones = {name: (p, r) for name, p, r in vmc_bone_transforms(q, body)}
    # Arms down: the upper arms turn 90 degrees about the forward axis (z), the left one
    # down from -x: +90 degrees about +z in Unity's left-handed frame, (0, 0, sin 45, cos 45).
    s = np.sqrt(0.5)
    np.testing.assert_allclose(bones["LeftUpperArm"][1], [0, 0, s, s], atol=1e-12)
    np.testing.assert_allclose(bones["RightUpperArm"][1], [0, 0, -s, s], atol=1e-12)
    np.testing.assert_allclose(bones["Hips"][1], [0, 0, 0, 1], atol=1e-12)  # facing +z
    np.testing.assert_allclose(bones["Hips"][0], 0.0)
    # Offsets are the body's: the left hip lies at -x (avatar's left), half the hip width.
    np.testing.assert_allclose(bones["LeftUpperLeg"][0], [-float(body.hip_half_width), 0, 0])
    root_p, root_r = vmc_root_transform(q)
    np.testing.assert_allclose(root_p, [-0.1, -0.2, -2.5])
    np.testing.assert_allclose(root_r, [0, 0, 0, 1])


def test_axis_conversion_of_quaternions():
    # R_unity = N R N with N = diag(-1, 1, 1) is (x, y, z, w) -> (x, -y, -z, w).
    from depthmocap.runtime.export.rotations import matrix_to_quat, rotvec_to_matrix

    r = rotvec_to_matrix(np.array([0.3, -0.5, 0.7]))
    x, y, z, w = matrix_to_quat(r)
    np.testing.assert_allclose(matrix_to_quat(UNITY_FROM_BVH @ r @ UNITY_FROM_BVH), [x, -y, -z, w])
    np.testing.assert_allclose(camera_to_unity_position([1.0, 2.0, 3.0]), [-1, -2, -3])


def test_bundle_layout():
    from depthmocap.runtime.export.osc import osc_bundle
    from depthmocap.runtime.export.vmc import vmc_bundle
    from pythonosc.osc_bundle import OscBundle

    body = BodyShape.default(torch.float64)
    q = rest_pose(1, dtype=torch.float64).numpy()[0]
    msgs = list(OscBundle(vmc_bundle(1.5, q, body).dgram))
    assert [m.address for m in msgs] == (
        ["/VMC/Ext/Root/Pos"] + ["/VMC/Ext/Bone/Pos"] * 19 + ["/VMC/Ext/OK", "/VMC/Ext/T"]
    )
    assert msgs[0].params[0] == "root" and len(msgs[0].params) == 8
    assert all(isinstance(v, float) for m in msgs[:20] for v in m.params[1:])
    assert msgs[-2].params == [1] and msgs[-1].params == [1.5]
    lost = list(OscBundle(vmc_bundle(2.0, None, body).dgram))
    assert [(m.address, m.params) for m in lost] == [("/VMC/Ext/OK", [0]), ("/VMC/Ext/T", [2.0])]
    joints = np.arange(48, dtype=float).reshape(16, 3) / 7
    joints[5, 0] = np.nan
    observed = np.arange(16) % 2 == 0
    msgs = list(OscBundle(osc_bundle(3, 0.1, "tracked", joints, observed).dgram))
    assert msgs[0].address == "/depthmocap/frame"
    assert msgs[0].params == [3, pytest.approx(0.1), "tracked"]
    assert len(msgs) == 1 + 15 and "/depthmocap/joint/r_shoulder" not in [m.address for m in msgs]
    head = msgs[1]
    assert head.address == "/depthmocap/joint/head"
    assert head.params == [np.float32(round(v, 6)) for v in joints[0]] + [1]
    assert [m.params for m in OscBundle(osc_bundle(4, 0.2, "lost", None).dgram)] == [
        [4, pytest.approx(0.2), "lost"]
    ]
