"""Kinect v1 depth sensor model, one home for synthesis (``train``) and the demo stream.

The model is the one the training frames are made with: :mod:`.kinect` applies it
(:func:`apply_kinect_noise`, :class:`KinectNoiseConfig`, with the sensor facts it rests on),
:mod:`.disparity` holds the measurement (disparity quantization and noise), :mod:`.dropout` the
missing data (projector shadows, grazing angles, holes, ragged edges), and :mod:`.background`
the floor, wall and boxes a rendered body is composited with before the sensor sees it.

Numpy only and vectorized; it lives in ``shared`` so that the runtime's demo stream produces the
same kind of depth as the recordings it is evaluated on.
"""

from depthmocap.shared.sensor_noise.background import (
    BackgroundBox,
    BackgroundConfig,
    BackgroundCylinder,
    BackgroundScene,
    add_floor_and_background,
    box_depth,
    cylinder_depth,
    floor_depth,
    level_from_camera,
    random_background_scene,
    wall_depth,
)
from depthmocap.shared.sensor_noise.disparity import (
    add_disparity_noise,
    quantize_depth,
    smooth_disparity,
)
from depthmocap.shared.sensor_noise.dropout import (
    edge_erosion_mask,
    grazing_dropout_mask,
    incidence_angle,
    projector_shadow_mask,
    random_holes_mask,
)
from depthmocap.shared.sensor_noise.kinect import KinectNoiseConfig, apply_kinect_noise

__all__ = [
    "level_from_camera",
    "KinectNoiseConfig",
    "BackgroundConfig",
    "BackgroundBox",
    "BackgroundCylinder",
    "BackgroundScene",
    "cylinder_depth",
    "apply_kinect_noise",
    "quantize_depth",
    "smooth_disparity",
    "add_disparity_noise",
    "projector_shadow_mask",
    "incidence_angle",
    "grazing_dropout_mask",
    "edge_erosion_mask",
    "random_holes_mask",
    "floor_depth",
    "wall_depth",
    "box_depth",
    "random_background_scene",
    "add_floor_and_background",
]
