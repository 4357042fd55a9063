"""Forest inference: the numba, torch and onnxruntime backends agree with each other and with
training's reference predictor, across save/load and ONNX export; batches, strides, camera
scaling; ``auto`` falls back to torch without numba."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from depthmocap.bench.forest import (
    benchmark_forest,
    benchmark_forest_on,
    forest_device_rows,
    forest_rows,
)
from depthmocap.bench.scenes import person_frame
from depthmocap.runtime.forest import inference
from depthmocap.runtime.forest.inference import (
    DEFAULT_MODEL,
    ForestClassifier,
    compiled_walk,
    load_classifier,
)
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.forest_format import ForestFormatError, save_forest
from depthmocap.shared.labels import PART_NAMES
from depthmocap.train.forest.config import ForestConfig
from depthmocap.train.forest.onnx_export import embedded_graph, export_onnx
from depthmocap.train.forest.predict import predict_posteriors
from depthmocap.train.forest.trainer import train_forest
from depthmocap.train.synth.trainset import TrainSet

INTR = Intrinsics(80, 60, 62.0, 62.0, 39.5, 29.5)


def frames(n: int, seed: int):
    """Blobs of 19 part classes in random layouts (not separable: exercises deep trees)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:60, 0:80]
    depth = np.zeros((n, 60, 80), np.uint16)
    labels = np.zeros((n, 60, 80), np.uint8)
    for i in range(n):
        z = rng.uniform(1.8, 3.0)
        cx, cy = rng.uniform(25, 55), rng.uniform(20, 40)
        body = ((xx - cx) / 14) ** 2 + ((yy - cy) / 22) ** 2 < 1
        part = 1 + ((np.arctan2(yy - cy, xx - cx) + np.pi) / (2 * np.pi) * 19).astype(int) % 19
        d = z + 0.05 * np.cos((xx - cx) / 5) + 0.01 * rng.standard_normal((60, 80))
        depth[i] = np.where(body, d * 1000, 3500).astype(np.uint16)
        labels[i] = np.where(body, part, 0)
        depth[i, rng.integers(0, 60, 20), rng.integers(0, 80, 20)] = 0  # missing readings
    return depth, labels


@pytest.fixture(scope="module")
def forest(tmp_path_factory, write_trainset):
    depth, labels = frames(24, 0)
    root = write_trainset(tmp_path_factory.mktemp("set"), depth, labels, INTR)
    cfg = ForestConfig(
        trees=3, max_depth=12, min_samples=2, feature_pool=48, candidates_per_node=24,
        thresholds_per_candidate=16, pixels_per_frame=300, threads=1, device="cpu",
    )  # fmt: skip
    f = train_forest(TrainSet(root), cfg, log=None)
    f.onnx_graph = embedded_graph(f)
    return f


@pytest.fixture(scope="module")
def test_frames():
    depth, labels = frames(4, 7)
    return torch.from_numpy(depth.astype(np.float32) / 1000.0), torch.from_numpy(labels) > 0


def test_torch_backend_matches_training_reference(forest, test_frames):
    d, m = test_frames
    clf = ForestClassifier(forest, "cpu", backend="torch")
    pix, post = clf.pixel_posteriors(d, m)
    ref_pix, ref_post = predict_posteriors(forest, d, m)
    assert torch.equal(pix, ref_pix) and torch.equal(post, ref_post)
    assert len(pix) == int((m & (d > 0)).sum()) and forest.max_depth > 6


def test_batch_single_dense_and_labels_agree(forest, test_frames):
    d, m = test_frames
    clf = ForestClassifier(forest)
    dense = clf.posteriors(d, m)
    assert dense.shape == (4, 20, 60, 80)
    single = clf.posteriors(d[1], m[1])
    assert single.shape == (20, 60, 80) and torch.equal(single, dense[1])
    lab = clf.labels(d, m)
    valid = m & (d > 0)
    assert torch.equal(lab[valid], dense.argmax(1)[valid]) and (lab[~valid] == 0).all()


def test_onnxruntime_backend_gives_the_same_labels(forest, test_frames):
    pytest.importorskip("onnxruntime")
    d, m = test_frames
    pix_t, post_t = ForestClassifier(forest).pixel_posteriors(d, m)
    pix_o, post_o = ForestClassifier(forest, backend="onnxruntime", threads=1).pixel_posteriors(
        d, m
    )
    assert torch.equal(pix_t, pix_o)
    assert torch.equal(post_t.argmax(1), post_o.argmax(1))
    assert torch.allclose(post_t, post_o, atol=1e-6)


