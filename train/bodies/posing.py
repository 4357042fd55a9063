"""Posing an ``anny`` mesh with a tracking-skeleton pose q, and the ground truth that goes with it.

Every anny bone takes the world rotation of the skeleton segment it belongs to. Our rest pose
has the arms hanging straight down while anny rests in an A-pose with forearms angled
forward, so arm-chain bones first get a fixed correction that turns their rest direction
onto the segment axis; trunk and leg bones keep anny's natural rest curvature.

Ground truth comes from the posed mesh itself: its anatomical joints (the points the tracker
must report) and, by IK, the q of a skeleton whose lengths are measured from that body.
"""

from __future__ import annotations

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.kinematics import forward_kinematics
from depthmocap.train.bodies.anny_body import AnnyBody, bone_segments
from depthmocap.train.bodies.measurements import anatomical_joints
from depthmocap.train.bodies.skinning import PosedBody, pose_body

__all__ = ["rest_corrections", "pose_anny", "skeleton_body_of"]

_ARM_SEGMENTS = {
    sk.SEGMENT_NAMES.index(n)
    for n in ("l_clavicle", "r_clavicle", "l_upper_arm", "r_upper_arm", "l_forearm", "r_forearm")
}


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector a onto unit vector b: (3, 3)."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def rest_corrections(body: AnnyBody) -> np.ndarray:
    """Per-bone rotation applied before the segment rotation: (n_bones, 3, 3).

    Arm-chain bones (clavicle, upper arm, forearm with hand and fingers) turn their segment's
    anny rest direction onto our segment axis; everything else is the identity.
    """
    seg_of_bone = bone_segments(body.bone_names)
    out = np.tile(np.eye(3), (body.num_bones, 1, 1))
    for k in _ARM_SEGMENTS:
        # The segment's anny direction: from its first bone's head to its last bone's tail
        # along the main chain (e.g. LeftArm head -> LeftArm tail for the upper arm).
        bones = [b for b in range(body.num_bones) if seg_of_bone[b] == k]
        main = bones[0]
        d = body.bone_tails[main] - body.bone_heads[main]
        d = d / np.linalg.norm(d)
        corr = _rotation_between(d, sk.SEGMENT_AXIS[k])
        out[bones] = corr
    return out


def pose_anny(body: AnnyBody, q: np.ndarray) -> PosedBody:
    """Pose the mesh with skeleton poses q (any frame; the hip centre goes to q's root).

    Args:
        body: rest anny body.
        q: (B, 34) poses.
    Returns:
        :class:`PosedBody` with batch B, in q's frame.
    """
    qt = torch.as_tensor(np.asarray(q), dtype=torch.float64)
    # Segment rotations do not depend on lengths; the default body is enough here.
    from depthmocap.shared.body import BodyShape

    kin = forward_kinematics(qt, BodyShape.default(torch.float64))
    seg_rot = kin.rotations.numpy()  # (B, 15, 3, 3)
    if "rest_corr" not in body._cache:
        body._cache["rest_corr"] = rest_corrections(body)
    rot = seg_rot[:, bone_segments(body.bone_names)] @ body._cache["rest_corr"]
    return pose_body(body, rot, qt[:, 0:3].numpy())


def skeleton_body_of(body: AnnyBody):
    """The tracking skeleton's :class:`BodyShape` measured on an anny body's rest mesh: lengths
    between its anatomical joints, section radii, centre offsets and extents from its vertices,
    clavicles from the shoulders as :func:`pose_anny` puts them at q = 0
    (:func:`shared.body_from_mesh.body_from_mesh`)."""
    from depthmocap.shared.body_from_mesh import body_from_mesh

    at_zero = anatomical_joints(body, pose_anny(body, np.zeros((1, sk.NUM_DOFS))))[0]
    shoulders = at_zero[[sk.JOINT_NAMES.index("l_shoulder"), sk.JOINT_NAMES.index("r_shoulder")]]
    return body_from_mesh(
        anatomical_joints(body), body.vertices, body.vertex_segment, body.faces, shoulders
    )
