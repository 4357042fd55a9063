"""Fit the joint confidence behind the observed flags (``shared.joint_confidence``).

    python -m depthmocap.train.evaluation.joint_confidence_fit \\
        --recordings data/tune_half_a data/tune_half_b --out models/joint_confidence.json

Each recording (synthetic, with ``groundtruth.npz`` and part labels) is tracked by the
shipped hybrid as ``runtime-track`` runs a file (``--config`` lays settings over it), in a
subprocess (``python -m depthmocap.bench.joint_evidence``; ``train`` never imports
``runtime``), into ``--evidence``, where a later fit finds it again. Every pose gives each
joint its evidence (confirmed area, limb visibility; the estimate's ``joint_support_cm2``
and ``limb_visibility``; the frame's fit and the joint's distance to the person's cut by the
image's edge, ``shared.joint_confidence.confidence_features``) and a target: the joint is in view
(``train.evaluation.visibility``, from the rendered labels) and its output position is within
``--within-m`` of the truth. One logistic regression per joint group fits the targets; the
threshold then keeps ``--recall`` of the joints in view. ``--validate`` tracks other
recordings and prints what the fitted flags and the tracker's own area test give there.

Fit on recordings you do not report: the shipped file comes from the broad protocol's tuning
sets (its spec with another seed; ``docs/protocol.md``), never from ``data/dev_broad``.
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import torch
from depthmocap.shared import skeleton as sk
from depthmocap.shared.joint_confidence import (
    GROUPS,
    JOINT_GROUP,
    VERSION,
    JointConfidence,
    confidence_features,
    joint_confidence,
    save_joint_confidence,
)

__all__ = ["flag_figures", "fit_confidence", "fit_logistic", "main", "recording_evidence"]


def recording_evidence(recording: Path, evidence: Path) -> dict[str, np.ndarray]:
    """A recording's evidence file (``bench.joint_evidence``) paired with its ground truth.

    Returns:
        ``support`` (F, J), ``visibility`` (F, 4) of the limbs in the fit, ``fit`` (F, 5)
        the frame's fit, ``cut_m`` (F, J) distances to the person's cut by the image's edge,
        ``in_view`` (F, J) bool, ``error_m`` (F, J) output joints to the truth, ``observed``
        (F, J) bool the area test's flags; F the frames with a pose.
    """
    from depthmocap.shared.recording import Recording

    from .truth import GROUND_TRUTH, recording_truth
    from .visibility import recording_joint_visibility

    rec = Recording(recording)
    truth = recording_truth(rec)
    if truth.kind != GROUND_TRUTH or tuple(truth.joint_names) != sk.JOINT_NAMES:
        raise ValueError(f"{recording}: needs a ground truth with this build's joints")
    in_view = recording_joint_visibility(rec, truth.joints, sk.JOINT_NAMES)
    if in_view is None:
        raise ValueError(f"{recording}: has no part labels to tell which joints are in view")
    try:
        with np.load(evidence) as data:
            keys = ("frame", "support", "visibility", "fit", "cut_m", "joints", "observed")
            stored = {k: data[k] for k in keys}
            # Evidence recorded before version 3's features has no parts: it fits version 2.
            parts = data["parts"] if "parts" in data.files else None
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as err:
        raise ValueError(
            f"{evidence}: not a readable evidence file ({err}); delete it to track "
            f"{recording.name} again"
        ) from None
    frames = stored["frame"]
    if len(frames) and (frames.min() < 0 or frames.max() >= len(truth.joints)):
        raise ValueError(f"{evidence}: frames beyond {recording}'s {len(truth.joints)}")
    evidence = {
        "support": stored["support"],
        "visibility": stored["visibility"],
        "fit": stored["fit"],
        "cut_m": stored["cut_m"],
        "joints": stored["joints"],
        "in_view": in_view[frames],
        "error_m": np.linalg.norm(stored["joints"] - truth.joints[frames], axis=-1),
        "observed": stored["observed"],
    }
    if parts is not None:
        evidence["parts"] = parts
    return evidence


def fit_logistic(x: np.ndarray, y: np.ndarray, l2: float = 1e-3) -> tuple[np.ndarray, float]:
    """Logistic regression of targets ``y`` (N,) in {0, 1} on features ``x`` (N, K):
    weights (K,) and bias on the raw features (fitted on standardized ones, with an L2
    penalty ``l2`` on the standardized weights)."""
    X = torch.as_tensor(x, dtype=torch.float64)
    Y = torch.as_tensor(y, dtype=torch.float64)
    mu, sd = X.mean(0), X.std(0).clamp_min(1e-9)
    Z = (X - mu) / sd
    w = torch.zeros(X.shape[1], dtype=torch.float64, requires_grad=True)
    b = torch.zeros((), dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([w, b], max_iter=500, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        logits = Z @ w + b
        loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, Y) + l2 * (w * w).sum()
        loss.backward()
        return loss

    opt.step(closure)
    with torch.no_grad():
        raw = w / sd
        return raw.numpy(), float(b - (raw * mu).sum())


def _inputs(evidence: dict[str, np.ndarray], version: int) -> tuple[torch.Tensor, ...]:
    """The evidence's (support, visibility, fit, cut_m[, joints, parts]) as
    :func:`joint_confidence` reads them for a model of ``version`` (2 or 3)."""
    keys = ("support", "visibility", "fit", "cut_m") + (("joints", "parts") if version >= 3 else ())
    return tuple(torch.as_tensor(evidence[k]) for k in keys)


def evidence_version(evidence: dict[str, np.ndarray]) -> int:
    """The newest model version ``evidence`` has the features for (3 with ``parts``, else 2)."""
    return 3 if "parts" in evidence else 2


def fit_confidence(
    evidence: dict[str, np.ndarray], recall: float = 0.95, within_m: float = 0.2
) -> JointConfidence:
    """The joint confidence fitted to ``evidence`` as :func:`recording_evidence` returns it (its
    ``support``, ``visibility``, ``fit``, ``cut_m``, ``in_view`` and ``error_m``; module
    docstring); its threshold keeps ``recall`` of the joints in view."""
    support = evidence["support"]
    in_view, error_m = evidence["in_view"], evidence["error_m"]
    version = evidence_version(evidence)
    f = confidence_features(*_inputs(evidence, version)).numpy()
    K = f.shape[-1]
    target = in_view & (error_m <= within_m)
    weights = np.zeros((len(GROUPS), K))
    bias = np.zeros(len(GROUPS))
    for k, group in enumerate(GROUPS):
        cols = [j for j, g in enumerate(JOINT_GROUP) if g == group]
        weights[k], bias[k] = fit_logistic(
            f[:, cols].reshape(-1, K), target[:, cols].reshape(-1).astype(float)
        )
    model = JointConfidence(weights, bias, 0.5, version=version)
    p = joint_confidence(model, *_inputs(evidence, version)).numpy()
    threshold = float(np.quantile(p[in_view], 1.0 - recall)) if in_view.any() else 0.5
    kept = float((p[in_view] >= threshold).mean()) if in_view.any() else float("nan")
    return JointConfidence(weights, bias, threshold, kept, frames=len(support), version=version)


def flag_figures(
    observed: np.ndarray, in_view: np.ndarray, error_m: np.ndarray, within_m: float = 0.2
) -> dict[str, float]:
    """What (F, J) ``observed`` flags give: ``recall`` (share of the joints in view they
    flag), ``failure`` (share of frames with a flagged joint beyond ``within_m``) and
    ``in_view`` (share of flagged joints in view)."""
    flagged = max(1, int(observed.sum()))
    return {
        "recall": float((observed & in_view).sum() / max(1, int(in_view.sum()))),
        "failure": float((observed & (error_m > within_m)).any(1).mean()) if len(observed) else 0.0,
        "in_view": float((observed & in_view).sum() / flagged),
    }


def _evidence(folders: list[Path], store: Path, config: str | None) -> dict[str, np.ndarray]:
    """Every recording's evidence in ``folders``, tracked into ``store/FOLDER`` by
    ``bench.joint_evidence`` in a subprocess where not there yet."""
    parts = []
    # Evidence tracked with other settings is kept apart: a file found is reused as it is.
    tag = "" if not config else "-" + hashlib.sha1(Path(config).read_bytes()).hexdigest()[:8]
    for folder in folders:
        out = store / f"{folder.name}{tag}"
        cmd = [sys.executable, "-m", "depthmocap.bench.joint_evidence"]
        cmd += ["--recordings", str(folder), "--out", str(out)]
        cmd += ["--config", config] if config else []
        if subprocess.run(cmd).returncode != 0:
            raise ValueError(f"tracking {folder} failed (command: {' '.join(cmd)})")
        for rec in sorted(p for p in folder.iterdir() if (p / "groundtruth.npz").is_file()):
            parts.append(recording_evidence(rec, out / f"{rec.name}.npz"))
    if not parts:
        raise ValueError(f"no recordings with ground truth in {', '.join(map(str, folders))}")
    # Version 3's parts only where every recording has them (older evidence fits version 2).
    keys = set.intersection(*(set(p) for p in parts))
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0] if k in keys}


def _report(label: str, data: dict, model: JointConfidence, within_m: float) -> None:
    p = joint_confidence(model, *_inputs(data, model.version))
    for name, flags in (("fitted flags", p.numpy() >= model.threshold),
                        ("area test", data["observed"])):  # fmt: skip
        f = flag_figures(flags, data["in_view"], data["error_m"], within_m)
        print(
            f"{label}, {name}: recall {100 * f['recall']:.1f}% of the joints in view, frames "
            f"with a flagged joint over {100 * within_m:g} cm {100 * f['failure']:.2f}%, "
            f"flagged joints in view {100 * f['in_view']:.1f}%"
        )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m depthmocap.train.evaluation.joint_confidence_fit",
        description=__doc__.splitlines()[0],
    )
    p.add_argument("--recordings", type=Path, nargs="+", required=True,
                   help="folders of synthetic recordings with ground truth")  # fmt: skip
    p.add_argument("--out", type=Path, required=True, help="the joint-confidence file to write")
    p.add_argument("--recall", type=float, default=0.95, help="share of in-view joints to flag")
    p.add_argument("--within-m", type=float, default=0.2, help="a joint further off is wrong")
    p.add_argument("--config", default=None, help="settings over the shipped preset")
    p.add_argument("--evidence", type=Path, default=Path("out/joint_evidence"),
                   help="where each recording's tracked evidence is kept and reused (per "
                        "folder name and --config file)")  # fmt: skip
    p.add_argument("--validate", type=Path, nargs="*", default=[], help="other recordings")
    args = p.parse_args(argv)
    if not 0.0 < args.recall <= 1.0:
        p.error(f"--recall must be in (0, 1], got {args.recall}")
    for folder in [*args.recordings, *args.validate]:
        if not folder.is_dir():
            p.error(f"{folder}: no such folder")
    try:
        data = _evidence(args.recordings, args.evidence, args.config)
        model = fit_confidence(data, args.recall, args.within_m)
        held = _evidence(args.validate, args.evidence, args.config) if args.validate else None
    except (FileNotFoundError, ValueError, KeyError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    model.fitted_on = ", ".join(map(str, args.recordings))
    save_joint_confidence(args.out, model)
    print(
        f"{len(data['support'])} frames -> {args.out} (version {model.version}, threshold "
        f"{model.threshold:.4f})"
    )
    if model.version < VERSION:  # evidence recorded before the newest features
        print(
            f"note: the evidence lacks version {VERSION}'s features; record it again (delete "
            f"its files under --evidence) to fit version {VERSION}",
            file=sys.stderr,
        )
    _report("fitted on", data, model, args.within_m)
    if held is not None:
        _report("held out", held, model, args.within_m)
    return 0


if __name__ == "__main__":
    sys.exit(main())