def test_standalone_onnx_file_and_save_load_round_trip(forest, test_frames, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    d, m = test_frames
    save_forest(tmp_path / "f.npz", forest)
    clf = load_classifier(tmp_path / "f.npz", expected_classes=PART_NAMES)
    pix, post = ForestClassifier(forest).pixel_posteriors(d, m)
    pix2, post2 = clf.pixel_posteriors(d, m)
    assert torch.equal(pix, pix2) and torch.equal(post, post2)
    export_onnx(clf.forest, tmp_path / "f.onnx")
    sess = ort.InferenceSession(str(tmp_path / "f.onnx"), providers=["CPUExecutionProvider"])
    frame0 = pix[:, 0] == 0
    probs, labels, pixels = sess.run(None, {"depth": d[0].numpy(), "mask": m[0].numpy()})
    assert np.array_equal(pixels, pix[frame0, 1:].numpy())
    assert np.array_equal(labels, post[frame0].argmax(1).numpy())
    assert np.allclose(probs, post[frame0].numpy(), atol=1e-6)


def test_bad_artifact_gives_clear_error(tmp_path):
    (tmp_path / "f.npz").write_bytes(b"PK\x03\x04 broken")
    with pytest.raises(ForestFormatError, match="truncated or corrupt"):
        load_classifier(tmp_path / "f.npz")


def test_stride_and_camera_scaling(forest, test_frames):
    d, m = test_frames
    clf = ForestClassifier(forest)
    pix, _ = clf.pixel_posteriors(d, m, stride=2)
    assert (pix[:, 1:] % 2 == 0).all() and len(pix) > 0
    # The same scene seen by a camera of twice the resolution (and focal length): offsets are
    # scaled to the same metric displacement, so labels carry over far better than unscaled.
    big = Intrinsics(160, 120, 124.0, 124.0, 79.5, 59.5)
    clf2 = ForestClassifier(forest, intrinsics=big)
    assert clf2.scale == (2.0, 2.0)
    up_d = d.repeat_interleave(2, 1).repeat_interleave(2, 2)
    up_m = m.repeat_interleave(2, 1).repeat_interleave(2, 2)
    lab = clf.labels(d, m)
    lab2 = clf2.labels(up_d, up_m)[:, ::2, ::2]
    unscaled = clf.labels(up_d, up_m)[:, ::2, ::2]
    valid = m & (d > 0)
    agree = (lab2[valid] == lab[valid]).float().mean()
    assert agree > 0.5 and agree > (unscaled[valid] == lab[valid]).float().mean() + 0.1


def test_empty_mask_and_bad_shapes(forest):
    clf = ForestClassifier(forest)
    pix, post = clf.pixel_posteriors(torch.ones(60, 80), torch.zeros(60, 80, dtype=torch.bool))
    assert pix.shape == (0, 3) and post.shape == (0, 20)
    with pytest.raises(ValueError, match="same shape"):
        clf.labels(torch.ones(60, 80), torch.ones(60, 81, dtype=torch.bool))
    with pytest.raises(ValueError, match="backend"):
        ForestClassifier(forest, backend="tensorrt")


def test_benchmark_reports_milliseconds(forest, tmp_path):
    save_forest(tmp_path / "f.npz", forest)
    res = benchmark_forest(tmp_path / "f.npz", threads=1, repeats=2)
    assert res["torch_cpu_ms"] > 0 and res["torch_cpu_stride2_ms"] > 0 and res["pixels"] > 1000
    assert res["torch_cpu_smoothed_ms"] > 0
    assert "onnxruntime_ms" in res
    if compiled_walk() is not None:
        for key in ("numba_cpu_ms", "numba_cpu_stride2_ms", "numba_cpu_smoothed_ms"):
            assert res[key] > 0
        assert res["numba_identical"] == 1.0
    rows = forest_rows(res)
    assert [r[0] for r in rows][:2] == ["torch CPU, every person pixel"] + (
        ["numba CPU, every person pixel"]
        if "numba_cpu_ms" in res
        else ["torch CPU, every 2nd pixel (detector)"]
    )
    assert all(ms > 0 for _, ms, _ in rows)
    assert benchmark_forest(tmp_path / "missing.npz") == {}
    depth, mask = person_frame()
    assert depth.shape == (240, 320) and (depth[mask] > 2).all() and (depth[~mask] == 0).all()


def test_benchmark_on_a_device_times_the_torch_walk_and_compares_it_with_the_cpu(
    forest, tmp_path, device
):
    """The GPU figure of ``runtime-bench --device cuda`` (here on every available device): the
    torch walk's times, and its labels against the CPU's on the same frame."""
    save_forest(tmp_path / "f.npz", forest)
    depth, labels = frames(1, seed=3)
    frame = ((depth[0] / 1000.0).astype(np.float32), labels[0] > 0)
    res = benchmark_forest_on(device, tmp_path / "f.npz", repeats=2, frame=frame)
    assert res["pixels"] == float(((labels[0] > 0) & (depth[0] > 0)).sum()) > 500
    assert all(res[k] > 0 for k in ("all_ms", "stride2_ms", "smoothed_ms"))
    if device.type == "cpu":  # the same walk on the same device: the same posteriors
        assert res["same_labels"] == 1.0 and res["posterior_diff"] == 0.0
    else:
        assert res["same_labels"] > 0.99 and res["posterior_diff"] < 1e-3
    rows = forest_device_rows(res, "GPU")
    assert [r[0] for r in rows] == [
        "torch GPU, every person pixel",
        "torch GPU, every 2nd pixel (detector)",
        "torch GPU, 5x5 smoothed (detector, hybrid)",
    ]
    assert "100.00% of pixels" in rows[0][2] or device.type != "cpu"
    assert benchmark_forest_on(device, tmp_path / "missing.npz") == {}


def test_default_model_path_points_into_models():
    assert (
        DEFAULT_MODEL.parent.name == "models"
        and DEFAULT_MODEL.parent.parent == Path(__file__).resolve().parents[3]
    )


def test_smoothing_option_matches_the_shared_function_on_both_backends(forest, test_frames):
    from depthmocap.shared.posterior_smoothing import smooth_posteriors

    d, m = test_frames
    pix, raw = ForestClassifier(forest).pixel_posteriors(d, m)
    smooth = ForestClassifier(forest, smooth_window=5, smooth_depth_gate_m=0.05)
    pix_s, post_s = smooth.pixel_posteriors(d, m)
    assert torch.equal(pix_s, pix)
    torch.testing.assert_close(post_s, smooth_posteriors(pix, raw, d, 5, 0.05))
    assert not torch.equal(post_s, raw)
    lab = smooth.labels(d, m)
    assert torch.equal(lab[pix[:, 0], pix[:, 1], pix[:, 2]], post_s.argmax(1))
    onnx = ForestClassifier(forest, backend="onnxruntime", threads=1, smooth_window=5)
    torch.testing.assert_close(onnx.pixel_posteriors(d, m)[1], post_s, atol=1e-6, rtol=0)
    for bad in ({"smooth_window": 4}, {"smooth_window": 0}, {"smooth_depth_gate_m": 0.0}):
        with pytest.raises(ValueError, match="smooth"):
            ForestClassifier(forest, **bad)


def test_labeler_reports_bad_smoothing_as_a_detector_error(forest, tmp_path):
    from depthmocap.runtime.detector import DetectorError, load_forest_labeler

    save_forest(tmp_path / "f.npz", forest)
    with pytest.raises(DetectorError, match="smoothing window must be odd"):
        load_forest_labeler(tmp_path / "f.npz", "cpu", INTR, smooth_window=4)
    labels = load_forest_labeler(tmp_path / "f.npz", "cpu", INTR, smooth_window=3)
    depth, mask = person_frame(80, 60)
    assert labels(torch.from_numpy(depth), torch.from_numpy(mask)).shape == (60, 80)


def test_labels_with_confidence_are_the_labels_and_their_posteriors(forest, test_frames, tmp_path):
    """``labels_and_confidence``: the labels of :meth:`labels` and, at each classified pixel,
    the posterior of that label (0 elsewhere), on every backend; the labeler's pair through
    ``forest_label_source``."""
    from depthmocap.runtime.detector import (
        DetectorError,
        forest_label_source,
        load_forest_labeler,
    )

    d, m = test_frames
    backends = ["torch", "onnxruntime"] + (["numba"] if inference.compiled_walk() else [])
    for backend in backends:
        clf = ForestClassifier(forest, backend=backend, smooth_window=3)
        lab, conf = clf.labels_and_confidence(d, m)
        assert torch.equal(lab, clf.labels(d, m)) and conf.dtype == torch.float32
        post = clf.posteriors(d, m)  # (B, C, H, W)
        torch.testing.assert_close(conf, post.gather(1, lab[:, None])[:, 0], atol=1e-6, rtol=0)
        seen = m & (d > 0)  # the classified pixels
        assert bool((conf[~seen] == 0).all()) and bool((conf[seen] > 0).all())
    save_forest(tmp_path / "f.npz", forest)
    labeler = load_forest_labeler(tmp_path / "f.npz", "cpu", INTR, confidence=True)

    class Frame:
        depth_m, mask = d[0], m[0]

    lab, conf = forest_label_source(labeler)(Frame)
    assert lab.shape == conf.shape == d[0].shape
    with pytest.raises(DetectorError, match="posteriors or labels"):
        load_forest_labeler(tmp_path / "f.npz", "cpu", INTR, posteriors=True, confidence=True)


# ---------------------------------------------------------------- numba backend and fallback


def both(forest, **kw):
    """The numba and the torch classifier of ``forest`` (skips without numba)."""
    pytest.importorskip("numba")
    fast = ForestClassifier(forest, backend="numba", **kw)
    return fast, ForestClassifier(forest, backend="torch", **kw)


def test_numba_backend_gives_the_torch_outputs_bit_for_bit(forest, test_frames):
    d, m = test_frames
    fast, ref = both(forest)
    assert ForestClassifier(forest).backend == "numba"  # what auto picks when numba is there
    for stride in (1, 2, 3):
        pix, post = fast.pixel_posteriors(d, m, stride)
        pix_r, post_r = ref.pixel_posteriors(d, m, stride)
        assert torch.equal(pix, pix_r) and torch.equal(post, post_r)
    assert torch.equal(fast.labels(d, m), ref.labels(d, m))
    assert torch.equal(fast.posteriors(d, m), ref.posteriors(d, m))
    assert torch.equal(fast.labels(d[2], m[2]), ref.labels(d[2], m[2]))  # (H, W) input
    assert torch.equal(fast.posteriors(d[2], m[2]), ref.posteriors(d[2], m[2]))
    assert fast.labels(d, m).dtype == torch.int64 and fast.posteriors(d, m).dtype == torch.float32
    # numpy inputs, float64 depth, an empty mask
    assert torch.equal(fast.labels(d.double().numpy(), m.numpy()), ref.labels(d, m))
    empty = torch.zeros_like(m)
    pix, post = fast.pixel_posteriors(d, empty)
    assert pix.shape == (0, 3) and post.shape == (0, 20)
    assert not fast.labels(d, empty).any() and fast.labels(d, empty).shape == d.shape


def test_numba_backend_with_smoothing_and_another_camera(forest, test_frames):
    d, m = test_frames
    big = Intrinsics(160, 120, 124.0, 124.0, 79.5, 59.5)
    fast, ref = both(forest, intrinsics=big, smooth_window=5)
    up_d = d.repeat_interleave(2, 1).repeat_interleave(2, 2)
    up_m = m.repeat_interleave(2, 1).repeat_interleave(2, 2)
    for stride in (1, 2):
        pix, post = fast.pixel_posteriors(up_d, up_m, stride)
        pix_r, post_r = ref.pixel_posteriors(up_d, up_m, stride)
        assert torch.equal(pix, pix_r) and torch.equal(post, post_r)


def test_shipped_forest_numba_equals_torch_on_the_bench_frame():
    if not DEFAULT_MODEL.is_file():
        pytest.skip("no shipped forest")
    pytest.importorskip("numba")
    from depthmocap.shared.forest_format import load_forest

    fast, ref = both(load_forest(DEFAULT_MODEL))
    depth, mask = (torch.from_numpy(a) for a in person_frame())
    pix, post = fast.pixel_posteriors(depth, mask)
    pix_r, post_r = ref.pixel_posteriors(depth, mask)
    assert len(pix) == 6963 and torch.equal(pix, pix_r) and torch.equal(post, post_r)
    assert torch.equal(fast.labels(depth, mask, stride=2), ref.labels(depth, mask, stride=2))


def test_without_numba_auto_falls_back_to_torch(forest, test_frames, monkeypatch, request):
    import depthmocap.shared as shared
    from depthmocap.shared.compiled import compiled_module

    # The loaded modules are remembered: forget them now and again after the test.
    compiled_module.cache_clear()
    request.addfinalizer(compiled_module.cache_clear)
    monkeypatch.setitem(sys.modules, "numba", None)  # "import numba" raises ImportError
    monkeypatch.delitem(sys.modules, "depthmocap.shared.forest_kernel", raising=False)
    monkeypatch.delattr(shared, "forest_kernel", raising=False)
    assert compiled_walk() is None
    clf = ForestClassifier(forest)
    assert clf.backend == "torch"
    d, m = test_frames
    pix, post = clf.pixel_posteriors(d, m)
    ref = predict_posteriors(forest, d, m)
    assert torch.equal(pix, ref[0]) and torch.equal(post, ref[1])
    with pytest.raises(ValueError, match="needs numba"):
        ForestClassifier(forest, backend="numba")


def test_numba_is_not_for_cuda_and_auto_uses_torch_there(forest, monkeypatch):
    monkeypatch.setattr(inference, "compiled_walk", lambda: pytest.fail("looked for numba"))
    with pytest.raises(ValueError, match="device 'cpu'"):
        ForestClassifier(forest, "cuda", backend="numba")
    if torch.cuda.is_available():
        assert ForestClassifier(forest, "cuda").backend == "torch"


def test_importing_the_runtime_does_not_import_numba():
    code = (
        "import sys, depthmocap.runtime.forest.inference, depthmocap.runtime.detector; "
        "print('numba' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
