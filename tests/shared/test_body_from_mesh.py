"""Measuring the cylinder body on a mesh: golden values on a synthetic mesh of known sections."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape, cross_section_axes
from depthmocap.shared.body_from_mesh import body_from_mesh, vertex_areas
from depthmocap.shared.kinematics import forward_kinematics, named_joint_positions

RADII = np.array([0.15, 0.1])
OFFSETS = np.array([0.0, 0.04])  # 4 cm forward of the joint axis
CHEST_TILT = 0.15  # rad, the chest leaning forward on the abdomen
CLAVICLE_REST = (-0.35, 0.12)  # rad, shoulders below and in front of a horizontal clavicle


def _rings(start, axis, length, radii, offset, section, n_axial=12, n_around=48):
    """Points on an elliptic cylinder around a segment, evenly spread in angle."""
    d = [s - (s @ axis) * axis for s in section]
    d = [v / np.linalg.norm(v) for v in d]
    t = np.linspace(0.05, 0.95, n_axial)[:, None, None] * length
    th = np.linspace(0, 2 * np.pi, n_around, endpoint=False)[None, :, None]
    centre = start + offset[0] * d[0] + offset[1] * d[1]
    pts = centre + t * axis + radii[0] * np.cos(th) * d[0] + radii[1] * np.sin(th) * d[1]
    return pts.reshape(-1, 3)


@pytest.fixture(scope="module")
def mesh():
    """Every segment of the default body, chest tilted, as rings of known radii and offsets,
    plus feet."""
    body = BodyShape.default(torch.float64)
    body.chest_tilt = torch.tensor(CHEST_TILT, dtype=torch.float64)
    body.clavicle_rest = torch.tensor(CLAVICLE_REST, dtype=torch.float64)
    q = torch.zeros(1, sk.NUM_DOFS, dtype=torch.float64)  # all angles 0: the body frame
    joints = named_joint_positions(forward_kinematics(q, body))[0].numpy()
    kin = forward_kinematics(q, body)
    section = cross_section_axes()
    verts, segs = [], []
    for k in range(sk.NUM_SEGMENTS):
        start = kin.origins[0, k].numpy()
        axis = kin.rotations[0, k].numpy() @ sk.SEGMENT_AXIS[k]
        ring = _rings(start, axis, float(body.lengths[k]), RADII * (1 if k < 3 else 0.4),
                      OFFSETS * (1 if k < 3 else 0.25), section[k])  # fmt: skip
        verts.append(ring)
        segs.append(np.full(len(ring), k))
    for k in (13, 14):  # a foot: a flat box of points 20 cm forward, 6 cm tall, below the ankle
        ankle = kin.origins[0, k].numpy() + kin.rotations[0, k].numpy() @ (
            sk.SEGMENT_AXIS[k] * float(body.lengths[k])
        )
        g = np.stack(np.meshgrid(np.linspace(-0.04, 0.04, 5), np.linspace(-0.07, -0.01, 7),
                                 np.linspace(-0.05, 0.2, 26)), -1).reshape(-1, 3)  # fmt: skip
        # body frame: x left, y up, z forward
        verts.append(ankle + g)
        segs.append(np.full(len(g), k))
    return joints, np.concatenate(verts), np.concatenate(segs)


def test_sections_offsets_and_feet_are_recovered(mesh):
    joints, verts, segs = mesh
    body = body_from_mesh(joints, verts, segs)
    ref = BodyShape.default()
    assert torch.allclose(body.lengths, ref.lengths, atol=1e-5)
    # 10%-90% quantile ranges of evenly spread angles give the semi-axes to within 2%.
    np.testing.assert_allclose(body.radii[:3].numpy(), np.tile(RADII, (3, 1)), rtol=0.02)
    np.testing.assert_allclose(body.offsets[:3].numpy(), np.tile(OFFSETS, (3, 1)), atol=2e-3)
    np.testing.assert_allclose(body.radii[7:].numpy(), 0.4 * np.tile(RADII, (8, 1)), rtol=0.03)
    np.testing.assert_allclose(body.feet[:, 0].numpy(), 0.2, atol=1e-5)  # toe tip
    np.testing.assert_allclose(body.feet[:, 1].numpy(), 0.03, atol=1e-5)  # half of 6 cm
    np.testing.assert_allclose(body.extents[13:, 1].numpy(), 0.07, atol=1e-5)  # sole
    assert float(body.chest_tilt) == pytest.approx(CHEST_TILT, abs=1e-6)
    np.testing.assert_allclose(body.clavicle_rest.numpy(), CLAVICLE_REST, atol=1e-6)
    # The measured body puts the joints back where they were.
    q = torch.zeros(1, sk.NUM_DOFS)
    again = named_joint_positions(forward_kinematics(q, body))[0].numpy()
    np.testing.assert_allclose(again, joints, atol=1e-5)


def test_posed_shoulders_set_clavicle_rest_and_length(mesh):
    """Shoulders where the poser puts them at q = 0 (here: as a body whose clavicles rest
    elsewhere, 20 cm long, would) override the rest mesh's for the clavicles."""
    joints, verts, segs = mesh
    other = BodyShape.default(torch.float64)
    other.chest_tilt = torch.tensor(CHEST_TILT, dtype=torch.float64)
    other.clavicle_rest = torch.tensor([-0.2, 0.3], dtype=torch.float64)
    other.lengths[5:7] = 0.2
    at_zero = named_joint_positions(forward_kinematics(torch.zeros(1, sk.NUM_DOFS).double(), other))
    shoulders = at_zero[0, [sk.JOINT_NAMES.index("l_shoulder"), sk.JOINT_NAMES.index("r_shoulder")]]
    body = body_from_mesh(joints, verts, segs, posed_shoulders=shoulders.numpy())
    np.testing.assert_allclose(body.clavicle_rest.numpy(), [-0.2, 0.3], atol=1e-6)
    np.testing.assert_allclose(body.lengths[5:7].numpy(), 0.2, atol=1e-6)
    np.testing.assert_allclose(body.lengths[7:].numpy(), BodyShape.default().lengths[7:], atol=1e-5)


def test_area_weights_ignore_dense_inner_points(mesh):
    joints, verts, segs = mesh
    # A dense clump inside the chest (like eyes inside a head) drags unweighted quantiles.
    chest = sk.SEGMENT_NAMES.index("chest")
    centre = verts[segs == chest].mean(0)
    clump = centre + 0.005 * np.random.default_rng(0).standard_normal((3000, 3))
    v = np.concatenate([verts, clump])
    s = np.concatenate([segs, np.full(len(clump), chest)])
    # Faces: a fan over the surface points only; the clump gets (almost) no area.
    surface = np.flatnonzero(segs == chest)
    tri = np.stack([surface[:-2], surface[1:-1], surface[2:]], 1)
    faces = np.concatenate([tri, len(verts) + np.arange(3)[None]], 0)
    assert vertex_areas(v, faces)[len(verts) + 3 :].sum() == 0.0
    plain = body_from_mesh(joints, v, s)
    weighted = body_from_mesh(joints, v, s, faces)
    assert float(plain.radii[chest, 0]) < 0.8 * RADII[0]
    assert float(weighted.radii[chest, 0]) == pytest.approx(RADII[0], rel=0.1)
