"""Person segmentation from a raw depth frame (issue 4 item 3): real sensor frames come without
a clean person mask, so the runtime makes one before tracking.

Steps (all batched over (B, H, W) images; device and dtype follow the input):

1. Depth gate: keep finite readings within ``[min_depth_m, max_depth_m]`` (the Kinect v1 is
   usable at about 0.8-4 m, DESIGN.md).
2. Floor removal: RANSAC plane fit on points of the lower image part. Hypotheses whose normal
   is more than ``floor_max_tilt_deg`` away from the camera's up direction (-y) are refused,
   so the torso or a wall never counts as floor, and so are planes with more than a few
   points below them (nothing stands under a floor; a plane slicing through a body has half
   of it below). The winner is refined by least squares on its inliers, and every point less
   than ``floor_band_m`` above it (or below it) is removed. A plane with too little support,
   or whose inliers do not recede in depth as a floor does, is ignored (no floor in view).
3. Depth-discontinuity cut: a pixel with a 4-neighbour nearer by more than
   ``edge_jump_m + edge_jump_per_m2 * z^2`` (the Kinect error grows as z^2) is cut, which
   separates the person from the wall behind while the nearer silhouette stays whole.
4. Connected components (OpenCV, 4-connectivity, all images of the batch in one call, stacked
   with a blank row between them). Components of implausible size for a person (metric width,
   height, depth extent) or too small a metric area are dropped; the largest remaining one by
   metric area (sum of z^2 / (fx fy)) is the person, its area weighted by how little convex
   it is (a box, a door or a cupboard projects to a convex shape, a person does not) and, in
   a stream, favouring the component where the previous frame's person was
   (:mod:`.selection`). A component seen partly behind a large nearer one (the wall or a
   second person behind the subject) is background and never chosen. Small components just
   in front of the person (hands, foreshortened forearms) join it, and cut pixels that touch
   the person at a smooth depth step (self-occlusion edges inside the body) are added back.

A stream's frames go through :class:`PersonSegmenter`, which carries the previous frame's
person and floor over (:class:`~.person.SegmentationMemory`): where a frame's floor fit fails
(a crouching person hiding most of the floor) the previous floor is removed if it still
explains the floor points.

An image with no plausible component gives an empty mask: the caller reports the frame as lost.

Modules: :mod:`.config` (the settings), :mod:`.depth_range` (step 1), :mod:`.floor` (step 2),
:mod:`.components` and :mod:`.canvas` (step 4 and the batch as one OpenCV image),
:mod:`.selection` (which component is the person), :mod:`.person` (the steps in order, and
:func:`segment_person`), :mod:`.segmenter` (a stream's segmentation).
"""

from .config import SegmentationConfig
from .depth_range import depth_valid_mask
from .floor import fit_floor_plane
from .person import segment_person
from .segmenter import PersonSegmenter

__all__ = [
    "PersonSegmenter",
    "SegmentationConfig",
    "segment_person",
    "fit_floor_plane",
    "depth_valid_mask",
]
