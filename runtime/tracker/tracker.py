"""The MAP tracker of Wei section 3.1: Gauss-Newton on eq. 8 from the previous pose.

Per frame: cut the observation to a window around the person and pool it to the working
resolution (once; by default the factor follows the person's size, see
:class:`TrackerConfig`), then iterate: ray-cast the model at the current pose in that window
(depth, silhouette, segment; normals at the depth term's pixels), classify pixels
(G, B1, B2, B3), build the linearized rows of the depth, extra depth and silhouette terms with
analytic Jacobians, add the constant-acceleration prior, solve the 34x34 normal equations in
float64 with a little damping and joint limits as an active set, shorten the step to at most
``cfg.max_step_rad`` per joint angle, and update q (root rotation on SO(3)); stop after
``cfg.iterations`` or when the update, or the energy a step removes, is small. The failure
signals of :mod:`runtime.tracker.signals` come from the last iteration's rendering (one step
before the result) rather than a ray-cast at the result, which saves a sixth of the frame
time; only a frame with no iteration at all is ray-cast once more.

Everything is batch-first (B poses on B frames) and follows the device/dtype of the tracker;
:class:`Tracker` is the single-stream wrapper that takes (H, W) frames.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
from depthmocap.runtime.raycast import BodyRender, SegmentGeometry, render_body, segment_geometry
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.compiled import compiled_float32
from depthmocap.shared.kinematics import Kinematics
from depthmocap.shared.labels import PART_SEGMENT

from .collision_term import collision_rows
from .config import TrackerConfig, TrackerConfigError
from .depth_term import depth_rows
from .extra_depth_term import MAX_CANDIDATES, ExtraResult, extra_rows, observed_candidates
from .gauss_newton import cat_rows, gauss_newton_step, normal_equations
from .joint_support import observed_joints
from .label_term import label_rows
from .observation import Observation, automatic_factor, observe, person_window
from .prior_term import predict_pose, prior_weights
from .regions import Regions, classify
from .shoulder_branch import align_branch, move_to_roomier_branch
from .signals import FitSignals, FrameSignals, depth_error_cm, frame_signals, overlap
from .silhouette_term import silhouette_rows

__all__ = [
    "TrackerError",
    "TrackResult",
    "FrameFit",
    "fit_frames",
    "expand_observation",
    "Tracker",
    "track_sequence",
]


# Constants of the tracker that were settings once (issue 34): the values they were tuned to,
# read at call time (tests patch them here).

# The tracker works in a window around the observed silhouette's bounding box, grown on every
# side by this fraction of the box's larger side (and by at least SILHOUETTE_MAX_PX + 2
# working pixels), so a frame's cost follows the person, not the image; model parts outside
# the window are not seen, and the margin leaves room for a model that sticks out (on
# rendered sequences the results equal the whole image's). Negative: the whole image.
CROP_MARGIN = 0.25
# The observed silhouette's distance transform is truncated here (working pixels), which caps
# the silhouette term's residual for a boundary pixel far outside; the window reaches at least
# this far (plus 2 pixels) past the silhouette so that the transform in it is the whole
# image's.
SILHOUETTE_MAX_PX = 10.0
# The update test: a frame has converged, and stops iterating, when every joint-angle and
# root-rotation update is below STOP_ANGLE_RAD (rad) and every root-translation update below
# STOP_TRANSLATION_M (m): further steps would move the model by a millimetre or two.
STOP_ANGLE_RAD = 2e-3
STOP_TRANSLATION_M = 1e-3
# ... or, from the second step on, when a step's predicted energy decrease dq^T H dq falls
# below this (noise scales squared; 0: off). On noisy data the angles the data hardly see keep
# moving by degrees per iteration, so the update test alone never stops; on the dev recordings
# the first step removes ~20,000, the fifth ~250.
STOP_DECREASE = 800.0
# The prior pulls towards q_prev + gain (q_prev - q_prev2): 1 is Wei's constant velocity (the
# prior penalizes acceleration), 0 would be the previous pose.
PRIOR_VELOCITY_GAIN = 1.0
# Before each frame a shoulder pinned at its limits moves to its other Euler form when that
# turns the upper arm by less than this (rad; 0: never): otherwise an arm that passed the
# gimbal lock in the wrong form stays stuck at the limits (runtime.tracker.shoulder_branch).
SHOULDER_BRANCH_TURN_RAD = 0.7
# On the CPU in float32 each Gauss-Newton iteration runs as one compiled call
# (runtime.tracker.iteration_kernel): the same poses as term by term, without the calls'
# glue. False: term by term everywhere (the reference the tests compare it with).
FUSED_ITERATION = True


class TrackerError(ValueError):
    """Input the tracker cannot work with (shapes, intrinsics)."""


@dataclass
class TrackResult:
    """Result of one tracked frame.

    Attributes:
        q: (34,) estimated pose in camera frame.
        depth_error_cm: mean depth / extra-depth residual (cm), Wei's epsilon1 signal.
        overlap: |R and O| / |R or O| of rendered and observed silhouettes, epsilon2 signal.
        surface_error_q97_mm: 97% quantile of observed points' distance to the model (mm).
        iterations: Gauss-Newton iterations run.
        converged: the last update was below the stop thresholds.
        limb_visibility: (4,) visible fraction of the left/right arm and leg in the model's
            rendering (:func:`runtime.tracker.signals.limb_visibility`); None if unknown.
        observed: (J,) bool, the named joints the depth image confirms
            (:mod:`runtime.tracker.joint_support`; the others are inferred); None if unknown.
        joint_support_cm2: (J,) the confirmed area behind ``observed``; None if unknown.
    """

    q: torch.Tensor
    depth_error_cm: float
    overlap: float
    surface_error_q97_mm: float
    iterations: int
    converged: bool
    limb_visibility: torch.Tensor | None = None
    observed: torch.Tensor | None = None
    joint_support_cm2: torch.Tensor | None = None

    @property
    def signals(self) -> FitSignals:
        """The three failure signals as one typed value."""
        return FitSignals(self.depth_error_cm, self.overlap, self.surface_error_q97_mm)


@dataclass
class FrameFit:
    """Batched result of :func:`fit_frames`.

    Attributes:
        q: (B, 34); signals: per-pose signals at q (None when not asked for); iterations:
        iterations the batch ran; converged: (B,) bool; steps: (B,) int64 Gauss-Newton steps
        each pose took (a pose that has converged stops moving while the others iterate
        on); overlap: (B,) the silhouette overlap at q (the signals' own).
    """

    q: torch.Tensor
    signals: FrameSignals | None
    iterations: int
    converged: torch.Tensor
    steps: torch.Tensor
    overlap: torch.Tensor


def _small(dq: torch.Tensor) -> torch.Tensor:
    return (dq[:, :3].abs().amax(1) < STOP_TRANSLATION_M) & (
        dq[:, 3:].abs().amax(1) < STOP_ANGLE_RAD
    )


def fit_frames(
    obs: Observation,
    q_prev: torch.Tensor,
    q_prev2: torch.Tensor | None,
    body: BodyShape,
    cfg: TrackerConfig,
    geom: SegmentGeometry | None = None,
    velocity_scale: float = 1.0,
    signals: bool = True,
) -> FrameFit:
    """Gauss-Newton fit of B poses to B observed frames.

    Each pose is fitted as it would be alone: pixel sampling caps and closest points are per
    pose, and a pose whose stop test passes keeps its result while the others iterate on, its
    rendering held at the pose of its last step, so that its failure signals are those it
    would have had alone. B starts on one frame (:func:`expand_observation`) thus cost one
    batched fit instead of B, with the same results up to rounding (a rounding difference
    can move a pixel where two capsules meet to the other segment, which moves a badly
    constrained angle by a few hundredths of a radian).

    Args:
        obs: working-resolution observation (batch B).
        q_prev, q_prev2: (B, 34) poses of the two previous frames (q_prev2 may be None: the
            prior then predicts no motion).
        geom: ``segment_geometry(body, q_prev)``, when the caller keeps it (it depends only
            on the body; a tracker computes it once); None: computed here.
        velocity_scale: the prior predicts ``q_prev`` plus this times the last step's
            motion (``q_prev - q_prev2``): the frames since ``q_prev`` over those between
            the two (1: consecutive frames, Wei's prior).
        signals: compute the failure signals; False: only the overlaps (the size search
            reads nothing else), ``FrameFit.signals`` None.
    """
    B = q_prev.shape[0]
    if SHOULDER_BRANCH_TURN_RAD > 0:
        q_prev = move_to_roomier_branch(q_prev, SHOULDER_BRANCH_TURN_RAD)
        q_prev2 = None if q_prev2 is None else align_branch(q_prev2, q_prev)
    q_pred = predict_pose(q_prev, q_prev2, PRIOR_VELOCITY_GAIN * velocity_scale)
    q = q_prev.clone()  # Wei starts each frame from the previous pose
    observed = observed_candidates(obs, MAX_CANDIDATES) if cfg.use_extra_depth else None
    converged = torch.zeros(B, dtype=torch.bool, device=q.device)
    steps = torch.zeros(B, dtype=torch.long, device=q.device)
    if geom is None:
        geom = segment_geometry(body, q)
    iterations = 0
    last = None
    q_cast = q  # the poses rendered: q, but a converged pose's last step's start
    fused = _fused_iteration(obs, q, body, geom)
    arrays = None if fused is None else _fit_arrays(fused, obs, observed, body, geom, B, cfg)
    for _ in range(cfg.iterations):
        if arrays is not None:  # the same iteration as below, in one compiled call
            q_step, dq, decrease, render, regions, extra = _fused_step(
                fused, arrays, q_cast, q_pred, body, geom, obs, cfg
            )
        else:
            q_step, dq, decrease, render, regions, extra = _iteration_by_terms(
                q_cast, q_pred, observed, body, geom, obs, cfg
            )
        q = torch.where(converged[:, None], q, q_step)
        iterations += 1
        steps += (~converged).long()
        small = _small(dq)
        if iterations > 1:
            # Not after the first step: the failure signals come from this iteration's
            # rendering, which then would still show the previous frame's pose.
            small = small | (decrease < STOP_DECREASE)
        q_cast = torch.where((converged | small)[:, None], q_cast, q)
        converged = converged | small
        last = (render, regions, extra)
        if bool(converged.all()):
            break
    if last is None:  # no iteration: ray-cast the start pose for the signals
        render = render_body(q, body, obs.intr, geom=geom, details=False)
        regions = classify(render, obs, cfg.depth_gate_m, cfg.occlusion_handling)
        extra = None
    else:
        render, regions, extra = last
    if not signals:
        iou = overlap(render.mask, obs.silhouette)
        return FrameFit(q, None, iterations, converged, steps, iou)
    if extra is None:
        cands = observed if observed is not None else observed_candidates(obs, MAX_CANDIDATES)
        extra = extra_rows(render, obs, regions, cands, cfg, B)
    if arrays is not None and (B == 1 or obs.valid.stride(0) == 0):  # one observed frame
        found = _fused_signals(render, obs, regions, extra, body, cfg)
    else:
        found = frame_signals(render, obs, regions, extra, body, cfg)
    return FrameFit(q, found, iterations, converged, steps, found.overlap)


def _iteration_by_terms(
    q_cast: torch.Tensor,
    q_pred: torch.Tensor,
    observed,
    body: BodyShape,
    geom: SegmentGeometry,
    obs: Observation,
    cfg: TrackerConfig,
):
    """One Gauss-Newton iteration at ``q_cast`` (B, 34), term by term (any device, dtype,
    autograd): the new poses, the steps, their predicted decreases, and the rendering, pixel
    classes and extra depth term it was linearized with."""
    B = q_cast.shape[0]
    render = render_body(q_cast, body, obs.intr, geom=geom, details=False)
    regions = classify(render, obs, cfg.depth_gate_m, cfg.occlusion_handling)
    extra = extra_rows(render, obs, regions, observed, cfg, B) if observed is not None else None
    rows = []
    if cfg.use_depth:
        rows.append(depth_rows(render, obs, regions, cfg))
    if extra is not None:
        rows.append(extra.rows)
    if cfg.use_silhouette:
        rows.append(silhouette_rows(render, obs, cfg))
    if cfg.use_labels and obs.labels is not None:
        rows.append(label_rows(render.kin, geom, obs, cfg))
    if rows:
        hess, grad = normal_equations(render.kin, cat_rows(rows), B)
    else:
        hess = q_cast.new_zeros(B, sk.NUM_DOFS, sk.NUM_DOFS, dtype=torch.float64)
        grad = q_cast.new_zeros(B, sk.NUM_DOFS, dtype=torch.float64)
    if cfg.use_collision:
        contact, columns = collision_rows(
            render.kin, geom, cfg.leg_collision, cfg.leg_collision_tolerance_m
        )
        h, g = normal_equations(render.kin, contact, B, columns)
        hess, grad = hess + h, grad + g
    if cfg.pose_prior_weight > 0:
        h, g = _pose_prior_rows(q_cast, cfg)
        hess, grad = hess + h, grad + g
    q_step, dq, decrease = gauss_newton_step(
        hess, grad, q_cast, q_pred if cfg.use_prior else None, cfg.damping,
        cfg.max_step_rad, cfg.sigma_prior_rad, cfg.sigma_prior_m,
    )  # fmt: skip
    return q_step, dq, decrease, render, regions, extra


def _pose_prior_rows(q: torch.Tensor, cfg: TrackerConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """The learned pose prior's normal equations at ``q`` (B, 34)."""
    from .pose_prior_term import pose_prior_system, tracker_pose_prior

    return pose_prior_system(q, *tracker_pose_prior(cfg.pose_prior_model, q), cfg.pose_prior_weight)


def _fused_iteration(obs: Observation, q: torch.Tensor, body: BodyShape, geom: SegmentGeometry):
    """:mod:`runtime.tracker.iteration_kernel` where it reproduces the term-by-term iteration
    to the bit (CPU float32 without autograd, numba installed), else None."""
    if not FUSED_ITERATION:
        return None
    tensors = [q, obs.depth, obs.points, obs.distance, geom.basis, geom.scale, geom.span]
    if torch.is_grad_enabled():
        params = (body.lengths, body.hip_half_width, body.chest_tilt, body.clavicle_rest)
        if any(t.requires_grad for t in (*tensors, *params)):
            return None
    return compiled_float32("depthmocap.runtime.tracker.iteration_kernel", *tensors)


def _fit_arrays(fused, obs: Observation, observed, body, geom, B: int, cfg: TrackerConfig):
    """The fused iteration's per-fit arrays, with the terms' constants as they are now (tests
    patch them in their modules)."""
    from depthmocap.runtime import capsule_pixels

    from . import collision_term, depth_term, extra_depth_term, label_term, silhouette_term

    e = extra_depth_term
    sampling = {
        "extra_margin": e.EXTRA_MARGIN_PX,
        "extra_half": max(1, e.MAX_EXTRA_POINTS // 2),
        "max_candidates": e.MAX_CANDIDATES,
        "max_depth_pixels": depth_term.MAX_DEPTH_PIXELS,
        "max_silhouette_pixels": silhouette_term.MAX_SILHOUETTE_PIXELS,
        "max_label_pixels": label_term.MAX_LABEL_PIXELS,
        "extra_max_distance": e.EXTRA_MAX_DISTANCE_M,
        "sigma_torso": e.SIGMA_EXTRA_TORSO_M,
        "min_cosine": depth_term.MIN_COSINE,
        "deadzone": silhouette_term.SILHOUETTE_DEADZONE_PX,
        "label_gate": label_term.LABEL_GATE_M,
        "near": capsule_pixels.NEAR,
        "collision": (  # each sample's tolerance, then the rows' noise scale
            collision_term.sample_tolerances(
                collision_term.collision_samples(cfg.leg_collision),
                cfg.leg_collision_tolerance_m,
            ),
            collision_term.SIGMA_COLLISION_M,
        ),
    }
    labels_on = cfg.use_labels and obs.labels is not None
    return fused.fit_arrays(obs, observed, body, geom, B, cfg, labels_on, sampling)


def _fused_step(fused, arrays, q_cast, q_pred, body, geom, obs, cfg):
    """:func:`_iteration_by_terms` through the compiled iteration (the same results)."""
    w = prior_weights(q_cast[:1], cfg.sigma_prior_rad, cfg.sigma_prior_m)[0]
    pose_prior = _pose_prior_rows(q_cast, cfg) if cfg.pose_prior_weight > 0 else None
    out = fused.iteration_cpu(
        arrays, q_cast, q_pred if cfg.use_prior else None, w * w, cfg.damping,
        cfg.max_step_rad, obs.intr.height, obs.intr.width, pose_prior,
    )  # fmt: skip
    lengths = body.lengths.expand(q_cast.shape[0], sk.NUM_SEGMENTS)
    kin = Kinematics(out["rotations"], out["origins"], out["dof_axes"], out["dof_origins"], lengths)
    rot, origin = out["rot"], out["origin"]
    geom.__dict__["_frames_of"] = (kin, (rot, origin))  # SegmentGeometry.frames' cache
    segment = out["segment"]
    render = BodyRender(
        out["depth"], segment >= 0, segment, None, None, kin, out["primitive"], geom, rot, origin
    )
    regions = Regions(*out["classes"])
    extra = ExtraResult(None, out["error_sum"], out["count"]) if arrays.flags[1] else None
    return out["q"], out["dq"], out["decrease"], render, regions, extra


def _fused_signals(render, obs, regions, extra, body, cfg) -> FrameSignals:
    """:func:`~runtime.tracker.signals.frame_signals` with the surface error, limb visibility
    and joint support in one compiled call (:mod:`runtime.tracker.signals_kernel`; the same
    values)."""
    from . import signals_kernel

    B = render.depth.shape[0]
    radii = body.radii.to(render.depth).expand(B, sk.NUM_SEGMENTS, 2)
    surface, visibility, support = signals_kernel.fit_signals(render, regions, obs, radii)
    return FrameSignals(
        depth_error_cm(regions, extra, cfg),
        overlap(render.mask, obs.silhouette),
        surface,
        visibility,
        support,
    )


def expand_observation(obs: Observation, size: int) -> Observation:
    """A batch-1 observation as a batch of ``size`` views of it (no copies), for fitting one
    frame from several starts in one :func:`fit_frames` call."""
    if obs.depth.shape[0] != 1:
        raise TrackerError(f"expand_observation needs a batch of 1, got {obs.depth.shape[0]}")
    fields = {f.name: getattr(obs, f.name) for f in dataclasses.fields(obs) if f.name != "intr"}
    views = {k: None if v is None else v.expand(size, *v.shape[1:]) for k, v in fields.items()}
    return Observation(obs.intr, **views)


class Tracker:
    """Frame-to-frame tracker of one depth stream.

    Args:
        body: the cylinder body model (from calibration or a body file).
        intr: intrinsics of the stream (full resolution); the tracker works at
            ``intr / cfg.downsample`` (or the automatic factor) in a window around the person.
        cfg: settings; defaults if None.
        device: where to compute (default: CPU); inputs are moved there.
        dtype: float dtype of the computation (normal equations are always float64).
    """

    def __init__(
        self,
        body: BodyShape,
        intr: Intrinsics,
        cfg: TrackerConfig | None = None,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        intr.validate()
        # The settings were checked when the config was made (TrackerConfig.__post_init__).
        self.cfg = TrackerConfig() if cfg is None else cfg
        self.intr = intr
        self.device = torch.device("cpu") if device is None else torch.device(device)
        self.dtype = dtype
        self.body = body.to(dtype=dtype, device=self.device)
        # The capsules' shape depends on the body alone: made once, not per fit.
        self.geometry = segment_geometry(self.body, self.body.lengths)
        if self.cfg.pose_prior_weight > 0:  # a bad prior file fails here, not mid-stream
            from depthmocap.shared.pose_prior import PosePriorError

            from .pose_prior_term import tracker_pose_prior

            try:
                tracker_pose_prior(self.cfg.pose_prior_model, self.geometry.basis)
            except PosePriorError as err:
                raise TrackerConfigError(f"pose_prior_model: {err}") from None

    def observe(
        self,
        depth_m: torch.Tensor,
        mask: torch.Tensor,
        labels: torch.Tensor | None = None,
        label_confidence: torch.Tensor | None = None,
    ) -> Observation:
        """Working-resolution observation of one frame (H, W) or a batch (B, H, W).

        ``labels``: the forest's part labels (``shared.labels`` classes, 0 = background) of
        the same shape, for the label term (kept only with ``cfg.use_labels``).
        ``label_confidence``: the same shape, each label's posterior; with
        ``cfg.label_min_posterior`` the label term skips the labels below it (None: it reads
        all; the observed-joint support always reads all).
        """
        if depth_m.shape[-2:] != (self.intr.height, self.intr.width):
            raise TrackerError(
                f"depth is {tuple(depth_m.shape[-2:])} (H, W), the tracker's intrinsics are "
                f"{self.intr.height}x{self.intr.width}"
            )
        if mask.shape != depth_m.shape:
            raise TrackerError(f"mask {tuple(mask.shape)} does not match depth {depth_m.shape}")
        depth = depth_m.to(device=self.device, dtype=self.dtype)
        mask = mask.to(device=self.device, dtype=torch.bool)
        segments = sure = None
        if labels is not None and self.cfg.use_labels:
            if labels.shape != depth_m.shape:
                raise TrackerError(f"labels {tuple(labels.shape)} do not match depth {depth.shape}")
            table = torch.as_tensor(PART_SEGMENT, device=self.device)
            labels = labels.to(device=self.device, dtype=torch.long)
            if labels.numel() and not (0 <= int(labels.min()) <= int(labels.max()) < len(table)):
                raise TrackerError(f"labels must be part classes in [0, {len(table) - 1}]")
            segments = table[labels]
            segments = segments[None] if segments.dim() == 2 else segments
            gate = self.cfg.label_min_posterior
            if label_confidence is not None and gate > 0:
                if label_confidence.shape != labels.shape:
                    raise TrackerError(
                        f"label confidence {tuple(label_confidence.shape)} does not match the "
                        f"labels {tuple(labels.shape)}"
                    )
                sure = label_confidence.to(device=self.device) >= gate
                sure = sure[None] if sure.dim() == 2 else sure
        if depth.dim() == 2:
            depth, mask = depth[None], mask[None]
        cfg = self.cfg
        factor = cfg.downsample or automatic_factor(mask, cfg.person_pixels)
        window = None
        if CROP_MARGIN >= 0:
            margin_px = int(SILHOUETTE_MAX_PX) + 2
            window = person_window(mask, factor, CROP_MARGIN, margin_px)
        return observe(depth, mask, self.intr, factor, SILHOUETTE_MAX_PX, window, segments, sure)

    def step(
        self,
        depth_m: torch.Tensor,
        mask: torch.Tensor,
        q_prev: torch.Tensor,
        q_prev2: torch.Tensor | None = None,
        labels: torch.Tensor | None = None,
    ) -> TrackResult:
        """Track one frame.

        Args:
            depth_m: (H, W) depth in metres at the stream's resolution, 0 = no reading.
            mask: (H, W) bool observed person silhouette (from the caller's segmentation).
            q_prev: (34,) pose of the previous frame; q_prev2: (34,) the one before, or None.
            labels: (H, W) forest part labels for the label term (``cfg.use_labels``), or
                None (the term is then skipped).
        Returns:
            :class:`TrackResult` (q on the tracker's device).
        """
        if depth_m.dim() != 2:
            raise TrackerError(f"depth must be (H, W), got {tuple(depth_m.shape)}")
        return self.fit(self.observe(depth_m, mask, labels), q_prev, q_prev2)

    def fit(
        self,
        obs: Observation,
        q_prev: torch.Tensor,
        q_prev2: torch.Tensor | None = None,
        iterations: int | None = None,
        velocity_scale: float = 1.0,
    ) -> TrackResult:
        """Fit one frame's observation (from :meth:`observe`, batch 1) from ``q_prev`` (34,)
        and ``q_prev2`` (34,) or None, with at most ``iterations`` Gauss-Newton steps
        (default: the config's), the prior predicting ``velocity_scale`` times the last
        step's motion ahead (:func:`fit_frames`). The frame's refits share one observation
        this way."""
        for name, q in (("q_prev", q_prev), ("q_prev2", q_prev2)):
            if q is not None and tuple(q.shape) != (sk.NUM_DOFS,):
                raise TrackerError(f"{name} must have shape ({sk.NUM_DOFS},), got {q.shape}")
        cfg = (
            self.cfg if iterations is None else dataclasses.replace(self.cfg, iterations=iterations)
        )
        qp = q_prev.to(device=self.device, dtype=self.dtype)[None]
        qp2 = None if q_prev2 is None else q_prev2.to(device=self.device, dtype=self.dtype)[None]
        fit = fit_frames(obs, qp, qp2, self.body, cfg, self.geometry, velocity_scale)
        return self._result(fit, 0, _host_scalars(fit))

    def fit_starts(
        self, obs: Observation, starts: torch.Tensor, iterations: int | None = None
    ) -> list[TrackResult]:
        """Fit one frame's observation (batch 1) from each of the K ``starts`` (K, 34), with
        no motion predicted (as :meth:`fit` without ``q_prev2``), in one batched fit: the
        same results as K calls of :meth:`fit` at a fraction of their cost (the refits of
        the arm search and the detector's refinement). A tracker of a batch of K bodies
        fits start k with body k (the size search's candidates)."""
        fit = self._fit_batch(obs, starts, iterations, signals=True)
        if fit is None:
            return []
        host = _host_scalars(fit)
        return [self._result(fit, k, host) for k in range(starts.shape[0])]

    def fit_overlaps(
        self, obs: Observation, starts: torch.Tensor, iterations: int | None = None
    ) -> torch.Tensor:
        """The silhouette overlaps (K,) of :meth:`fit_starts`' results, without their other
        signals (the size search's refits read nothing else)."""
        fit = self._fit_batch(obs, starts, iterations, signals=False)
        return torch.zeros(0, dtype=torch.float64) if fit is None else fit.overlap.cpu()

    def _fit_batch(
        self, obs: Observation, starts: torch.Tensor, iterations: int | None, signals: bool
    ) -> FrameFit | None:
        """The batched fit of :meth:`fit_starts` (None for no starts)."""
        if starts.dim() != 2 or starts.shape[1] != sk.NUM_DOFS:
            raise TrackerError(f"starts must be (K, {sk.NUM_DOFS}), got {tuple(starts.shape)}")
        K = starts.shape[0]
        if K == 0:
            return None
        cfg = (
            self.cfg if iterations is None else dataclasses.replace(self.cfg, iterations=iterations)
        )
        q0 = starts.to(device=self.device, dtype=self.dtype)
        obs_k = expand_observation(obs, K)
        return fit_frames(obs_k, q0, None, self.body, cfg, self.geometry, signals=signals)

    def _result(self, fit: FrameFit, k: int, host: torch.Tensor) -> TrackResult:
        """The result of start ``k``; ``host``: :func:`_host_scalars` of ``fit``."""
        s = fit.signals
        depth_error, overlap, surface, steps, converged = host[k].tolist()
        return TrackResult(
            q=fit.q[k],
            depth_error_cm=depth_error,
            overlap=overlap,
            surface_error_q97_mm=surface,
            iterations=int(steps),
            converged=bool(converged),
            limb_visibility=s.limb_visibility[k],
            observed=observed_joints(s.joint_support_cm2[k], self.cfg.observed_joint_area_cm2),
            joint_support_cm2=s.joint_support_cm2[k],
        )


def _host_scalars(fit: FrameFit) -> torch.Tensor:
    """(B, 5) float64 on the CPU: each pose's depth error, overlap, surface error, steps and
    converged flag, read from the device in one copy (on a GPU, one host sync for the batch
    instead of five per pose). float64 holds the float32 signals and the counts exactly."""
    s = fit.signals
    columns = (s.depth_error_cm, s.overlap, s.surface_error_q97_mm, fit.steps, fit.converged)
    return torch.stack([c.to(torch.float64) for c in columns], 1).cpu()


def track_sequence(
    depths: torch.Tensor, masks: torch.Tensor, q0: torch.Tensor, tracker: Tracker
) -> tuple[torch.Tensor, list[TrackResult]]:
    """Track a sequence frame by frame, starting from ``q0`` (e.g. ground truth of frame 0).

    Frame 0 is tracked like the others with ``q0`` as its previous pose (and no velocity).

    Args:
        depths: (F, H, W) metres; masks: (F, H, W) bool; q0: (34,) start pose.
    Returns:
        q (F, 34) estimated poses and one :class:`TrackResult` per frame.
    """
    if depths.dim() != 3 or masks.shape != depths.shape:
        raise TrackerError(
            f"depths and masks must both be (F, H, W), got {tuple(depths.shape)}, "
            f"{tuple(masks.shape)}"
        )
    q0 = q0.to(device=tracker.device, dtype=tracker.dtype)
    results = []
    prev, prev2 = q0, None
    for f in range(depths.shape[0]):
        res = tracker.step(depths[f], masks[f], prev, prev2)
        results.append(res)
        prev, prev2 = res.q, prev
    return torch.stack([r.q for r in results]), results
