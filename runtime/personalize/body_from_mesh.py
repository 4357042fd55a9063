"""The tracker's cylinder body (:class:`shared.body.BodyShape`) measured on a fitted rest mesh.

The measurement itself is :func:`shared.body_from_mesh.body_from_mesh` (lengths, section radii
and centre offsets, extents), the same one that gives synthetic recordings their ground-truth
body; this module supplies the named joints, defined on anny's bones by the recipes of
:data:`shared.anny_rig.JOINT_RECIPES` that synthesis uses too
(``train.bodies.measurements.anatomical_joints``: head = middle of the Head bone, neck = Neck
head, spine = Spine head, shoulder/elbow/wrist = Arm/ForeArm/Hand heads, hip/knee/ankle =
UpLeg/Leg/Foot heads), so that the tracker's named joints land on the same anatomical points.
"""

from __future__ import annotations

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.anny_rig import JOINT_RECIPES
from depthmocap.shared.body import BodyShape
from depthmocap.shared.body_from_mesh import body_from_mesh

from .shape_model import RestShape, ShapeModel

__all__ = ["named_joints_from_bones", "posed_shoulders", "body_from_rest"]


def named_joints_from_bones(model: ShapeModel, rest: RestShape) -> np.ndarray:
    """(16, 3) named joints (``shared.skeleton.JOINT_NAMES`` order) of a batch-1 rest body."""
    heads, tails = rest.heads[0].detach().numpy(), rest.tails[0].detach().numpy()
    out = np.zeros((len(sk.JOINT_NAMES), 3))
    for j, name in enumerate(sk.JOINT_NAMES):
        out[j] = sum(
            w * (heads if end == "head" else tails)[model.bone_names.index(b)]
            for b, end, w in JOINT_RECIPES[name]
        )
    return out


def posed_shoulders(model: ShapeModel, rest: RestShape) -> np.ndarray:
    """(2, 3) left and right shoulder of a batch-1 rest body posed at q = 0 (arms straight
    down: the arm-chain rest corrections turn the clavicle bones, which moves the shoulders)."""
    heads, tails = rest.heads[:1].detach(), rest.tails[:1].detach()
    q0 = heads.new_zeros(1, sk.NUM_DOFS)
    rotations = model.bone_rotations(q0, model.rest_corrections(heads, tails))
    none = torch.zeros(0, dtype=torch.long)
    _, posed = model.pose(RestShape(rest.vertices[:1, :0], heads, tails), rotations,
                          heads.new_zeros(1, 3), none)  # fmt: skip
    bones = [model.bone_names.index(JOINT_RECIPES[f"{s}_shoulder"][0][0]) for s in "lr"]
    return posed[0, bones].numpy()


def body_from_rest(model: ShapeModel, rest: RestShape) -> BodyShape:
    """The tracker's body measured on a batch-1 rest body of ``model`` (module docstring)."""
    return body_from_mesh(
        named_joints_from_bones(model, rest),
        rest.vertices[0].detach().numpy(),
        model.vertex_segment.numpy(),
        model.faces.numpy(),
        posed_shoulders(model, rest),
    )
