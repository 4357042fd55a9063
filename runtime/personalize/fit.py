"""Joint shape and pose fit to depth point clouds (Helten et al. 2013, section III-B).

One shape phi = (anny phenotype, local PCA coefficients; :mod:`.shape_model`) and one 34-DoF
skeleton pose per view are fitted jointly to K point clouds (front and back view) by
Levenberg-Marquardt in an ICP loop:

* **Visible model points**: vertices facing the camera and not hidden behind nearer model
  vertices (a z-buffer splat of the posed mesh), as Helten restricts the mesh point cloud to
  what the camera sees.
* **Correspondences both ways** by closest points (``torch.cdist``): sampled visible vertices
  to their nearest observed point, sampled observed points to their nearest visible vertex.
  Pairs farther apart than a per-level gate are outliers (segmentation leftovers).
* **Residuals** (Helten eq. 4): point-to-plane along the model vertex normal when the pair is
  within ``tau`` = 15 mm, point-to-point beyond. Helten sums unsquared distances with a
  conditioned gradient descent; we minimise the sum of squares of the same distances with
  Gauss-Newton/LM, the usual choice for ICP. Each of the (view, direction) terms is averaged
  over its pairs so that front and back, and both directions, count equally.
* **Coarse to fine**: few correspondences first, more later (``FitConfig.levels``), a
  shrinking outlier gate, and tau shrinking to Helten's 15 mm at the finest level. With
  tau = 15 mm from the start, the many point-to-point pairs of the first iterations make the
  ICP crawl (measured: 17 mm mean vertex error after 20 iterations against 2 mm with the
  schedule, same noise-free views); point-to-plane pairs let surfaces slide into place.
* **Derivatives**: autograd (forward mode, ``torch.func.jacfwd``) of the posed vertices with
  respect to the shape and to a small world rotation of every segment plus a root shift;
  the chain rule through the DoF world axes (``Kinematics.dof_axes``,
  ``DOF_AFFECTS_SEGMENT``) turns the latter into d/dq, so forward kinematics runs once per
  iteration. The root rotation is updated on SO(3) (``pose_update``). anny's phenotype ->
  blendshape-coefficient map is piecewise linear and is linearised once per iteration (central
  differences), so that the forward-mode pass only sees a linear shape basis.
* **Floor**: segmentation removes everything within a band above the floor, the soles
  included; model vertices in that band get no model-to-data pairs (else the feet are pulled
  up: measured 35 mm on the shanks).
* **Priors**: local coefficients ~ N(0, 1) (population units), and a pull of each view's
  joint angles towards the reference calibration pose: strong at the coarsest level (shape
  and root settle first; limbs otherwise fold into the trunk), weak at the finest (the user
  holds the pose only roughly). Phenotypes are kept inside ``PHENOTYPE_BOUNDS``, joint
  angles inside their limits.

Initialisation (Helten: base shape in the standard pose moved to the cloud's mean): an
average adult phenotype (``INITIAL_PHENOTYPE``) and the reference calibration pose, facing the
camera for the front view and turned by 180 degrees for the back view, with the hip centre
placed behind the cloud's centroid.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.config import field_doc
from depthmocap.shared.kinematics import clamp_to_limits, forward_kinematics, pose_update
from depthmocap.shared.least_squares import damped_solve

from .correspondences import closest_pairs, residual_jacobian, residuals, visible_vertices
from .jacobian import linear_shape, pose_jacobian, posed_perturbed
from .reference_pose import INITIAL_PHENOTYPE, initial_pose
from .shape_model import PHENOTYPE_BOUNDS, RestShape, ShapeModel, vertex_normals

__all__ = ["FitConfig", "FitResult", "PersonalizeError", "fit_shape"]


class PersonalizeError(ValueError):
    """Inputs the personalization cannot use (missing view, no person, wrong sizes...)."""


@dataclass
class FitConfig:
    """Settings of the shape fit (units: metres, radians)."""

    levels: tuple[int, ...] = field_doc(
        (300, 800, 2000), help="correspondences per direction and view at each coarse-to-fine level"
    )
    iterations: tuple[int, ...] = field_doc((10, 6, 4), help="ICP/LM iterations per level")
    gate_m: tuple[float, ...] = field_doc(
        (0.3, 0.1, 0.05), help="pairs farther apart than this are outliers, per level"
    )
    tau_m: tuple[float, ...] = field_doc(
        (0.05, 0.03, 0.015),
        help="per level: point-to-plane within, point-to-point beyond (Helten: 15 mm; wider at "
        "the coarse levels, where point-to-point pairs would slow the ICP down)",
    )
    max_points: int = field_doc(5000, help="observed points kept per view (random subset)")
    local_prior: float = field_doc(
        1e-5, help="weight of |local|^2 (population sd units) against mean squared residuals m^2"
    )
    pose_prior: tuple[float, ...] = field_doc(
        (1e-2, 1e-4, 2e-5),
        help="per level: weight of squared joint-angle deviation from the calibration pose "
        "(rad^2); strong at first so that shape and root settle before the limbs move",
    )
    lm_lambda: float = field_doc(1e-3, help="initial Levenberg-Marquardt damping (relative)")
    visibility_margin_m: float = field_doc(
        0.03, help="a vertex this far behind the nearest model surface at its pixel is hidden"
    )
    floor_margin_m: float = field_doc(
        0.03, help="model vertices this close above the floor band get no model-to-data pair"
    )
    seed: int = field_doc(0, help="seed of the point subsampling")


@dataclass
class FitResult:
    """Outcome of :func:`fit_shape`.

    Attributes:
        phenotype: (6,) anny phenotype in PHENOTYPE_KEYS order.
        local: (K,) local-change coefficients.
        q: (views, 34) skeleton pose of each view (camera frame; drives the mesh).
        rest: the fitted rest body (batch 1, float64).
        rms_m: (views,) RMS closest-point distance of observed points to the posed model.
        iterations: ICP/LM iterations run.
        seconds: wall time of the fit.
        history: per-iteration energy.
    """

    phenotype: np.ndarray
    local: np.ndarray
    q: np.ndarray
    rest: RestShape
    rms_m: np.ndarray
    iterations: int
    seconds: float
    history: list[float] = field(default_factory=list)


def _check_clouds(clouds: list[torch.Tensor]) -> None:
    if len(clouds) < 2:
        raise PersonalizeError(
            f"personalization needs two views (front and back), got {len(clouds)}"
        )
    for i, c in enumerate(clouds):
        if c.ndim != 2 or c.shape[1] != 3:
            raise PersonalizeError(f"view {i}: points must be (N, 3), got {tuple(c.shape)}")
        if len(c) < 500:
            raise PersonalizeError(f"view {i}: only {len(c)} points of a person (need >= 500)")
        if not bool(torch.isfinite(c).all()):
            raise PersonalizeError(f"view {i}: points contain non-finite values")


def fit_shape(
    model: ShapeModel,
    clouds: list[torch.Tensor],
    intrinsics: Intrinsics | None = None,
    views: tuple[str, ...] = ("front", "back"),
    cfg: FitConfig | None = None,
    initial_q: torch.Tensor | None = None,
    initial_phenotype: torch.Tensor | None = None,
    floors: list | None = None,
) -> FitResult:
    """Fit one shape and one pose per view to the person's points of each view.

    Args:
        model: the shape model.
        clouds: per view (N_k, 3) camera-frame points of the person only, metres.
        intrinsics: the camera (for the visibility z-buffer); facing test only when None.
        views: "front"/"back" per cloud (initial orientation).
        cfg: settings.
        initial_q: (K, 34) starting poses instead of :func:`initial_pose`.
        initial_phenotype: (6,) starting phenotype instead of the population average.
        floors: per view None or (normal (3,), point (3,), band): the floor plane (normal
            pointing up) and the height above it below which segmentation removed the data;
            model vertices there have nothing to match (the soles would be pulled up).
    Returns:
        :class:`FitResult`.
    """
    cfg = cfg or FitConfig()
    lengths = {len(x) for x in (cfg.levels, cfg.iterations, cfg.gate_m, cfg.tau_m, cfg.pose_prior)}
    if len(lengths) != 1:
        raise PersonalizeError(
            "levels, iterations, gate_m, tau_m and pose_prior need one value per level"
        )
    start = time.perf_counter()
    clouds = [torch.as_tensor(c, dtype=torch.float64) for c in clouds]
    _check_clouds(clouds)
    if len(views) != len(clouds):
        raise PersonalizeError(f"{len(clouds)} clouds but {len(views)} view names")
    floors = [None] * len(clouds) if floors is None else list(floors)
    if len(floors) != len(clouds):
        raise PersonalizeError(f"{len(clouds)} clouds but {len(floors)} floor entries")
    floors = [
        None if f is None else
        (torch.as_tensor(f[0], dtype=torch.float64), torch.as_tensor(f[1], dtype=torch.float64),
         float(f[2]))
        for f in floors
    ]  # fmt: skip
    gen = torch.Generator().manual_seed(cfg.seed)
    clouds = [c[torch.randperm(len(c), generator=gen)[: cfg.max_points]] for c in clouds]
    n_views, n_local = len(clouds), model.num_local
    bounds = torch.as_tensor(PHENOTYPE_BOUNDS, dtype=torch.float64)
    phen = torch.as_tensor(INITIAL_PHENOTYPE, dtype=torch.float64).clone()
    if initial_phenotype is not None:
        phen = torch.as_tensor(initial_phenotype, dtype=torch.float64).reshape(6).clone()
    local = torch.zeros(n_local, dtype=torch.float64)
    if initial_q is None:
        q = torch.stack([initial_pose(c, v) for c, v in zip(clouds, views)])
    else:
        q = torch.as_tensor(initial_q, dtype=torch.float64).reshape(n_views, sk.NUM_DOFS).clone()
    q_ref = q.clone()
    n_shape = 6 + n_local
    n_params = n_shape + n_views * sk.NUM_DOFS
    faces = model.faces
    default_body = BodyShape.default(torch.float64)  # segment rotations do not need lengths
    history: list[float] = []
    lam = cfg.lm_lambda
    iterations = 0
    angle = slice(6, sk.NUM_DOFS)

    def prior_energy(local_, q_):
        return cfg.local_prior * float((local_**2).sum()) + pose_prior * float(
            ((q_[:, angle] - q_ref[:, angle]) ** 2).sum()
        )

    schedule = zip(cfg.levels, cfg.iterations, cfg.gate_m, cfg.tau_m, cfg.pose_prior)
    for count, iters, gate, tau, pose_prior in schedule:
        for _ in range(iters):
            iterations += 1
            with torch.no_grad():
                rest = model.rest(phen[None], local[None])
                corr = model.rest_corrections(rest.heads, rest.tails)
                rot = model.bone_rotations(q, corr.expand(n_views, -1, -1, -1))
                full = RestShape(*(x.expand(n_views, -1, -1) for x in
                                   (rest.vertices, rest.heads, rest.tails)))  # fmt: skip
                posed, _ = model.pose(full, rot, q[:, 0:3])
                normals = vertex_normals(posed, faces)
            hess = torch.zeros(n_params, n_params, dtype=torch.float64)
            grad = torch.zeros(n_params, dtype=torch.float64)
            energy = 0.0
            setups = []
            for k in range(n_views):
                vis = visible_vertices(posed[k], normals[k], intrinsics, cfg.visibility_margin_m)
                observable = torch.ones_like(vis)
                if floors[k] is not None:
                    normal, point, band = floors[k]
                    observable = (posed[k] - point) @ normal > band + cfg.floor_margin_m
                active, pairs = closest_pairs(
                    posed[k], normals[k], vis, clouds[k], count, gate, tau, gen, observable
                )
                lin = linear_shape(model, phen, active)
                s0 = torch.cat([torch.zeros(6, dtype=torch.float64), local])
                qk = q[k]
                kin = forward_kinematics(qk[None], default_body)
                zero_w = torch.zeros(sk.NUM_SEGMENTS, 3, dtype=torch.float64)
                zero_t = torch.zeros(3, dtype=torch.float64)

                def f(s, w, t, lin=lin, seg_rot=kin.rotations[0], root=qk[0:3], corr=corr):
                    return posed_perturbed(model, lin, s, w, t, seg_rot, root, corr)

                js, jw, jt = torch.func.jacfwd(f, argnums=(0, 1, 2))(s0, zero_w, zero_t)
                jq = pose_jacobian(jw, jt, kin.dof_axes[0])  # (A, 3, 34)
                verts = f(s0, zero_w, zero_t)
                res = residuals(verts, pairs)
                jac = residual_jacobian(torch.cat([js, jq], -1), pairs)  # (P, 3, S + 34)
                first = n_shape + k * sk.NUM_DOFS
                cols = torch.cat([torch.arange(n_shape), first + torch.arange(sk.NUM_DOFS)])
                jw = jac * pairs.weight[:, None, None]
                hess[cols[:, None], cols[None]] += torch.einsum("pix,piy->xy", jw, jac)
                grad[cols] += torch.einsum("pix,pi->x", jw, res)
                energy += float((pairs.weight * (res**2).sum(-1)).sum())
                setups.append((lin, pairs, qk))
            # Priors: local ~ N(0, 1); joint angles near the calibration pose.
            energy += prior_energy(local, q)
            idx_local = torch.arange(6, n_shape)
            hess[idx_local, idx_local] += cfg.local_prior
            grad[idx_local] += cfg.local_prior * local
            for k in range(n_views):
                ia = n_shape + k * sk.NUM_DOFS + torch.arange(6, sk.NUM_DOFS)
                hess[ia, ia] += pose_prior
                grad[ia] += pose_prior * (q[k, angle] - q_ref[k, angle])
            history.append(energy)

            # LM step with the correspondences fixed; retry with more damping if it fails.
            diag = hess.diagonal().clamp_min(1e-12)
            for _try in range(4):
                step = -damped_solve(hess, grad, lam * diag)
                new_phen = (phen + step[:6]).clamp(bounds[:, 0], bounds[:, 1])
                new_local = local + step[6:n_shape]
                new_q = pose_update(q, step[n_shape:].reshape(n_views, sk.NUM_DOFS))
                new_q = clamp_to_limits(new_q)
                trial = _trial_energy(model, setups, new_phen, new_local, new_q, corr)
                trial += prior_energy(new_local, new_q)
                if trial <= energy:
                    phen, local, q = new_phen, new_local, new_q
                    lam = max(lam / 3.0, 1e-7)
                    break
                lam *= 8.0
    with torch.no_grad():
        rest = model.rest(phen[None], local[None])
        rms = _rms(model, rest, q, clouds)
    return FitResult(
        phenotype=phen.numpy(),
        local=local.numpy(),
        q=q.numpy(),
        rest=rest,
        rms_m=rms,
        iterations=iterations,
        seconds=time.perf_counter() - start,
        history=history,
    )


def _trial_energy(model, setups, phen, local, q, corr) -> float:
    """Data energy at new parameters with the correspondences of this iteration (exact model)."""
    total = 0.0
    with torch.no_grad():
        coeffs = model.phenotype_coefficients(phen[None])
        rest_full = model.rest_from_coefficients(coeffs, local[None])
        for k, (lin, pairs, _q) in enumerate(setups):
            active = lin.active
            rot = model.bone_rotations(q[k : k + 1], corr)
            verts, _ = model.pose(rest_full, rot, q[k : k + 1, 0:3], active)
            res = residuals(verts[0], pairs)
            total += float((pairs.weight * (res**2).sum(-1)).sum())
    return total


def _rms(model: ShapeModel, rest: RestShape, q: torch.Tensor, clouds) -> np.ndarray:
    """RMS distance of each view's observed points to the nearest posed model vertex."""
    corr = model.rest_corrections(rest.heads, rest.tails)
    out = []
    rot = model.bone_rotations(q, corr.expand(len(q), -1, -1, -1))
    both = RestShape(*(x.expand(len(q), -1, -1) for x in (rest.vertices, rest.heads, rest.tails)))
    posed, _ = model.pose(both, rot, q[:, 0:3])
    normals = vertex_normals(posed, model.faces)
    for k, cloud in enumerate(clouds):
        verts = posed[k][(normals[k] * posed[k]).sum(-1) < 0]  # facing the camera
        d = torch.cdist(cloud.float(), verts.float()).min(1).values.double()
        out.append(float(d.square().mean().sqrt()))
    return np.array(out)
