"""200 seeded corruptions of a recording and of a forest through ``runtime-track`` (issue 36).

Whatever is wrong with the input (bytes, sizes, JSON fields, missing files, symbolic links),
a run ends with exit 0 or 2, at most one ``error:`` line and no traceback, and whatever it
wrote is a valid partial result.
"""

from __future__ import annotations

import json
import random
import shutil
from pathlib import Path

import depthmocap.runtime.track_cli as cli
import numpy as np
import pytest
from depthmocap.shared.camera import Intrinsics
from depthmocap.shared.forest_format import Forest, save_forest
from depthmocap.shared.labels import PART_NAMES
from depthmocap.shared.recording import RecordingWriter
from depthmocap.shared.skeleton import JOINT_NAMES, NUM_DOFS

INTR = Intrinsics.kinect_v1(80)  # 80 x 60: a run takes a few tens of milliseconds
CASES = 200


def _person(z_mm: int) -> np.ndarray:
    u, v = np.meshgrid(np.arange(INTR.width), np.arange(INTR.height))
    z = z_mm / 1000
    x, y = (u - INTR.cx) / INTR.fx * z, (v - INTR.cy) / INTR.fy * z
    return np.where((np.abs(x) < 0.25) & (y > -0.8) & (y < 0.9), z_mm, 0).astype(np.uint16)


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("pristine")
    rec = root / "rec"
    with RecordingWriter(rec, INTR, fps=30.0, source="fuzz") as w:
        for z in (2500, 2520, 2540):
            w.write_frame(_person(z))
        q = np.zeros((3, NUM_DOFS))
        q[:, 2], q[:, 3], q[:, 1] = 2.5, np.pi, 0.05
        w.write_groundtruth(np.zeros((3, len(JOINT_NAMES), 3)), list(JOINT_NAMES), q=q)
    # A one-split forest: far from useful, but the whole format and its loader.
    C = len(PART_NAMES)
    dist = np.full((2, C), 0.5 / (C - 1), np.float16)
    dist[0, 1] = dist[1, 5] = 0.5
    forest = Forest(
        u=[[1.0, 0.0], [0, 0], [0, 0]], v=[[-1.0, 0.0], [0, 0], [0, 0]],
        threshold=[0.01, 0, 0], left=[1, -1, -1], right=[2, -1, -1], leaf=[-1, 0, 1],
        leaf_dist=dist, roots=[0], class_names=PART_NAMES,
        camera=dict(INTR.as_dict()),
    )  # fmt: skip
    save_forest(root / "forest.npz", forest)
    return rec, root / "forest.npz"


# ---- mutations: each takes (rng, recording dir, forest path) and changes one thing --------


def _frame(rng, rec):
    return rec / "depth" / f"{rng.randrange(3):06d}.png"


def flip_bytes(rng, rec, forest):
    target = _frame(rng, rec) if rng.random() < 0.6 else forest
    data = bytearray(target.read_bytes())
    for _ in range(rng.randint(1, 8)):
        data[rng.randrange(len(data))] = rng.randrange(256)
    target.write_bytes(bytes(data))


def truncate(rng, rec, forest):
    target = rng.choice([_frame(rng, rec), forest, rec / "meta.json", rec / "groundtruth.npz"])
    data = target.read_bytes()
    target.write_bytes(data[: rng.randrange(len(data))])


def remove(rng, rec, forest):
    rng.choice([_frame(rng, rec), forest, rec / "meta.json", rec / "groundtruth.npz"]).unlink()


def meta_field(rng, rec, forest):
    meta = json.loads((rec / "meta.json").read_text())
    key = rng.choice(sorted(meta))
    meta[key] = rng.choice([None, -1, 0, 1e9, "x", [], {}, True, 3.5, -0.0])
    (rec / "meta.json").write_text(json.dumps(meta))


def meta_missing_key(rng, rec, forest):
    meta = json.loads((rec / "meta.json").read_text())
    meta.pop(rng.choice(sorted(meta)))
    (rec / "meta.json").write_text(json.dumps(meta))


