"""The forest artifact: round trip, validation, and a clear error for every malformed case."""

import json
import zipfile

import numpy as np
import pytest
from depthmocap.shared.forest_format import (
    FOREST_VERSION,
    Forest,
    ForestFormatError,
    forest_checksum,
    load_forest,
    load_forest_shared,
    save_forest,
    traversal_table,
)

CLASSES = ("background", "a", "b")
CAMERA = {"width": 64, "height": 48, "fx": 50.0, "fy": 50.0, "cx": 31.5, "cy": 23.5}


def two_trees() -> Forest:
    """Tree 0: root split with two leaves; tree 1: a single leaf."""
    return Forest(
        u=np.array([[3.0, 0.0], [0, 0], [0, 0], [0, 0]]),
        v=np.array([[0.0, -2.0], [0, 0], [0, 0], [0, 0]]),
        threshold=np.array([0.25, 0, 0, 0]),
        left=np.array([1, -1, -1, -1]),
        right=np.array([2, -1, -1, -1]),
        leaf=np.array([-1, 0, 1, 2]),
        leaf_dist=np.array([[0, 1, 0], [0, 0.25, 0.75], [0, 0.5, 0.5]]),
        roots=np.array([0, 3]),
        class_names=CLASSES,
        camera=CAMERA,
        config={"trees": 2},
        stats={"seconds": 1.5},
    )


def test_round_trip(tmp_path):
    f = two_trees()
    f.onnx_graph = b"\x08\x01graph"
    save_forest(tmp_path / "f.npz", f)
    g = load_forest(tmp_path / "f.npz", expected_classes=CLASSES)
    for name in ("u", "v", "threshold", "left", "right", "leaf", "leaf_dist", "roots"):
        a, b = getattr(f, name), getattr(g, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert g.leaf_dist.dtype == np.float16
    assert g.class_names == CLASSES and g.camera == CAMERA
    assert g.config == {"trees": 2} and g.stats == {"seconds": 1.5}
    assert g.onnx_graph == b"\x08\x01graph"
    assert g.max_depth == 1 and g.num_trees == 2 and g.num_leaves == 3
    assert g.offset_scale(100.0, 25.0) == (2.0, 0.5)


def test_shared_load_reads_each_file_version_once(tmp_path):
    import os

    path = tmp_path / "f.npz"
    save_forest(path, two_trees())
    a = load_forest_shared(path, expected_classes=CLASSES)
    assert load_forest_shared(path, expected_classes=CLASSES) is a  # read once, then shared
    assert load_forest_shared(str(path), CLASSES) is a
    assert np.array_equal(a.leaf_dist, load_forest(path).leaf_dist)
    with pytest.raises(ValueError):
        a.threshold[0] = 1.0  # shared: nobody may change it under the others
    with pytest.raises(ForestFormatError, match="classes differ"):
        load_forest_shared(path, expected_classes=("background", "b", "a"))
    # Replaced by another forest (new size and time): read and validated again.
    f = two_trees()
    f.threshold = np.array([0.5, 0, 0, 0], dtype=np.float32)
    f.stats = {"seconds": 12345.0}
    save_forest(path, f)
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    b = load_forest_shared(path, expected_classes=CLASSES)
    assert b is not a and float(b.threshold[0]) == 0.5
    # ... and an edited, now corrupt file fails as load_forest does.
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 2 * 10**9))
    with pytest.raises(ForestFormatError):
        load_forest_shared(path, expected_classes=CLASSES)
    with pytest.raises(ForestFormatError, match="not found"):
        load_forest_shared(tmp_path / "nope.npz")


def test_traversal_table_leaves_point_to_themselves():
    t = traversal_table(two_trees())
    assert t.shape == (4, 8) and t.dtype == np.float32
    assert t[0, 5] == 1 and t[0, 6] == 2 and t[0, 4] == np.float32(0.25)
    for leaf in (1, 2, 3):
        assert t[leaf, 5] == leaf and t[leaf, 6] == leaf and np.isinf(t[leaf, 4])
        assert not t[leaf, :4].any()
    assert list(t[1:, 7]) == [0, 1, 2]


def test_missing_file(tmp_path):
    with pytest.raises(ForestFormatError, match="not found"):
        load_forest(tmp_path / "nope.npz")


def test_not_an_npz(tmp_path):
    (tmp_path / "f.npz").write_text("hello")
    with pytest.raises(ForestFormatError, match="not an .npz"):
        load_forest(tmp_path / "f.npz")


def test_npz_that_is_not_a_forest(tmp_path):
    np.savez(tmp_path / "f.npz", depth=np.zeros(3))
    with pytest.raises(ForestFormatError, match="not a forest"):
        load_forest(tmp_path / "f.npz")


def test_truncated_file(tmp_path):
    save_forest(tmp_path / "f.npz", two_trees())
    data = (tmp_path / "f.npz").read_bytes()
    (tmp_path / "f.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ForestFormatError, match="truncated or corrupt"):
        load_forest(tmp_path / "f.npz")


def _rewrite(path, change):
    """Rewrite the npz with ``change(arrays, meta)`` applied (keeping the stored checksum)."""
    with np.load(path) as d:
        arrays = {k: d[k] for k in d.files}
    meta = json.loads(str(arrays.pop("meta")))
    checksum = str(arrays.pop("checksum"))
    checksum = change(arrays, meta) or checksum
    path.unlink()
    np.savez(path, meta=np.array(json.dumps(meta, sort_keys=True)), checksum=checksum, **arrays)


def test_checksum_mismatch(tmp_path):
    path = tmp_path / "f.npz"
    save_forest(path, two_trees())

    def edit(arrays, meta):
        arrays["threshold"] = arrays["threshold"] + 1

    _rewrite(path, edit)
    with pytest.raises(ForestFormatError, match="checksum mismatch"):
        load_forest(path)


def test_newer_version(tmp_path):
    path = tmp_path / "f.npz"
    save_forest(path, two_trees())

    def edit(arrays, meta):
        meta["version"] = FOREST_VERSION + 1
        return forest_checksum(arrays, json.dumps(meta, sort_keys=True))

    _rewrite(path, edit)
    with pytest.raises(ForestFormatError, match=f"version {FOREST_VERSION + 1} is newer"):
        load_forest(path)


def test_class_set_mismatch(tmp_path):
    save_forest(tmp_path / "f.npz", two_trees())
    with pytest.raises(ForestFormatError, match=r"extra \['a', 'b'\], missing \['c'\]"):
        load_forest(tmp_path / "f.npz", expected_classes=("background", "c"))
    with pytest.raises(ForestFormatError, match="another order"):
        load_forest(tmp_path / "f.npz", expected_classes=("background", "b", "a"))


def test_invalid_trees_are_rejected(tmp_path):
    f = two_trees()
    f.left[0] = 9
    with pytest.raises(ForestFormatError, match="outside"):
        save_forest(tmp_path / "f.npz", f)
    f = two_trees()
    f.leaf[0] = 0
    with pytest.raises(ForestFormatError, match="leaves must"):
        f.validate()


def test_save_is_atomic_and_a_zip(tmp_path):
    save_forest(tmp_path / "f.npz", two_trees())
    assert zipfile.is_zipfile(tmp_path / "f.npz")
    assert [p.name for p in tmp_path.iterdir()] == ["f.npz"]
