"""Regions reaching a mask's outline (shared/mask_outline.py): golden masks."""

import numpy as np
import torch
from depthmocap.shared.mask_outline import mask_outline, reaching_outline


def test_outline_is_the_mask_pixels_beside_the_outside():
    mask = np.zeros((5, 6), bool)
    mask[1:4, 1:5] = True
    expected = mask.copy()
    expected[2, 2:4] = False
    np.testing.assert_array_equal(mask_outline(mask), expected)
    full = np.ones((3, 3), bool)  # the image border counts as outside
    np.testing.assert_array_equal(mask_outline(full), ~np.pad([[True]], 1))


def test_only_clutter_reaching_the_outline_leaves():
    mask = torch.zeros(12, 14, dtype=torch.bool)
    mask[1:11, 1:13] = True
    region = torch.zeros_like(mask)
    region[5:7, 5:7] = True  # inside the person: a doubtful patch of the body stays
    region[8:11, 9:11] = True  # reaches the silhouette's bottom edge: furniture
    region[2, 12] = True  # one pixel on the right edge
    kept = reaching_outline(region, mask)
    expected = region.clone()
    expected[5:7, 5:7] = False
    assert torch.equal(kept, expected)
    # batched like single frames; a mask that fills the image has the image border as outline
    both = reaching_outline(torch.stack([region, region]), torch.stack([mask, mask]))
    assert torch.equal(both[1], expected)
    full = torch.ones(4, 4, dtype=torch.bool)
    corner = torch.zeros_like(full)
    corner[0, 0] = True
    assert torch.equal(reaching_outline(corner, full), corner)
    assert not bool(reaching_outline(torch.zeros_like(full), full).any())
