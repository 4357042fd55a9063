"""Personalization (runtime.personalize, runtime-personalize): the anny shape model against
train.bodies.anny_body, the pose Jacobian against finite differences, recovery of a known shape from
noise-free views, the body measured on the mesh, and clear errors on bad inputs.

Tests needing anny skip without it; the shape fit itself is marked slow (about 5 s).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.kinematics import clamp_to_limits, forward_kinematics, pose_update
from depthmocap.shared.recording import RecordingWriter

INTR = Intrinsics.kinect_v1(320)
PHEN = {"gender": 0.8, "age": 0.8, "muscle": 0.3, "weight": 0.6, "height": 0.45,
        "proportions": 0.4}  # fmt: skip


@pytest.fixture(scope="module")
def model():
    pytest.importorskip("anny")
    from depthmocap.runtime.personalize.shape_model import load_shape_model

    return load_shape_model()


@pytest.fixture(scope="module")
def gt_body():
    pytest.importorskip("anny")
    from depthmocap.train.bodies.anny_body import make_body

    return make_body(PHEN)


def _phen(d):
    from depthmocap.runtime.personalize.shape_model import PHENOTYPE_KEYS

    return torch.tensor([[d[k] for k in PHENOTYPE_KEYS]], dtype=torch.float64)


def _views_q() -> np.ndarray:
    from depthmocap.runtime.personalize.reference_pose import calibration_pose

    q = np.stack(
        [calibration_pose("front", (0.05, 0.1, 2.7)), calibration_pose("back", (0.0, 0.1, 2.6))]
    )
    q[:, 6:] += np.random.default_rng(0).normal(0.0, np.radians(4), (2, 28))
    return clamp_to_limits(torch.tensor(q)).numpy()


# --- model ------------------------------------------------------------------------------------


def test_rest_and_pose_match_train_anny_body(model, gt_body):
    from depthmocap.train.bodies.posing import pose_anny

    rest = model.rest(_phen(PHEN))
    np.testing.assert_allclose(rest.vertices[0].numpy(), gt_body.vertices, atol=1e-9)
    np.testing.assert_allclose(rest.heads[0].numpy(), gt_body.bone_heads, atol=1e-9)
    assert (model.vertex_segment.numpy() == gt_body.vertex_segment).all()
    q = _views_q()
    corr = model.rest_corrections(rest.heads, rest.tails).expand(2, -1, -1, -1)
    verts, _ = model.pose(
        type(rest)(*(x.expand(2, -1, -1) for x in (rest.vertices, rest.heads, rest.tails))),
        model.bone_rotations(torch.tensor(q), corr),
        torch.tensor(q[:, 0:3]),
    )
    np.testing.assert_allclose(verts.numpy(), pose_anny(gt_body, q).vertices, atol=1e-9)


def test_local_basis_is_small_and_zero_means_no_change(model):
    assert 6 <= model.num_local <= 20
    assert model.local_vertices.shape[1:] == model.template.shape
    a = model.rest(_phen(PHEN)).vertices
    b = model.rest(_phen(PHEN), torch.zeros(1, model.num_local, dtype=torch.float64)).vertices
    assert torch.equal(a, b)


def test_pose_jacobian_matches_finite_differences(model):
    from depthmocap.runtime.personalize import jacobian as F

    phen = _phen(PHEN)[0]
    index = torch.arange(0, model.num_vertices, 97)
    lin = F.linear_shape(model, phen, index)
    s0 = torch.zeros(6 + model.num_local, dtype=torch.float64)
    rest = lin.rest(s0)
    corr = model.rest_corrections(rest.heads, rest.tails)
    q = torch.tensor(_views_q()[:1])
    kin = forward_kinematics(
        q, __import__("depthmocap.shared.body", fromlist=["B"]).BodyShape.default(torch.float64)
    )
    zw, zt = torch.zeros(15, 3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64)

    def f(s, w, t):
        return F.posed_perturbed(model, lin, s, w, t, kin.rotations[0], q[0, 0:3], corr)

    js, jw, jt = torch.func.jacfwd(f, argnums=(0, 1, 2))(s0, zw, zt)
    jq = F.pose_jacobian(jw, jt, kin.dof_axes[0])

    def posed(qq, s=s0):
        rot = model.bone_rotations(qq, corr)
        return model.pose(lin.rest(s), rot, qq[:, 0:3], index)[0][0]

    h = 1e-6
    for d in (0, 4, 11, 18, 24, 26, 32):  # root, lower back, shoulder, elbow, hip, knee
        dq = torch.zeros_like(q)
        dq[0, d] = h
        fd = (posed(pose_update(q, dq)) - posed(pose_update(q, -dq))) / (2 * h)
        np.testing.assert_allclose(jq[..., d].numpy(), fd.numpy(), atol=1e-6)
    ds = torch.zeros_like(s0)
    ds[8] = h
    fd = (posed(q, s0 + ds) - posed(q, s0 - ds)) / (2 * h)
    np.testing.assert_allclose(js[..., 8].numpy(), fd.numpy(), atol=1e-6)


def test_body_from_rest_matches_ground_truth_skeleton(model, gt_body):
    from depthmocap.runtime.personalize.body_from_mesh import body_from_rest
    from depthmocap.train.bodies.posing import skeleton_body_of

    body = body_from_rest(model, model.rest(_phen(PHEN)))
    ref = skeleton_body_of(gt_body)
    np.testing.assert_allclose(body.lengths.numpy(), ref.lengths.numpy(), atol=1e-5)
    assert float(body.hip_half_width) == pytest.approx(float(ref.hip_half_width), abs=1e-5)
    radii = body.radii.numpy()
    assert (radii > 0.02).all() and (radii < 0.25).all()
    assert body.extents[13, 1] > 0.03  # the foot below the ankle


def _visible_points(model, q: np.ndarray) -> list[torch.Tensor]:
    from depthmocap.runtime.personalize.correspondences import visible_vertices
    from depthmocap.runtime.personalize.shape_model import vertex_normals
    from depthmocap.train.bodies.anny_body import make_body
    from depthmocap.train.bodies.posing import pose_anny

    posed = torch.tensor(pose_anny(make_body(PHEN), q).vertices)
    normals = vertex_normals(posed, model.faces)
    return [posed[k][visible_vertices(posed[k], normals[k], INTR, 0.02)] for k in range(2)]


@pytest.mark.slow
def test_fit_recovers_known_shape_from_noise_free_views(model, gt_body):
    from depthmocap.runtime.personalize.fit import FitConfig, fit_shape

    clouds = _visible_points(model, _views_q())
    cfg = FitConfig(levels=(300, 800, 1500), iterations=(8, 5, 3), max_points=3000)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # many small ops: one thread is faster under contention
    try:
        result = fit_shape(model, clouds, INTR, cfg=cfg)
    finally:
        torch.set_num_threads(threads)
    err = np.linalg.norm(result.rest.vertices[0].numpy() - gt_body.vertices, axis=1)
    keep = gt_body.vertex_segment != sk.SEGMENT_NAMES.index("head")
    assert err[keep].mean() < 0.008
    assert (result.rms_m < 0.01).all()
    assert abs(result.phenotype[4] - PHEN["height"]) < 0.05


# --- bad inputs -------------------------------------------------------------------------------


def test_fit_needs_two_views_with_a_person():
    from depthmocap.runtime.personalize.fit import FitConfig, PersonalizeError, fit_shape

    cloud = torch.rand(2000, 3, dtype=torch.float64)
    with pytest.raises(PersonalizeError, match="two views"):
        fit_shape(None, [cloud])
    with pytest.raises(PersonalizeError, match="only 100 points"):
        fit_shape(None, [cloud, cloud[:100]])
    with pytest.raises(PersonalizeError, match="one value per level"):
        fit_shape(None, [cloud, cloud], cfg=FitConfig(levels=(100,)))


def _write(path, depth: np.ndarray) -> None:
    with RecordingWriter(path, Intrinsics.kinect_v1(160), overwrite=True) as w:
        w.write_frame(depth)


def _run(argv):
    from depthmocap.runtime.personalize_cli import main

    return main(argv)


def test_cli_one_view_only(tmp_path, capsys):
    _write(tmp_path / "front", np.zeros((120, 160), np.uint16))
    assert _run(["--input", str(tmp_path), "--output", str(tmp_path / "b.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "back" in err and "two" in err
    assert _run(["--front", str(tmp_path / "front"), "--output", str(tmp_path / "b.json")]) == 2
    assert "two views" in capsys.readouterr().err


def test_cli_no_person(tmp_path, capsys):
    for v in ("front", "back"):
        _write(tmp_path / v, np.zeros((120, 160), np.uint16))
    assert _run(["--input", str(tmp_path), "--output", str(tmp_path / "b.json")]) == 2
    err = capsys.readouterr().err
    assert "no person found" in err and "front" in err and err.count("\n") == 1


def test_cli_wrong_image_size(tmp_path, capsys):
    import cv2

    for v in ("front", "back"):
        _write(tmp_path / v, np.full((120, 160), 2000, np.uint16))
    cv2.imwrite(str(tmp_path / "back" / "depth" / "000000.png"), np.zeros((240, 320), np.uint16))
    assert _run(["--input", str(tmp_path), "--output", str(tmp_path / "b.json")]) == 2
    err = capsys.readouterr().err
    assert "320x240" in err and "160x120" in err


def test_cli_missing_anny(tmp_path, capsys, monkeypatch):
    from depthmocap.runtime.personalize import shape_model as sm

    box = np.zeros((120, 160), np.uint16)
    box[20:110, 60:100] = 2500  # a person-sized slab in front of nothing
    for v in ("front", "back"):
        _write(tmp_path / v, box)

    def no_anny(*a, **k):
        raise sm.AnnyUnavailableError(
            "the body model package 'anny' is not installed (pip install 'depthmocap[personalize]')"
        )

    monkeypatch.setattr(sm, "load_shape_model", no_anny)
    assert _run(["--input", str(tmp_path), "--output", str(tmp_path / "b.json")]) == 2
    assert "pip install 'depthmocap[personalize]'" in capsys.readouterr().err


def test_anny_users_share_these_tables():
    """Personalization and synthesis read the same anny facts (shared.anny_rig), not copies."""
    from depthmocap.runtime.personalize import shape_model
    from depthmocap.shared import anny_rig as rig
    from depthmocap.train.bodies import anny_body

    assert shape_model.SEGMENT_BONES is rig.SEGMENT_BONES
    assert shape_model.ANNY_TO_BODY is rig.ANNY_TO_BODY
    assert anny_body.BONE_SEGMENT is rig.BONE_SEGMENT
    assert anny_body.PHENOTYPE_KEYS is shape_model.PHENOTYPE_KEYS
