import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions
from depthmocap.shared.procedural_motion import (
    MOTIONS,
    ground_poses,
    motion_poses,
    procedural_sequences,
    random_poses,
)
from depthmocap.train.mocap.retarget import body_from_named_joints, retarget_joints

LIMB = [i for i, n in enumerate(sk.JOINT_NAMES) if n not in ("spine", "neck")]


def joints_of(q, body):
    return named_joint_positions(
        forward_kinematics(torch.as_tensor(q), body.to(torch.float64))
    ).numpy()


def test_procedural_motions_within_limits_and_grounded():
    seqs = procedural_sequences(np.random.default_rng(0), fps=15, seconds=2)
    assert set(seqs) == set(MOTIONS)
    body = BodyShape.default(torch.float64)
    for q in seqs.values():
        assert q.shape == (30, 34) and np.isfinite(q).all()
        assert (q[:, 6:] >= sk.DOF_LIMITS[6:, 0] - 1e-9).all()
        assert (q[:, 6:] <= sk.DOF_LIMITS[6:, 1] + 1e-9).all()
        j = joints_of(q, body)
        sole = j[:, [sk.JOINT_NAMES.index("l_ankle"), sk.JOINT_NAMES.index("r_ankle")], 1].min(1)
        np.testing.assert_allclose(sole, float(body.extents[13, 1]), atol=1e-9)


def test_determinism_and_unknown_motion():
    a = motion_poses("wave", 10, 30.0, np.random.default_rng(5))
    b = motion_poses("wave", 10, 30.0, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="unknown motion 'fly'"):
        motion_poses("fly", 10, 30.0, np.random.default_rng(0))


def test_random_poses_inside_limits():
    q = random_poses(500, np.random.default_rng(1))
    assert (q[:, 6:] >= sk.DOF_LIMITS[6:, 0]).all() and (q[:, 6:] <= sk.DOF_LIMITS[6:, 1]).all()
    assert q[:, 6:].std(0).min() > 0.01  # every joint actually varies


def test_retarget_round_trip_within_2cm():
    rng = np.random.default_rng(2)
    body = BodyShape.default(torch.float64).scaled(1.07)
    q = np.concatenate([ground_poses(motion_poses(m, 12, 10.0, rng), body) for m in MOTIONS])
    source = joints_of(q, body)
    measured = body_from_named_joints(source)
    limbs = [sk.SEGMENT_NAMES.index(n) for n in ("l_thigh", "r_shank", "l_upper_arm", "r_forearm")]
    np.testing.assert_allclose(
        measured.lengths.numpy()[limbs], body.lengths.numpy()[limbs], atol=1e-4
    )
    q_fit, rms = retarget_joints(source, measured)
    err = np.linalg.norm(joints_of(q_fit, measured) - source, axis=-1)
    assert err[:, LIMB].max() < 0.02, err.max()


def test_retarget_real_hdm05_clip(shared_data):
    from depthmocap.train.mocap import read_amc, read_asf
    from depthmocap.train.mocap.retarget import clip_named_joints

    folder = shared_data / "mocap" / "hdm05" / "dev"
    asf = read_asf(folder / "HDM_mm.asf")
    amc = sorted(folder.glob("*.amc"))[0]
    clip = read_amc(amc, asf, max_frames=240).subsample(8)
    source = clip_named_joints(clip)
    body = body_from_named_joints(source)
    q, _ = retarget_joints(source, body)
    err = np.linalg.norm(joints_of(q, body) - source, axis=-1)
    assert err[:, LIMB].mean() < 0.02
