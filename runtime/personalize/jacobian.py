"""The posed model linearised for the shape fit (:mod:`.fit`): the rest body linear in the shape
parameters, and the derivatives of the posed vertices by shape and by joint angles (forward-mode
autograd through small segment rotations, then the chain rule through the DoF world axes)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.so3 import skew

from .shape_model import RestShape, ShapeModel

__all__ = ["LinearShape", "linear_shape", "pose_jacobian", "posed_perturbed"]


@dataclass
class LinearShape:
    """Rest body linearised in s = (phenotype delta, local coefficients) at some vertices."""

    active: torch.Tensor  # (N,) the vertex ids
    vertices: torch.Tensor  # (N, 3) at s = 0 (current phenotype, no local change)
    heads: torch.Tensor  # (nb, 3)
    tails: torch.Tensor
    basis_vertices: torch.Tensor  # (S, N, 3)
    basis_heads: torch.Tensor  # (S, nb, 3)
    basis_tails: torch.Tensor
    hips: tuple[int, int]

    def rest(self, s: torch.Tensor) -> RestShape:
        """s (S,) -> hip-centred rest body with batch 1 (differentiable)."""

        def lin(base, basis):
            return base + torch.einsum("s,spi->pi", s, basis)

        v, h, t = (lin(self.vertices, self.basis_vertices), lin(self.heads, self.basis_heads),
                   lin(self.tails, self.basis_tails))  # fmt: skip
        hip = h[list(self.hips)].mean(0)
        return RestShape((v - hip)[None], (h - hip)[None], (t - hip)[None])


def linear_shape(model: ShapeModel, phen: torch.Tensor, index: torch.Tensor) -> LinearShape:
    """Linearise the phenotype part at ``phen`` (6,); local coefficients enter linearly, so
    ``rest(s)`` with s = (dphen, local) reproduces the model to first order in dphen."""
    # The map is piecewise linear: central differences are exact inside a piece and average
    # the two slopes at a kink (6 batched evaluations instead of C reverse passes).
    h = 1e-4
    probes = torch.cat([phen[None], phen + h * torch.eye(6, dtype=phen.dtype),
                        phen - h * torch.eye(6, dtype=phen.dtype)])  # fmt: skip
    with torch.no_grad():
        c = model.phenotype_coefficients(probes)
    coeffs = c[0]  # (C,)
    jac = ((c[1:7] - c[7:13]) / (2 * h)).T  # (C, 6)

    def part(template, bs, local_bs):
        base = template + torch.einsum("c,cpi->pi", coeffs, bs)
        return base, torch.cat([torch.einsum("cd,cpi->dpi", jac, bs), local_bs], 0)

    v, bv = part(model.template[index], model.blendshapes[:, index], model.local_vertices[:, index])
    h, bh = part(model.template_heads, model.heads_blendshapes, model.local_heads)
    t, bt = part(model.template_tails, model.tails_blendshapes, model.local_tails)
    return LinearShape(index, v, h, t, bv, bh, bt, model._hips)


def posed_perturbed(
    model: ShapeModel,
    lin: LinearShape,
    s: torch.Tensor,
    omega: torch.Tensor,
    shift: torch.Tensor,
    seg_rot: torch.Tensor,
    root: torch.Tensor,
    corr: torch.Tensor,
) -> torch.Tensor:
    """Posed vertices (N, 3) of the linearised shape s with every segment rotation turned by
    a small world rotation omega (15, 3) (first order) and the root moved by shift (3,).

    Its derivatives at omega = shift = 0 give the pose Jacobian by the chain rule: a joint
    angle turns every segment it affects about its world axis (:func:`pose_jacobian`), so
    forward kinematics runs once per iteration instead of once per derivative direction."""
    rot = seg_rot + skew(omega) @ seg_rot
    bone_rot = rot[model.bone_segment] @ corr[0]
    verts, _ = model.pose(lin.rest(s), bone_rot[None], (root + shift)[None], lin.active)
    return verts[0]


def pose_jacobian(j_omega: torch.Tensor, j_shift: torch.Tensor, axes: torch.Tensor) -> torch.Tensor:
    """d posed / d q (A, 3, 34) from the derivatives by segment rotations (A, 3, 15, 3) and
    root shift (A, 3, 3); axes: (34, 3) world DoF axes (root rotation: left-multiplied, as
    :func:`shared.kinematics.pose_update` applies it)."""
    affects = torch.as_tensor(sk.DOF_AFFECTS_SEGMENT, dtype=j_omega.dtype)  # (15, 34)
    j_q = torch.einsum("aiks,kd,ds->aid", j_omega, affects, axes)
    return torch.cat([j_shift, j_q[..., 3:]], -1)
