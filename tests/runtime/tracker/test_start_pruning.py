"""Early rejection of a batched refit's starts: the kept starts' fits are the whole batch's."""

from __future__ import annotations

import pytest
import torch
from depthmocap.runtime.tracker import Tracker, TrackerConfig, TrackerError
from depthmocap.runtime.tracker.extra_depth_term import ObservedCandidates
from depthmocap.runtime.tracker.start_pruning import (
    StartPruning,
    starts_to_keep,
    subset_candidates,
    subset_observation,
)
from depthmocap.runtime.tracker.tracker import expand_observation, fit_frames
from depthmocap.shared.body import BodyShape
from depthmocap.shared.camera import Intrinsics

INTR = Intrinsics.kinect_v1(320)


def _starts(truth: torch.Tensor, count: int, seed: int) -> torch.Tensor:
    """Starts around frame 1's pose, the worse the later: start k is off by about k * 4 cm."""
    gen = torch.Generator().manual_seed(seed)
    scale = torch.arange(count, dtype=truth.dtype)[:, None]
    starts = truth[1][None] + 0.06 * scale * torch.randn(count, 34, generator=gen).to(truth)
    starts[:, :3] = truth[1, :3] + 0.04 * scale * torch.randn(count, 3, generator=gen).to(truth)
    return starts


class TestPrunedFit:
    @pytest.mark.parametrize("after, keep", [(1, 3), (2, 2), (1, 1)])
    def test_kept_starts_fit_as_in_the_whole_batch(self, render_sequence, after, keep):
        """The kept starts are the best by the score after ``after`` iterations, and their
        fits, signals and steps are those of the unpruned batch, exactly."""
        body, truth, depth, mask = render_sequence("wave", 2, torch.float64)
        tracker = Tracker(body, INTR, TrackerConfig(iterations=4), dtype=torch.float64)
        obs = tracker.observe(depth[1], mask[1])
        starts = _starts(truth, 6, 4)
        whole = tracker.fit_starts(obs, starts)
        prune = StartPruning(after, keep, overlap_weight_cm=10.0)
        pruned = tracker.fit_starts(obs, starts, prune=prune)
        assert len(pruned) == keep
        # Which starts were kept: the fit of each kept start equals one of the whole batch's.
        kept = []
        for r in pruned:
            match = [k for k, w in enumerate(whole) if torch.equal(w.q, r.q)]
            assert len(match) == 1
            k = match[0]
            kept.append(k)
            assert r.depth_error_cm == whole[k].depth_error_cm
            assert r.overlap == whole[k].overlap
            assert r.iterations == whole[k].iterations
        assert kept == sorted(kept)  # the starts' order
        assert 0 in kept  # the start at the truth fits best at any cut

        # The same from fit_frames, with the kept indices reported.
        fit = fit_frames(
            expand_observation(obs, 6), starts, None, tracker.body, tracker.cfg,
            tracker.geometry, prune,
        )  # fmt: skip
        assert fit.kept.tolist() == kept and fit.q.shape == (keep, 34)

    def test_no_cut_when_all_are_kept_or_the_fit_ends_first(self, render_sequence):
        body, truth, depth, mask = render_sequence("wave", 2, torch.float64)
        tracker = Tracker(body, INTR, TrackerConfig(iterations=2), dtype=torch.float64)
        obs = tracker.observe(depth[1], mask[1])
        starts = _starts(truth, 4, 1)
        whole = tracker.fit_starts(obs, starts)
        for prune in (StartPruning(1, 4), StartPruning(2, 1), StartPruning(5, 1)):
            same = tracker.fit_starts(obs, starts, prune=prune)
            assert [torch.equal(a.q, b.q) for a, b in zip(whole, same, strict=True)] == [True] * 4

    def test_needs_one_body(self, render_sequence):
        body, truth, depth, mask = render_sequence("wave", 2, torch.float64)
        bodies = body.scaled(torch.tensor([0.9, 1.0, 1.1], dtype=torch.float64))
        sizes = Tracker(bodies, INTR, dtype=torch.float64)
        obs = sizes.observe(depth[1], mask[1])
        with pytest.raises(TrackerError, match="one body"):
            sizes.fit_starts(obs, truth[1][None].expand(3, -1), prune=StartPruning(1, 1))

    def test_settings_are_checked(self):
        for bad in ((0, 1), (1, 0), (1, 1, -1.0), (1, 1, float("nan"))):
            with pytest.raises(ValueError):
                StartPruning(*bad)


def test_starts_to_keep_lowest_in_index_order():
    scores = torch.tensor([3.0, 1.0, float("nan"), 1.0, 0.5], dtype=torch.float64)
    assert starts_to_keep(scores, 2).tolist() == [1, 4]
    assert starts_to_keep(scores, 3).tolist() == [1, 3, 4]  # ties: the lower index first
    assert starts_to_keep(scores, 5).tolist() == [0, 1, 2, 3, 4]  # NaN last


def test_subset_candidates_renumbers_the_kept_poses():
    batch = torch.tensor([0, 0, 1, 2, 2, 2, 3])
    points = torch.arange(21, dtype=torch.float32).reshape(7, 3)
    sub = subset_candidates(ObservedCandidates(batch, points), torch.tensor([1, 2]))
    assert sub.batch.tolist() == [0, 1, 1, 1]
    torch.testing.assert_close(sub.points, points[2:6])
    empty = ObservedCandidates(torch.zeros(0, dtype=torch.long), torch.zeros(0, 3))
    assert subset_candidates(empty, torch.tensor([0])).batch.numel() == 0


def test_subset_observation_keeps_views_of_one_frame(render_frame, make_pose):
    obs = render_frame(make_pose(), BodyShape.default(torch.float64))
    views = expand_observation(obs, 5)
    sub = subset_observation(views, torch.tensor([1, 3]))
    assert sub.depth.shape[0] == 2 and sub.depth.stride(0) == 0
    torch.testing.assert_close(sub.points[1], obs.points[0])
