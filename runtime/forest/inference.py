"""Per-pixel body-part posteriors from a trained forest (Wei 2012 section 4.1, eq. 13).

Which pixels: those in the person ``mask`` (from ``runtime.segmentation``) that have a depth
reading. Every probe that lands outside the mask, on a pixel without a reading, or off the
image reads the forest's background constant (10 m), as in training. Posteriors are the mean
over trees of the leaf class distributions; ``labels`` is their arg-max (0 = background outside
the mask).

Backends (``backend="auto"``, the default, is ``numba`` on the CPU when numba is installed and
``torch`` otherwise):

- ``numba`` (CPU): :mod:`shared.forest_kernel`, a compiled loop in which each pixel walks down
  each tree and stops at its leaf; the same leaves and posteriors as ``torch`` bit for bit, and
  faster: on one thread than torch on two. numba is optional (the ``runtime`` extra). Pixels
  are listed and results scattered with numpy, not torch (see ``_prepare``).
- ``torch`` (CPU or CUDA, follows ``device``): all (pixel, tree) pairs descend together, one
  level per step, with one row gather from the node table (:func:`shared.forest_format.
  traversal_table`) and one depth gather per step. Leaves point to themselves, so there is no
  per-pixel test; every few levels the pairs that reached a leaf are dropped (cheap on the CPU,
  where work is proportional to the pairs).
- ``onnxruntime``: the ONNX graph stored in the artifact (``train-forest`` embeds it; see
  ``train/forest/onnx_export.py``) with the node and leaf tables fed as inputs; CPU execution.
  Same arithmetic, same labels. Several times slower than torch (the graph copies six slices
  of every level's node rows and broadcasts over all pairs for all ``max_depth`` levels; more
  threads do not help, ``docs/experiments.md``), so ``auto`` never picks it.

Another camera: the artifact records the focal lengths it was trained for. Pass the runtime
camera's ``intrinsics`` and offsets are scaled by ``(fx'/fx, fy'/fy)`` so that each probe keeps
its metric distance in the scene (e.g. a 320x240 forest on a 640x480 stream). Accuracy is best at
the trained resolution; ``stride`` > 1 classifies every stride-th pixel in both directions (the
detector needs part centroids, not every pixel), a 4x saving at stride 2.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.compiled import compiled_module
from depthmocap.shared.forest_format import Forest, load_forest, traversal_table
from depthmocap.shared.forest_walk import traverse, walk_posteriors
from depthmocap.shared.posterior_smoothing import check_smoothing, smooth_posteriors
from depthmocap.shared.resources import MODELS_DIR

BACKENDS = ("auto", "numba", "torch", "onnxruntime")

__all__ = [
    "DEFAULT_MODEL",
    "DEFAULT_CALIBRATION_MODEL",
    "BACKENDS",
    "ForestClassifier",
    "compiled_walk",
    "traverse",
    "load_classifier",
]

# The forest shipped in the repository (models/README.md), used when no --model is given.
DEFAULT_MODEL = MODELS_DIR / "forest.npz"
# Trained on the calibration T-pose only (Wei section 6): labels that pose more accurately.
DEFAULT_CALIBRATION_MODEL = DEFAULT_MODEL.with_name("forest_calib.npz")


def compiled_walk():
    """The module :mod:`shared.forest_kernel` (numba's compiled walk), or None without numba."""
    return compiled_module("depthmocap.shared.forest_kernel")


class ForestClassifier:
    """Per-pixel posteriors of a forest; see the module docstring.

    Args:
        forest: a loaded :class:`Forest`.
        device: torch device of the torch backend (inputs are moved to it).
        backend: one of :data:`BACKENDS` (see the module docstring); ``"auto"`` is ``"numba"``
            on the CPU when numba imports and ``"torch"`` otherwise.
        intrinsics: runtime camera; offsets are rescaled when its focal lengths differ from the
            trained camera's.
        threads: CPU threads of the onnxruntime session (torch uses its global setting, numba
            one thread).
        smooth_window: posteriors are averaged over this box of classified pixels
            (:func:`shared.posterior_smoothing.smooth_posteriors`; 1: off).
        smooth_depth_gate_m: neighbours farther in depth than this are not averaged in (m).
    """

    def __init__(
        self,
        forest: Forest,
        device: str | torch.device = "cpu",
        backend: str = "auto",
        intrinsics: Intrinsics | None = None,
        threads: int = 2,
        smooth_window: int = 1,
        smooth_depth_gate_m: float = 0.05,
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, not {backend!r}")
        check_smoothing(smooth_window, smooth_depth_gate_m)
        self.smooth_window, self.smooth_depth_gate_m = smooth_window, smooth_depth_gate_m
        self.forest = forest
        self.device = torch.device(device)
        self._kernel = None
        if backend in ("auto", "numba") and self.device.type == "cpu":
            self._kernel = compiled_walk()
        if backend == "numba" and self._kernel is None:
            raise ValueError(
                "backend 'numba' needs numba (pip install numba) and device 'cpu'; "
                "backend 'torch' runs anywhere"
            )
        if backend == "auto":
            backend = "torch" if self._kernel is None else "numba"
        self.backend = backend
        # The numba backend prepares pixels and scatters results with numpy, not torch.
        self._numpy = backend == "numba"
        self.levels = forest.max_depth
        if intrinsics is None:
            self.scale = (1.0, 1.0)
        else:
            self.scale = forest.offset_scale(intrinsics.fx, intrinsics.fy)
        self.background = float(forest.background_m)
        table = traversal_table(forest)
        self._table_np = table
        self.table = torch.from_numpy(table).to(self.device)
        self.is_leaf = torch.from_numpy(forest.left < 0).to(self.device)
        self.roots = torch.from_numpy(forest.roots.astype(np.int64)).to(self.device)
        self._leaf_dist_np = forest.leaf_dist.astype(np.float32)  # converted once, at load
        self._roots_np = forest.roots.astype(np.int64)
        self.leaf_dist = torch.from_numpy(self._leaf_dist_np).to(self.device)
        self._session = None
        if backend == "onnxruntime":
            self._session = self._make_session(threads)
        if backend == "numba":  # compile (or load numba's cache) now, not on the first frame
            self.pixel_posteriors(torch.ones(1, 1), torch.ones(1, 1, dtype=torch.bool))

    @property
    def num_classes(self) -> int:
        return self.forest.num_classes

    # ---------------------------------------------------------------- onnxruntime backend

    def _make_session(self, threads: int):
        if self.forest.onnx_graph is None:
            raise ValueError(
                "this forest artifact has no embedded ONNX graph; re-save it with train-forest "
                "(or use backend='torch')"
            )
        try:
            import onnxruntime as ort
        except ImportError as exc:
            raise ValueError(
                "backend 'onnxruntime' needs the onnxruntime package (pip install onnxruntime)"
            ) from exc
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        return ort.InferenceSession(
            self.forest.onnx_graph, opts, providers=["CPUExecutionProvider"]
        )

    def _onnx_posteriors(self, depth: np.ndarray, mask: np.ndarray) -> np.ndarray:
        feeds = {
            "depth": depth.astype(np.float32, copy=False),
            "mask": mask.astype(bool, copy=False),
            "offset_scale": np.asarray(self.scale, dtype=np.float32),
            "node_table": self._table_np,
            "leaf_dist": self.forest.leaf_dist,
            "roots": self.forest.roots.astype(np.int64),
        }
        return self._session.run(["posteriors"], feeds)[0]

    # ---------------------------------------------------------------- public API

    def _prepare(self, depth_m: torch.Tensor, mask: torch.Tensor, stride: int):
        depth_m = torch.as_tensor(depth_m)
        mask = torch.as_tensor(mask)
        if depth_m.ndim not in (2, 3) or mask.shape != depth_m.shape:
            raise ValueError(
                f"depth (H, W) or (B, H, W) and a mask of the same shape expected, got "
                f"{tuple(depth_m.shape)} and {tuple(mask.shape)}"
            )
        single = depth_m.ndim == 2
        depth_m = depth_m.to(self.device, torch.float32)
        mask = mask.to(self.device, torch.bool)
        if single:
            depth_m, mask = depth_m[None], mask[None]
        if self._numpy:
            # numpy is single-threaded: on a busy 2-core host each of torch's multi-threaded
            # element-wise passes over a 320x240 frame costs more than the whole walk.
            d, m = depth_m.numpy(), mask.numpy()
            valid = m & (d > 0) & np.isfinite(d)
            if stride > 1:
                keep = np.zeros_like(valid)
                keep[:, ::stride, ::stride] = True
                valid &= keep
            return depth_m, torch.from_numpy(valid), single
        valid = mask & (depth_m > 0) & torch.isfinite(depth_m)
        if stride > 1:
            sub = torch.zeros_like(valid)
            sub[:, ::stride, ::stride] = True
            valid &= sub
        return depth_m, valid, single

    def pixel_posteriors(
        self, depth_m: torch.Tensor, mask: torch.Tensor, stride: int = 1
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Posteriors of the classified pixels.

        Args:
            depth_m: (H, W) or (B, H, W) depth in metres, 0 = no reading.
            mask: bool person mask of the same shape.
            stride: classify only pixels whose row and column are multiples of ``stride``.
        Returns:
            pixels (N, 3) int64 (frame, row, col) in row-major order, posteriors (N, C) float32
            (smoothed when the classifier's ``smooth_window`` > 1).
        """
        depth, valid, _ = self._prepare(depth_m, mask, stride)
        b, h, w = depth.shape
        if self._numpy:
            pix = torch.from_numpy(np.argwhere(valid.numpy()))  # row-major, as torch.nonzero
        else:
            pix = torch.nonzero(valid)
        if pix.shape[0] == 0:
            return pix, torch.zeros(0, self.num_classes, device=self.device)
        if self.backend == "onnxruntime":
            probs = torch.cat(
                [
                    torch.from_numpy(
                        self._onnx_posteriors(depth[i].cpu().numpy(), valid[i].cpu().numpy())
                    )
                    for i in range(b)  # one image per ONNX call: the graph takes (H, W)
                ]
            ).to(self.device)
        elif self.backend == "numba":
            probs = self._numba_posteriors(depth, valid, pix)
        else:
            probs = self._torch_posteriors(depth, valid, pix)
        probs = smooth_posteriors(
            pix, probs, depth, self.smooth_window, self.smooth_depth_gate_m, max(stride, 1)
        )
        return pix, probs

    def _torch_posteriors(self, depth, valid, pix) -> torch.Tensor:
        # Dropping finished pairs pays off on the CPU, where work is proportional to pairs.
        is_leaf = self.is_leaf if self.device.type == "cpu" else None
        return walk_posteriors(
            self.table, self.roots, self.leaf_dist, self.levels, self.background, depth, valid,
            pix, self.scale, is_leaf,
        )  # fmt: skip

    def _numba_posteriors(self, depth, valid, pix) -> torch.Tensor:
        post = self._kernel.walk_posteriors(
            self._table_np, self._roots_np, self._leaf_dist_np, self.levels, self.background,
            depth.numpy(), valid.numpy(), pix.numpy(), self.scale,
        )  # fmt: skip
        return torch.from_numpy(post)

    def _dense(self, depth_m, pix: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        """(B, H, W, *values.shape[1:]) zeros with ``values`` at ``pix``; the batch axis dropped
        for an (H, W) input."""
        shape = torch.as_tensor(depth_m).shape
        single = len(shape) == 2
        b, h, w = (1, *shape) if single else shape
        if self._numpy:
            out = np.zeros((b, h, w, *values.shape[1:]), values.numpy().dtype)
            p = pix.numpy()
            out[p[:, 0], p[:, 1], p[:, 2]] = values.numpy()
            out = torch.from_numpy(out)
        else:
            out = torch.zeros(b, h, w, *values.shape[1:], dtype=values.dtype, device=self.device)
            out[pix[:, 0], pix[:, 1], pix[:, 2]] = values
        return out[0] if single else out

    def posteriors(self, depth_m: torch.Tensor, mask: torch.Tensor, stride: int = 1):
        """Dense posteriors: (C, H, W) for an (H, W) input, (B, C, H, W) for (B, H, W); zero at
        pixels that were not classified."""
        pix, probs = self.pixel_posteriors(depth_m, mask, stride)
        return self._dense(depth_m, pix, probs).movedim(-1, -3)

    def labels(self, depth_m: torch.Tensor, mask: torch.Tensor, stride: int = 1) -> torch.Tensor:
        """Arg-max class per pixel: (H, W) or (B, H, W) int64, 0 where not classified."""
        pix, probs = self.pixel_posteriors(depth_m, mask, stride)
        return self._dense(depth_m, pix, self._arg_max(probs))

    def labels_and_confidence(
        self, depth_m: torch.Tensor, mask: torch.Tensor, stride: int = 1
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`labels` and each label's posterior (the arg-max class's): (H, W) int64 and
        (H, W) float32, or batched as :meth:`labels`; 0 where not classified."""
        pix, probs = self.pixel_posteriors(depth_m, mask, stride)
        arg = self._arg_max(probs)
        top = probs.gather(1, arg[:, None])[:, 0]
        return self._dense(depth_m, pix, arg), self._dense(depth_m, pix, top)

    def _arg_max(self, probs: torch.Tensor) -> torch.Tensor:
        """(N,) int64 class of each row of (N, C) posteriors, the first maximum on ties."""
        if self._numpy:  # first maximum on ties, as torch.argmax
            return torch.from_numpy(probs.numpy().argmax(1).astype(np.int64))
        return probs.argmax(1)


def load_classifier(
    path: str | Path,
    device: str | torch.device = "cpu",
    backend: str = "torch",
    intrinsics: Intrinsics | None = None,
    expected_classes: tuple[str, ...] | None = None,
) -> ForestClassifier:
    """:func:`load_forest` (clear errors for bad artifacts) and a :class:`ForestClassifier`."""
    return ForestClassifier(
        load_forest(path, expected_classes), device=device, backend=backend, intrinsics=intrinsics
    )
