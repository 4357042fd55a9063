"""The tracker's extra depth term (runtime.tracker.extra_depth_term): it pulls the model towards
the observation, weighs torso and limb offsets by their own scales, and its closest-point
search respects the depth gate and the batch."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from depthmocap.runtime.raycast import render_body
from depthmocap.runtime.tracker import TrackerConfig, extra_depth_term
from depthmocap.runtime.tracker.extra_depth_term import (
    closest_points,
    closest_points_torch,
    extra_rows,
    observed_candidates,
)
from depthmocap.runtime.tracker.gauss_newton import normal_equations, solve_step
from depthmocap.runtime.tracker.regions import classify
from depthmocap.shared import skeleton as sk
from depthmocap.shared.body import BodyShape

D = {n: i for i, n in enumerate(sk.DOF_NAMES)}

pytestmark = pytest.mark.usefixtures("one_thread")


class TestExtraRows:
    def test_pulls_the_model_towards_the_observation(self, make_pose, render_frame):
        body = BodyShape.default(torch.float64)
        truth = make_pose()
        q = truth.clone()
        q[0, D["l_humerus_abd"]] += 0.35  # arm 10 cm off: B1/B3 bands wider than the margin
        obs = render_frame(truth, body)
        render = render_body(q, body, obs.intr)
        regions = classify(render, obs, 0.08, True)
        cfg = TrackerConfig()
        extra = extra_rows(render, obs, regions, observed_candidates(obs, 5000), cfg, 1)
        rows = extra.rows
        assert len(rows) > 0 and bool((rows.weight > 0).any())
        # Solving the extra term alone (plus damping) lowers the arm.
        hess, grad = normal_equations(render.kin, rows, 1)
        dq = solve_step(hess + 1e-2 * torch.eye(34, dtype=torch.float64), grad, q, 1e-3)
        assert float(dq[0, D["l_humerus_abd"]]) < -0.05
        assert float(extra.error_sum[0] / extra.count[0]) > 0.01

    def test_weighs_torso_and_limb_offsets_by_their_own_scales(
        self, monkeypatch, make_pose, render_frame
    ):
        body = BodyShape.default(torch.float64)
        truth = make_pose()
        q = truth.clone()
        q[0, D["l_humerus_abd"]] += 0.35  # the arm off
        q[0, D["root_tx"]] += 0.04  # and the whole body: torso offsets too
        obs = render_frame(truth, body)
        render = render_body(q, body, obs.intr)
        regions = classify(render, obs, 0.08, True)
        observed = observed_candidates(obs, 5000)
        cfg = TrackerConfig(sigma_extra_m=0.005)
        monkeypatch.setattr(extra_depth_term, "SIGMA_EXTRA_TORSO_M", 0.005)
        rows = extra_rows(render, obs, regions, observed, cfg, 1).rows
        torso = rows.segment < sk.SEGMENT_NAMES.index("l_upper_arm")
        assert bool((torso & (rows.weight > 0)).any()) and bool((~torso & (rows.weight > 0)).any())
        monkeypatch.setattr(extra_depth_term, "SIGMA_EXTRA_TORSO_M", 0.04)
        scaled = extra_rows(render, obs, regions, observed, cfg, 1).rows
        # Same correspondences; torso rows weigh 8 times less, limb rows the same.
        assert torch.equal(scaled.residual, rows.residual)
        torch.testing.assert_close(scaled.weight[torso], rows.weight[torso] / 8)
        torch.testing.assert_close(scaled.weight[~torso], rows.weight[~torso])


def test_the_compiled_term_gives_the_torch_rows_bit_for_bit(
    assert_same_rows, monkeypatch, off_truth_batch
):
    """runtime.tracker.extra_kernel (the whole term in one compiled call, float32) against
    the torch code it replaces: the same rows, error sums and counts to the bit, for a batch
    of poses off the truth by different amounts (every correspondence type)."""
    pytest.importorskip("depthmocap.runtime.tracker.extra_kernel")
    changes = [{"l_humerus_abd": 0.35}, {"root_tx": 0.05, "r_femur_flex": -0.4}]
    _, obs, _, render = off_truth_batch(changes)
    regions = classify(render, obs, 0.08, True)
    cfg = TrackerConfig()
    observed = observed_candidates(obs, 800)  # thinned: the sampling ratios matter too
    got = extra_rows(render, obs, regions, observed, cfg, 3)
    with monkeypatch.context() as m:  # the torch code (its sampling and search compiled)
        m.setattr(extra_depth_term, "compiled_float32", lambda name, *t: None)
        want = extra_rows(render, obs, regions, observed, cfg, 3)
    assert len(want.rows) > 0 and bool((want.rows.weight > 0).any())
    assert bool((want.rows.weight == 0).any())  # unmatched queries too
    assert_same_rows(got.rows, want.rows)
    assert torch.equal(got.error_sum, want.error_sum) and torch.equal(got.count, want.count)


class TestClosestPoints:
    @pytest.fixture(params=["dispatch", "torch"])
    def closest_points(self, request):
        """Both the dispatching search (numba's loop on the CPU when installed) and torch's."""
        return closest_points if request.param == "dispatch" else closest_points_torch

    def test_golden(self, closest_points):
        """The closest points respect the depth gate and the batch."""
        query = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0], [1.0, 0.0, 2.0]])
        qb = torch.tensor([0, 1, 0])
        cand = torch.tensor([[0.01, 0.0, 2.0], [0.0, 0.0, 2.05], [0.0, 0.0, 2.5], [1.0, 0.0, 2.2]])
        cb = torch.tensor([0, 1, 0, 0])
        idx, found = closest_points(query, qb, cand, cb, depth_gate=0.08, max_distance=0.3)
        assert idx[:2].tolist() == [0, 1] and found.tolist() == [True, True, False]

    def test_poses_never_match_each_other(self, closest_points):
        """Each query is matched within its own pose only, whatever the distances, and a
        pose without candidates finds nothing."""
        gen = torch.Generator().manual_seed(0)
        query, cand = torch.rand(30, 3, generator=gen), torch.rand(50, 3, generator=gen)
        qb = torch.randint(0, 3, (30,), generator=gen)
        cb = torch.randint(0, 2, (50,), generator=gen)  # pose 2 has no candidates
        idx, found = closest_points(query, qb, cand, cb, depth_gate=10.0, max_distance=10.0)
        for n in range(30):
            own = (cb == qb[n]).nonzero()[:, 0]
            if own.numel() == 0:
                assert not found[n]
                continue
            best = own[(cand[own] - query[n]).norm(dim=-1).argmin()]
            assert found[n] and int(idx[n]) == int(best)

    def test_the_compiled_search_matches_torch(self):
        """Random scenes of several poses with the depth and distance gates biting: the same
        candidates as torch's table, in float32 and float64."""
        kernel = pytest.importorskip("depthmocap.runtime.tracker.closest_kernel")
        gen = torch.Generator().manual_seed(1)
        for dtype in (torch.float32, torch.float64):
            query = torch.rand(400, 3, generator=gen, dtype=dtype) * torch.tensor([1, 1, 0.6])
            cand = torch.rand(900, 3, generator=gen, dtype=dtype) * torch.tensor([1, 1, 0.6])
            qb = torch.randint(0, 4, (400,), generator=gen)
            cb = torch.randint(0, 3, (900,), generator=gen)  # pose 3: no candidates
            want = closest_points_torch(query, qb, cand, cb, depth_gate=0.05, max_distance=0.08)
            got = kernel.closest_points_cpu(query, qb, cand, cb, 0.05, 0.08)
            assert torch.equal(got[1], want[1]) and bool(got[1].any()) and not bool(got[1].all())
            assert torch.equal(got[0][got[1]], want[0][want[1]])

    def test_the_compiled_search_is_the_exact_nearest(self):
        """Against brute force in float64: the smallest squared distance within the gates,
        ties to the smallest index, in scenes built to break a grid search: exact ties on a
        lattice, candidates with NaN coordinates or depths, queries far outside the
        candidates' box or without depth, candidates on a line (a degenerate box), empty
        poses."""
        kernel = pytest.importorskip("depthmocap.runtime.tracker.closest_kernel")
        rng = np.random.default_rng(0)
        for trial in range(120):
            nq, nc, poses = int(rng.integers(1, 200)), int(rng.integers(1, 400)), 3
            q = (rng.random((nq, 3)) * [0.8, 1.8, 0.6]).astype(np.float32)
            c = (rng.random((nc, 3)) * [0.8, 1.8, 0.6]).astype(np.float32)
            if trial % 3 == 0:  # a 5 cm lattice: many candidates at exactly equal distances
                q, c = np.round(q * 20) / 20, np.round(c * 20) / 20
            if trial % 4 == 1:
                c[:, 0] = 0.25  # a vertical line of candidates
            if trial % 5 == 2:
                c[: nc // 4, 1] = np.nan
            if trial % 7 == 3:
                q[: nq // 3, :2] += 3.0  # far outside the box
            if trial % 6 == 4:  # no depth: never within the gate (nor in a cell's range)
                c[: nc // 5, 2] = np.nan
                q[: nq // 5, 2] = np.nan
            qb = rng.integers(0, poses, nq)
            cb = rng.integers(0, poses - 1, nc)  # the last pose has no candidates
            gate, max_d2 = float(rng.choice([0.03, 0.2, 10.0])), float(rng.choice([0.01, 1.0]))
            index, found = kernel.closest_of(q, qb, c, cb, gate, max_d2)
            q64, c64 = q.astype(np.float64), c.astype(np.float64)
            for i in range(nq):
                d = q64[i] - c64
                d2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
                ok = (cb == qb[i]) & (np.abs(d[:, 2]) <= gate) & (d2 <= max_d2)
                if not ok.any():
                    assert not found[i]
                    continue
                best = np.flatnonzero(ok & (d2 == d2[ok].min()))[0]
                assert found[i] and index[i] == best, (trial, i)
