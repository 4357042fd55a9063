"""Real UTD-MHAD takes from ../shared (skipped without them): the imported geometry against the
real silhouettes, and the shipped system tracking a few real frames close to the Kinect SDK's
skeleton after offset normalization."""

from __future__ import annotations

import numpy as np
import pytest
from depthmocap.shared.recording import Recording, mapped_reference
from depthmocap.train.evaluation.evaluate import evaluate
from depthmocap.train.evaluation.overlay_sheet import project
from depthmocap.train.importers import utd_mhad as utd
from depthmocap.train.importers.cli import main as import_main

pytestmark = pytest.mark.shareddata


@pytest.fixture
def utd_root(shared_data):
    root = shared_data / "real" / "utd_mhad"
    if not (root / "Depth").is_dir():
        pytest.skip("../shared/data/real/utd_mhad is not present")
    return root


def _import(root, out, action: int, subject: int, frames: int):
    args = ["--utd-mhad", str(root), "--out", str(out), "-q", "--actions", str(action),
            "--subjects", str(subject), "--trials", "1", "--max-frames", str(frames)]  # fmt: skip
    assert import_main(args) == 0
    return Recording(out / f"a{action:02d}_s{subject}_t1")


def _on_silhouette(rec: Recording, joints: np.ndarray) -> tuple[float, float]:
    """Share of joints (F, J, 3) that project onto a body pixel, and the mean column offset
    of the torso joints (neck, spine, pelvis) from the middle of the body's run of pixels on
    their row (positive: the silhouette lies to the right of the joints)."""
    hits, offsets = [], []
    for f in range(len(rec)):
        body = rec.read_depth_mm(f) > 0
        px = np.round(project(joints[f], rec.intrinsics)).astype(int)
        for j, (u, v) in enumerate(px):
            inside = 0 <= v < body.shape[0] and 0 <= u < body.shape[1] and body[v, u]
            hits.append(inside)
            if inside and j in (1, 2, 3):
                row = body[v]
                left, right = u, u
                while left > 0 and row[left - 1]:
                    left -= 1
                while right < len(row) - 1 and row[right + 1]:
                    right += 1
                offsets.append((left + right) / 2 - u)
    return float(np.mean(hits)), float(np.mean(offsets))


@pytest.mark.parametrize("action, subject", [(22, 1), (27, 3)])
def test_reference_joints_land_on_the_unmirrored_silhouette(utd_root, tmp_path, action, subject):
    rec = _import(utd_root, tmp_path, action, subject, frames=10)
    joints, names = mapped_reference(rec.reference())
    share, offset = _on_silhouette(rec, joints)
    # The SDK's joints lie 3-12 cm inside the body: nearly all project onto it.
    assert share > 0.9, share
    # Across all 192 takes the silhouette's middle sits 1-2 px to the side of the SDK's torso
    # joints (the SDK's own bias, the same either side of the flip, docs/real_data.md); a
    # lost flip of x would put the joints ~10-20 px off the person.
    assert abs(offset) < 4, offset
    unflipped = joints * [-1, 1, 1]  # the mirrored x: the flip of the depth without that of x
    assert _on_silhouette(rec, unflipped)[0] < share - 0.2
    # A person facing the camera has their left shoulder on the image's right.
    u = project(joints[0], rec.intrinsics)[:, 0]
    assert u[names.index("l_shoulder")] > u[names.index("r_shoulder")] + 10


def test_shipped_system_agrees_with_the_kinect_sdk_on_real_frames(utd_root, tmp_path):
    from depthmocap.runtime.track_cli import main as track_main

    rec = _import(utd_root, tmp_path, 27, 1, frames=10)
    result = tmp_path / "result"
    # Fully automatic: no body, no settings, no start pose (the recording has no ground truth).
    assert track_main(["--input", str(rec.path), "--output", str(result), "-q",
                       "--threads", "1", "--device", "cpu"]) == 0  # fmt: skip
    ev = evaluate(rec.path, result)
    r = ev.report
    assert r["truth"] == "reference" and r["frames_with_pose"] == 10
    assert len(r["joints"]) == 16
    worst = np.nanmax(ev.norm_errors_m, axis=0)
    far = {n: round(float(w), 3) for n, w in zip(ev.joint_names, worst) if not w < 0.25}
    assert not far, f"joints beyond 25 cm of the reference after normalization: {far}"
    # Raw, before normalization: the two trackers' joint definitions differ by up to ~15 cm
    # (the SDK's spine sits low on the back), but a swapped side would be 30 cm off.
    raw = r["per_joint_error_mm"]
    assert all(v < 200 for v in raw.values()), raw


def test_the_stored_depth_runs_two_frames_behind_the_skeleton(utd_root, tmp_path):
    from depthmocap.train.evaluation.reference_lag import refuted_by_lag

    # Two fast takes, imported as stored (index by index).
    lags, counts = [0, 1, 2, 3], 0
    for action in (5, 17):
        args = ["--utd-mhad", str(utd_root), "--out", str(tmp_path), "-q", "--actions",
                str(action), "--subjects", "1", "--trials", "1", "--skeleton-lag", "0"]  # fmt: skip
        assert import_main(args) == 0
        rec = Recording(tmp_path / f"a{action:02d}_s1_t1")
        reference, _ = mapped_reference(rec.reference())
        depth = [rec.read_depth(i) for i in range(len(rec))]
        counts = counts + refuted_by_lag(depth, reference, rec.intrinsics, lags)
    # The depth image alone refutes the SDK's joints far less often two frames later (the
    # importer's default pairing) than index by index: 58, 15, 8, 42 when this was written.
    assert int(np.argmin(counts)) == lags.index(utd.SKELETON_LAG_FRAMES), counts
    assert counts[2] < counts[0] / 3, counts
