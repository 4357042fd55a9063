"""Settings of person segmentation (:mod:`runtime.segmentation`)."""

from __future__ import annotations

from dataclasses import dataclass

from depthmocap.shared.config import ConfigError, field_doc

__all__ = ["SegmentationConfig"]


@dataclass
class SegmentationConfig:
    """How :func:`segment_person` finds the person in a depth frame."""

    min_depth_m: float = field_doc(0.4, help="nearest depth kept, metres")
    max_depth_m: float = field_doc(4.5, help="farthest depth kept, metres")
    remove_floor: bool = field_doc(True, help="fit and remove the floor plane")
    floor_region: float = field_doc(
        0.5, help="lower fraction of the image rows searched for floor points"
    )
    floor_band_m: float = field_doc(
        0.05, help="points less than this above the floor plane are floor, metres"
    )
    floor_max_tilt_deg: float = field_doc(
        45.0, help="largest angle between the floor normal and the camera's up axis (-y)"
    )
    floor_min_support: float = field_doc(
        0.05, help="fraction of sampled lower-image points the floor plane must explain"
    )
    floor_min_depth_span_m: float = field_doc(
        0.4,
        help="the floor's inliers must span this much depth (5-95 percentile), metres: a "
        "floor recedes from the camera, a slice through a body does not",
    )
    floor_max_below: float = field_doc(
        0.03,
        help="largest fraction of sampled points allowed below the floor plane (nothing "
        "stands under a floor; a plane slicing through the body has half of it below)",
    )
    floor_max_depth_gap_m: float = field_doc(
        0.25, help="largest gap between the depths of floor inliers (5-95 percentile), metres"
    )
    ransac_samples: int = field_doc(1024, help="points sampled per image for the floor fit")
    ransac_hypotheses: int = field_doc(96, help="plane hypotheses per image")
    ransac_score_samples: int = field_doc(
        256, help="sampled points each hypothesis is scored on (the winner is refined on all)"
    )
    edge_jump_m: float = field_doc(
        0.08, help="depth step between neighbours that separates surfaces, metres"
    )
    edge_jump_per_m2: float = field_doc(
        0.01, help="extra depth-step allowance per squared metre of depth (sensor noise ~ z^2)"
    )
    occluder_min_area_m2: float = field_doc(
        0.15,
        help="a component partly hidden behind a nearer one of at least this area is "
        "background (the wall behind the person), square metres; smaller occluders (a hand "
        "in front of the chest) do not count",
    )
    merge_radius_px: int = field_doc(
        3, help="components this close to the person (pixels) may join it (hands, forearms)"
    )
    merge_depth_margin_m: float = field_doc(
        0.1,
        help="a nearby component joins the person only if its mean depth is at most this "
        "much behind the person's: parts in front of the body join, the background never",
    )
    merge_max_area_fraction: float = field_doc(
        0.2,
        help="a joining component has at most this fraction of the person's metric area "
        "(a hand or forearm, not a second person)",
    )
    merge_max_front_m: float = field_doc(
        0.8, help="a joining component is at most this far in front of the person (arm reach)"
    )
    merge_rounds: int = field_doc(3, help="rounds of joining (hand -> forearm -> body chains)")
    min_area_m2: float = field_doc(
        0.04, help="smallest frontal area of a person, square metres (smaller: no person)"
    )
    max_width_m: float = field_doc(2.5, help="widest plausible person (x extent), metres")
    max_height_m: float = field_doc(2.6, help="tallest plausible person (y extent), metres")
    max_depth_extent_m: float = field_doc(1.5, help="deepest plausible person (z extent), metres")
    seed: int = field_doc(0, help="seed of the RANSAC sampling (results are deterministic)")
    keep_floor: bool = field_doc(
        True,
        help="in a stream, where a frame's floor fit fails, remove the previous frame's floor "
        "if it still explains the floor points (a crouching person can hide most of it)",
    )
    person_max_solidity: float = field_doc(
        0.8,
        help="components filling at most this share of their convex hull count with their "
        "full area when choosing the person (people: about 0.4-0.8)",
    )
    convex_solidity: float = field_doc(
        0.9,
        help="components at least this convex count with convex_weight of their area (boxes, "
        "doors, cupboards project to convex shapes); linear in between",
    )
    solidity_erosion_px: int = field_doc(
        1,
        help="measure a component's solidity without its fringe this many pixels deep: "
        "flying pixels along a box's edge make it look less convex (0: as it is)",
    )
    convex_weight: float = field_doc(
        0.05, help="weight of a convex component's area when choosing the person"
    )
    continuity_overlap: float = field_doc(
        0.3,
        help="in a stream, a component with at least this share of its pixels on the previous "
        "frame's person is the same person",
    )
    continuity_gain: float = field_doc(
        4.0, help="factor on the score of the previous frame's person (choices do not flip)"
    )
    clutter_model: str = field_doc(
        "",
        help="person/clutter forest that takes furniture left attached to the person out of "
        "the mask (runtime.segmentation.clutter; a bare file name is looked up in the "
        "package's models/); empty: off",
    )
    clutter_threshold: float = field_doc(
        0.7,
        help="a mask pixel whose clutter posterior reaches this leaves the mask (0.7: the "
        "lowest at which the recipe's forest calls at most 0.1%% of a furniture-free person "
        "clutter, python -m depthmocap.train.evaluation.clutter_threshold)",
    )

    def __post_init__(self) -> None:
        if not 0.0 < self.clutter_threshold <= 1.0:
            raise ConfigError(f"clutter_threshold must be in (0, 1], not {self.clutter_threshold}")
