"""Depth-gated posterior smoothing: golden values, the depth gate, image borders, the stride,
and that the forest classifier and its evaluation apply it."""

from __future__ import annotations

import pytest
import torch
from depthmocap.shared.posterior_smoothing import smooth_posteriors


def _grid(depth: torch.Tensor, probs_hw: torch.Tensor, mask: torch.Tensor | None = None):
    """(N, 3) pixels and (N, C) posteriors of the masked pixels of one (H, W) frame."""
    mask = torch.ones_like(depth, dtype=torch.bool) if mask is None else mask
    pix = torch.nonzero(mask[None])
    return pix, probs_hw[pix[:, 1], pix[:, 2]]


def test_window_one_is_the_identity_and_even_windows_are_rejected():
    depth = torch.full((1, 4, 5), 2.0)
    pix, probs = _grid(depth[0], torch.rand(4, 5, 3))
    assert smooth_posteriors(pix, probs, depth, 1, 0.05) is probs
    empty = torch.zeros(0, 3, dtype=torch.int64)
    assert smooth_posteriors(empty, torch.zeros(0, 3), depth, 5, 0.05).shape == (0, 3)
    with pytest.raises(ValueError, match="odd"):
        smooth_posteriors(pix, probs, depth, 4, 0.05)


def test_golden_values_on_a_flat_patch_with_one_speckle():
    """A 3 x 3 patch of class 0 with a class-1 speckle in its centre: every pixel's 3 x 3 mean
    counts the speckle once among its in-image neighbours (4 at corners, 6 at edges, 9 in the
    centre), so the speckle is voted down."""
    depth = torch.full((1, 3, 3), 2.0)
    probs_hw = torch.zeros(3, 3, 2)
    probs_hw[..., 0] = 1.0
    probs_hw[1, 1] = torch.tensor([0.0, 1.0])
    pix, probs = _grid(depth[0], probs_hw)
    out = smooth_posteriors(pix, probs, depth, 3, 0.05).view(3, 3, 2)
    expected_speckle = torch.tensor([[1 / 4, 1 / 6, 1 / 4], [1 / 6, 1 / 9, 1 / 6],
                                     [1 / 4, 1 / 6, 1 / 4]])  # fmt: skip
    torch.testing.assert_close(out[..., 1], expected_speckle)
    torch.testing.assert_close(out.sum(-1), torch.ones(3, 3))  # still distributions
    assert bool((out.argmax(-1) == 0).all())


def test_the_depth_gate_keeps_a_hand_off_the_chest():
    """Left columns: a hand at 1.5 m (class 1); right columns: the chest at 2.0 m (class 0).
    With the gate nothing crosses the depth edge; without it (a huge gate) it does."""
    depth = torch.full((1, 4, 6), 2.0)
    depth[0, :, :2] = 1.5
    probs_hw = torch.zeros(4, 6, 2)
    probs_hw[:, :2, 1] = 1.0
    probs_hw[:, 2:, 0] = 1.0
    pix, probs = _grid(depth[0], probs_hw)
    gated = smooth_posteriors(pix, probs, depth, 5, 0.05)
    torch.testing.assert_close(gated, probs)
    mixed = smooth_posteriors(pix, probs, depth, 5, 10.0).view(4, 6, 2)
    assert float(mixed[0, 2, 1]) > 0.3  # the chest pixel beside the hand now votes hand


def test_unclassified_pixels_and_other_frames_are_not_averaged_in():
    depth = torch.full((2, 3, 3), 2.0)
    mask = torch.zeros(2, 3, 3, dtype=torch.bool)
    mask[0, 1, 1] = mask[0, 1, 2] = True
    mask[1, 1, 1] = True
    pix = torch.nonzero(mask)
    probs = torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.25, 0.75]])
    out = smooth_posteriors(pix, probs, depth, 3, 0.05)
    torch.testing.assert_close(out, torch.tensor([[0.5, 0.5], [0.5, 0.5], [0.25, 0.75]]))


def test_the_window_steps_over_a_stride():
    """Classified every second pixel: with stride 2 the 3 x 3 box reaches the classified
    neighbours two pixels away; with stride 1 it finds none."""
    depth = torch.full((1, 5, 5), 2.0)
    mask = torch.zeros(1, 5, 5, dtype=torch.bool)
    mask[:, ::2, ::2] = True
    pix = torch.nonzero(mask)
    probs = torch.zeros(len(pix), 2)
    probs[:, 0] = 1.0
    centre = int(((pix[:, 1] == 2) & (pix[:, 2] == 2)).nonzero())
    probs[centre] = torch.tensor([0.0, 1.0])
    torch.testing.assert_close(smooth_posteriors(pix, probs, depth, 3, 0.05), probs)
    strided = smooth_posteriors(pix, probs, depth, 3, 0.05, stride=2)
    torch.testing.assert_close(strided[centre], torch.tensor([8 / 9, 1 / 9]))


@pytest.mark.parametrize("stride", [1, 2])
def test_the_compiled_smoothing_matches_torch(stride):
    """The numba loop (the CPU path) against the torch code: the same posteriors to float32
    rounding on a random batch of frames with holes, depth steps at the gate and image
    borders, and the same arg-max labels."""
    pytest.importorskip("numba")
    from depthmocap.shared.posterior_smoothing import smooth_posteriors_torch
    from depthmocap.shared.smoothing_kernel import smooth_posteriors_cpu

    gen = torch.Generator().manual_seed(stride)
    depth = 2.0 + 0.1 * torch.randint(0, 3, (2, 30, 40), generator=gen).float()
    valid = torch.rand(2, 30, 40, generator=gen) < 0.7
    if stride > 1:
        lattice = torch.zeros_like(valid)
        lattice[:, ::stride, ::stride] = True
        valid &= lattice
    pix = valid.nonzero()
    probs = torch.softmax(3 * torch.randn(pix.shape[0], 20, generator=gen), 1)
    for window, gate in ((3, 0.05), (5, 0.15), (5, 10.0)):
        got = smooth_posteriors_cpu(pix, probs, depth, window, gate, stride)
        want = smooth_posteriors_torch(pix, probs, depth, window, gate, stride)
        assert got.dtype == want.dtype
        torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-7)
        assert torch.equal(got.argmax(1), want.argmax(1))
    # A NaN depth at a classified pixel is out of every gate, its own included, in both.
    v, u = pix[0, 1:].tolist()
    depth[pix[0, 0], v, u] = float("nan")
    got = smooth_posteriors_cpu(pix, probs, depth, 3, 0.05, stride)
    torch.testing.assert_close(got, smooth_posteriors_torch(pix, probs, depth, 3, 0.05, stride))
    assert bool((got[0] == 0).all())
