"""The tracking skeleton of Wei et al. 2012 (section 2): 15 rigid segments, pose q in R^34.

This module is the single place that fixes the segment tree, the layout of q, each degree of
freedom's axis and its joint limits. Everything else (kinematics, ray-casting, IK, export)
reads these tables.

Body frame (rest pose, all joint angles zero): x = the person's left, y = up, z = the
person's forward; the person stands upright with arms hanging straight down. The root
orientation maps body frame to camera frame, so a person facing the camera upright has
root rotation diag(1, -1, -1) (rotation vector (pi, 0, 0)).

Layout of q (the order of Wei section 2 / DESIGN.md):

====  =====================  =========================================================
idx   name                   meaning (positive direction)
====  =====================  =========================================================
0-2   root_tx/ty/tz          root (hip centre) position in camera frame, metres
3-5   root_rx/ry/rz          root orientation, rotation vector (updated on SO(3))
6-8   head_x/y/z             nod forward, turn left, tilt left... (about x, y, z)
9-10  lower_neck_x/z         flex forward, bend sideways
11-13 lower_back_x/y/z       flex forward, twist, bend sideways
14-15 l_clavicle_elev/prot   shrug up, move forward
16-17 r_clavicle_elev/prot   (mirrored: same meaning on the right)
18-20 l_humerus_abd/flex/tw  raise sideways, raise forwards, twist about the arm
21-23 r_humerus_abd/flex/tw
24,25 l/r_radius_flex        elbow flexion
26-28 l_femur_flex/abd/tw    raise leg forwards, sideways, twist
29-31 r_femur_flex/abd/tw
32,33 l/r_tibia_flex         knee flexion
====  =====================  =========================================================

Each joint with several DoFs composes its rotations in the order listed:
``R_joint = R(axis_1, q_1) @ R(axis_2, q_2) @ R(axis_3, q_3)``. Axes of right-side joints
are the mirror images (x, y, z) -> (x, -y, -z) of the left ones, so equal angles mean the
same anatomical motion on both sides. Euler singularities sit at poses that are rare or
excluded by the limits: shoulder abduction-first puts it at a horizontal forward reach,
hip flexion-first at 90 degrees of leg abduction; the damped solvers cope with either.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "SEGMENT_NAMES",
    "NUM_SEGMENTS",
    "SEGMENT_PARENT",
    "SEGMENT_AXIS",
    "SEGMENT_ATTACH_END",
    "SEGMENT_LATERAL",
    "SEGMENT_LEVELS",
    "DOF_NAMES",
    "NUM_DOFS",
    "DOF_SEGMENT",
    "DOF_AXIS",
    "DOF_LIMITS",
    "SEGMENT_DOF_SLOTS",
    "DOF_SLOT",
    "SEGMENT_ANCESTORS",
    "DOF_AFFECTS_SEGMENT",
    "FIRST_LIMB_SEGMENT",
    "JOINT_NAMES",
    "JOINT_SEGMENT",
    "JOINT_FRACTION",
    "JOINT_BONES",
    "ROOT_TRANSLATION",
    "ROOT_ROTATION",
    "ANGLE_DOFS",
    "CLAVICLE_DOFS",
    "FACING_CAMERA_ROTVEC",
]

SEGMENT_NAMES: tuple[str, ...] = (
    "pelvis",  # 0  root; origin at the hip centre, cylinder up to the lower back joint
    "abdomen",  # 1  lower back joint (3 DoF)
    "chest",  # 2  rigid on the abdomen: wider elliptic section up to the base of the neck
    "neck",  # 3  lower neck joint (2 DoF)
    "head",  # 4  head joint at the top of the neck (3 DoF)
    "l_clavicle",  # 5
    "r_clavicle",  # 6
    "l_upper_arm",  # 7  humerus
    "r_upper_arm",  # 8
    "l_forearm",  # 9  radius; geometry extends over the hand
    "r_forearm",  # 10
    "l_thigh",  # 11 femur
    "r_thigh",  # 12
    "l_shank",  # 13 tibia; geometry extends down to the sole
    "r_shank",  # 14
)
NUM_SEGMENTS = len(SEGMENT_NAMES)

SEGMENT_PARENT = np.array([-1, 0, 1, 2, 3, 2, 2, 5, 6, 7, 8, 0, 0, 11, 12], dtype=np.int64)

_UP, _DOWN, _LEFT, _RIGHT = (0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0)
# Direction from a segment's origin (its joint) towards its end, in the segment frame.
SEGMENT_AXIS = np.array(
    [
        _UP,
        _UP,
        _UP,
        _UP,
        _UP,
        _LEFT,
        _RIGHT,
        _DOWN,
        _DOWN,
        _DOWN,
        _DOWN,
        _DOWN,
        _DOWN,
        _DOWN,
        _DOWN,
    ],
    dtype=np.float64,
)
# A child's joint sits at ``attach_end * parent_length`` along the parent axis, plus
# ``lateral * hip_half_width`` along x (only the hips sit beside their parent's origin).
SEGMENT_ATTACH_END = np.array([0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 1, 1], dtype=np.float64)
SEGMENT_LATERAL = np.array([0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, -1, 0, 0], dtype=np.float64)
# Segments grouped by tree depth: forward kinematics handles one level per batched step.
SEGMENT_LEVELS: tuple[tuple[int, ...], ...] = (
    (0,),
    (1, 11, 12),
    (2, 13, 14),
    (3, 5, 6),
    (4, 7, 8),
    (9, 10),
)


def _mirror(axis: tuple[float, float, float]) -> tuple[float, float, float]:
    return (axis[0], -axis[1], -axis[2])


_X, _Y, _Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
_NX, _NY = (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0)

# (name, segment, axis in the parent-side joint frame, lower deg, upper deg)
_ANGLE_DOFS: tuple[tuple[str, int, tuple[float, float, float], float, float], ...] = (
    ("head_x", 4, _X, -50, 50),
    ("head_y", 4, _Y, -75, 75),
    ("head_z", 4, _Z, -40, 40),
    ("lower_neck_x", 3, _X, -30, 50),
    ("lower_neck_z", 3, _Z, -30, 30),
    ("lower_back_x", 1, _X, -30, 90),
    ("lower_back_y", 1, _Y, -50, 50),
    ("lower_back_z", 1, _Z, -40, 40),
    ("l_clavicle_elev", 5, _Z, -15, 40),
    ("l_clavicle_prot", 5, _NY, -20, 30),
    ("r_clavicle_elev", 6, _mirror(_Z), -15, 40),
    ("r_clavicle_prot", 6, _mirror(_NY), -20, 30),
    ("l_humerus_abd", 7, _Z, -45, 180),
    ("l_humerus_flex", 7, _NX, -70, 180),
    ("l_humerus_twist", 7, _Y, -100, 100),
    ("r_humerus_abd", 8, _mirror(_Z), -45, 180),
    ("r_humerus_flex", 8, _mirror(_NX), -70, 180),
    ("r_humerus_twist", 8, _mirror(_Y), -100, 100),
    ("l_radius_flex", 9, _NX, 0, 155),
    ("r_radius_flex", 10, _mirror(_NX), 0, 155),
    ("l_femur_flex", 11, _NX, -40, 130),
    ("l_femur_abd", 11, _Z, -35, 80),
    ("l_femur_twist", 11, _Y, -60, 60),
    ("r_femur_flex", 12, _mirror(_NX), -40, 130),
    ("r_femur_abd", 12, _mirror(_Z), -35, 80),
    ("r_femur_twist", 12, _mirror(_Y), -60, 60),
    ("l_tibia_flex", 13, _X, 0, 160),
    ("r_tibia_flex", 14, _mirror(_X), 0, 160),
)

ROOT_TRANSLATION = slice(0, 3)
ROOT_ROTATION = slice(3, 6)
ANGLE_DOFS = slice(6, 34)

DOF_NAMES: tuple[str, ...] = (
    "root_tx",
    "root_ty",
    "root_tz",
    "root_rx",
    "root_ry",
    "root_rz",
) + tuple(d[0] for d in _ANGLE_DOFS)
NUM_DOFS = len(DOF_NAMES)
assert NUM_DOFS == 34
# The clavicle (elevation, protraction) pairs, left then right: a body's clavicle rest angles
# (shared.body.BodyShape.clavicle_rest) add to these.
CLAVICLE_DOFS: tuple[int, ...] = tuple(
    DOF_NAMES.index(f"{s}_clavicle_{a}") for s in "lr" for a in ("elev", "prot")
)

# Segment moved by each DoF (the root's six move the pelvis).
DOF_SEGMENT = np.array([0] * 6 + [d[1] for d in _ANGLE_DOFS], dtype=np.int64)
# Axis of each DoF: root translations/rotations use the camera axes (global perturbation).
DOF_AXIS = np.concatenate([np.eye(3), np.eye(3), np.array([d[2] for d in _ANGLE_DOFS])], 0)
_inf = math.inf
DOF_LIMITS = np.array(
    [(-_inf, _inf)] * 6 + [(math.radians(d[3]), math.radians(d[4])) for d in _ANGLE_DOFS],
    dtype=np.float64,
)  # (34, 2) lower, upper; radians for joint angles

# For each segment, the q indices of its joint's DoFs in composition order, padded with -1.
SEGMENT_DOF_SLOTS = np.full((NUM_SEGMENTS, 3), -1, dtype=np.int64)
# Position of each DoF within its joint's composition order (root DoFs: 0).
DOF_SLOT = np.zeros(NUM_DOFS, dtype=np.int64)
for _i, _d in enumerate(_ANGLE_DOFS):
    _dof = 6 + _i
    _slot = int((SEGMENT_DOF_SLOTS[_d[1]] >= 0).sum())
    SEGMENT_DOF_SLOTS[_d[1], _slot] = _dof
    DOF_SLOT[_dof] = _slot

# The limbs (upper arms, forearms, thighs, shanks) are the segments from the left upper arm on;
# the torso, neck, head and clavicles come before them.
FIRST_LIMB_SEGMENT = SEGMENT_NAMES.index("l_upper_arm")
assert all(SEGMENT_NAMES[k][2:] in ("upper_arm", "forearm", "thigh", "shank")
           for k in range(FIRST_LIMB_SEGMENT, NUM_SEGMENTS))  # fmt: skip

# SEGMENT_ANCESTORS[k, j]: segment j is k or one of k's ancestors.
SEGMENT_ANCESTORS = np.zeros((NUM_SEGMENTS, NUM_SEGMENTS), dtype=bool)
for _k in range(NUM_SEGMENTS):
    _j = _k
    while _j >= 0:
        SEGMENT_ANCESTORS[_k, _j] = True
        _j = SEGMENT_PARENT[_j]
# DOF_AFFECTS_SEGMENT[k, d]: DoF d moves points fixed on segment k.
DOF_AFFECTS_SEGMENT = SEGMENT_ANCESTORS[:, DOF_SEGMENT]

# Named output joints: a point on a segment's axis at ``fraction * length`` from its origin.
# They are anatomical joint centres, the same points the synthetic ground truth marks.
_NAMED = (
    ("head", 4, 0.45),  # centre of the head
    ("neck", 3, 0.0),  # base of the neck (lower neck joint)
    ("spine", 2, 0.0),  # mid back (top of the lumbar spine)
    ("pelvis", 0, 0.0),  # hip centre, the root
    ("l_shoulder", 7, 0.0),
    ("r_shoulder", 8, 0.0),
    ("l_elbow", 9, 0.0),
    ("r_elbow", 10, 0.0),
    ("l_wrist", 9, 1.0),
    ("r_wrist", 10, 1.0),
    ("l_hip", 11, 0.0),
    ("r_hip", 12, 0.0),
    ("l_knee", 13, 0.0),
    ("r_knee", 14, 0.0),
    ("l_ankle", 13, 1.0),
    ("r_ankle", 14, 1.0),
)
JOINT_NAMES: tuple[str, ...] = tuple(n[0] for n in _NAMED)
JOINT_SEGMENT = np.array([n[1] for n in _NAMED], dtype=np.int64)
JOINT_FRACTION = np.array([n[2] for n in _NAMED], dtype=np.float64)
# The named joints' stick figure (overlays, live view, contact sheets): pairs of JOINT_NAMES.
JOINT_BONES: tuple[tuple[str, str], ...] = (
    ("head", "neck"), ("neck", "spine"), ("spine", "pelvis"),
    ("neck", "l_shoulder"), ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"),
    ("neck", "r_shoulder"), ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"),
    ("pelvis", "l_hip"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"),
    ("pelvis", "r_hip"), ("r_hip", "r_knee"), ("r_knee", "r_ankle"),
)  # fmt: skip

# Upright, facing the camera (camera y points down, z away from the camera).
FACING_CAMERA_ROTVEC = np.array([math.pi, 0.0, 0.0])
