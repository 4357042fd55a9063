import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions

J = {n: i for i, n in enumerate(sk.JOINT_NAMES)}


@pytest.fixture(scope="module")
def body():
    pytest.importorskip("anny")
    from depthmocap.train.bodies.anny_body import make_body

    return make_body(
        {
            "gender": 0.0,
            "age": 0.75,
            "muscle": 0.5,
            "weight": 0.5,
            "height": 0.4,
            "proportions": 0.5,
        }
    )


@pytest.mark.slow
def test_rest_q_hangs_arms_down(body):
    from depthmocap.train.bodies.measurements import anatomical_joints
    from depthmocap.train.bodies.posing import pose_anny

    q = np.zeros((1, 34))
    j = anatomical_joints(body, pose_anny(body, q))[0]
    for s in "lr":
        arm = j[J[f"{s}_wrist"]] - j[J[f"{s}_shoulder"]]
        # A-pose corrected: the whole arm points straight down (our rest pose).
        assert arm[1] < 0 and np.hypot(arm[0], arm[2]) < 0.02 * np.linalg.norm(arm)
    np.testing.assert_allclose(j[J["pelvis"]], 0.0, atol=1e-9)


@pytest.mark.slow
def test_posed_mesh_follows_skeleton_pose(body):
    from depthmocap.shared.procedural_motion import motion_poses
    from depthmocap.train.bodies.measurements import anatomical_joints
    from depthmocap.train.bodies.posing import pose_anny, skeleton_body_of
    from depthmocap.train.mocap.retarget import retarget_joints

    sb = skeleton_body_of(body)
    q = motion_poses("wave", 6, 5.0, np.random.default_rng(0))
    j = anatomical_joints(body, pose_anny(body, q))
    q_fit, _ = retarget_joints(j, sb)
    fit = named_joint_positions(forward_kinematics(torch.as_tensor(q_fit), sb.to(torch.float64)))
    err = np.linalg.norm(fit.numpy() - j, axis=-1)
    limbs = [J[n] for n in ("l_elbow", "r_elbow", "l_wrist", "r_wrist", "l_knee", "r_knee")]
    # anny's rest curvature differs from straight cylinders: centimetres, not millimetres.
    assert err[:, limbs].mean() < 0.03
