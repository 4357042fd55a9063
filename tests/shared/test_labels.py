import numpy as np
from depthmocap.shared.labels import (
    NUM_CLASSES,
    PART_COLORS,
    PART_NAMES,
    PART_SEGMENT,
    segment_to_part,
)
from depthmocap.shared.skeleton import NUM_SEGMENTS, SEGMENT_NAMES


def test_nineteen_parts_plus_background():
    assert NUM_CLASSES == 20 and PART_NAMES[0] == "background"
    # Every segment has a part; legs have two.
    counts = np.bincount(PART_SEGMENT[1:], minlength=NUM_SEGMENTS)
    for k, name in enumerate(SEGMENT_NAMES):
        assert counts[k] == (2 if name.endswith(("thigh", "shank")) else 1)


def test_segment_to_part_split():
    thigh, arm = SEGMENT_NAMES.index("l_thigh"), SEGMENT_NAMES.index("r_upper_arm")
    got = segment_to_part(np.array([thigh, thigh, arm, arm, -1]), np.array([0.1, 0.6, 0.1, 0.9, 0]))
    names = [PART_NAMES[i] for i in got]
    assert names == ["l_thigh_upper", "l_thigh_lower", "r_upper_arm", "r_upper_arm", "background"]


def test_palette_distinct():
    assert len({tuple(c) for c in PART_COLORS}) == NUM_CLASSES