def meta_not_json(rng, rec, forest):
    (rec / "meta.json").write_text(rng.choice(["", "{", "[]", "null", "\x00\xff", "{'a': 1}"]))


def frame_size(rng, rec, forest):
    import cv2

    h, w = rng.choice([(INTR.height // 2, INTR.width), (INTR.height, INTR.width + 1), (1, 1)])
    image = np.full((h, w), 2500, np.uint16)
    if rng.random() < 0.3:
        image = image.astype(np.uint8)
    cv2.imwrite(str(_frame(rng, rec)), image)


def links(rng, rec, forest):
    target = rng.choice([_frame(rng, rec), rec / "meta.json", forest])
    target.unlink()
    if rng.random() < 0.5:
        target.symlink_to(target)  # a loop
    else:
        target.symlink_to(target.parent / "nowhere")


def depth_dir(rng, rec, forest):
    shutil.rmtree(rec / "depth")
    if rng.random() < 0.5:
        (rec / "depth").write_text("not a folder")


def forest_meta(rng, rec, forest):
    with np.load(forest) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"]))
    key = rng.choice(["version", "format", "class_names", "camera", "num_trees", "background_m"])
    meta[key] = rng.choice([99, "other", [], {}, None, -1])
    arrays["meta"] = np.array(json.dumps(meta))
    if rng.random() < 0.5:  # a forger who also fixes the checksum
        from depthmocap.shared.forest_format import forest_checksum

        rest = {k: v for k, v in arrays.items() if k not in ("meta", "checksum")}
        arrays["checksum"] = np.array(forest_checksum(rest, str(arrays["meta"])))
    np.savez(forest, **arrays)


def forest_array(rng, rec, forest):
    with np.load(forest) as z:
        arrays = {k: z[k] for k in z.files}
    key = rng.choice(["u", "left", "right", "leaf", "leaf_dist", "roots", "threshold"])
    arrays[key] = rng.choice([arrays[key][:1], arrays[key] * -7, np.zeros((0,), np.int32)])
    from depthmocap.shared.forest_format import forest_checksum

    rest = {k: v for k, v in arrays.items() if k not in ("meta", "checksum")}
    arrays["checksum"] = np.array(forest_checksum(rest, str(arrays["meta"])))
    np.savez(forest, **arrays)


MUTATIONS = (flip_bytes, truncate, remove, meta_field, meta_missing_key, meta_not_json,
             frame_size, links, depth_dir, forest_meta, forest_array)  # fmt: skip


def check_partial_result(out: Path) -> None:
    """Whatever a run left in ``out`` reads back: every poses line, the summary."""
    if not out.exists():
        return
    lines = (out / "poses.jsonl").read_text().splitlines()
    frames = [json.loads(line)["frame"] for line in lines]
    assert frames == sorted(frames)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == len(lines)


def test_two_hundred_corruptions_end_cleanly(pristine, tmp_path, capfd):
    rec0, forest0 = pristine
    seen = []
    for case in range(CASES):
        rng = random.Random(case)
        work = tmp_path / f"case{case}"
        rec, forest = work / "rec", work / "forest.npz"
        shutil.copytree(rec0, rec)
        shutil.copy(forest0, forest)
        mutation = MUTATIONS[case % len(MUTATIONS)]
        mutation(rng, rec, forest)
        mode = "tracker" if case % 2 else "detector"
        out = work / "out"
        argv = ["-i", str(rec), "-o", str(out), "--mode", mode, "--model", str(forest), "-q"]
        where = f"case {case} ({mutation.__name__}, {mode})"
        try:
            code = cli.main(argv)
        except BaseException as err:  # noqa: BLE001 - what escapes main is the failure
            pytest.fail(f"{where}: {type(err).__name__}: {err}")
        err = capfd.readouterr().err
        assert code in (0, 2), (where, code, err)
        assert "Traceback" not in err and "libpng" not in err, (where, err)
        assert sum(line.startswith("error: ") for line in err.splitlines()) <= 1, (where, err)
        assert (code == 2) == ("error: " in err), (where, err)
        check_partial_result(out)
        seen.append(code)
    assert 0 in seen and 2 in seen  # both clean ends happen
