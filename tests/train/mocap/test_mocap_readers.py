"""BVH and ASF/AMC readers: golden forward kinematics on hand-written files, conventions,
units, malformed input, and (when ../shared is present) plausibility on real clips."""

from __future__ import annotations

import glob
from pathlib import Path

import numpy as np
import pytest
from depthmocap.train.mocap import (
    MotionClip,
    axis_rotation,
    euler_to_matrix,
    read_amc,
    read_asf,
    read_bvh,
)

MOCAP_DATA = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "mocap"


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def bone_lengths(clip: MotionClip) -> np.ndarray:
    """(F, J-1) distances between each non-root joint and its parent."""
    child = np.arange(1, clip.num_joints)
    return np.linalg.norm(
        clip.positions[:, child] - clip.positions[:, clip.parents[child]], axis=-1
    )


# --------------------------------------------------------------------------------------------
# BVH

CHAIN_BVH = """HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.0333333
0 0 0 0 0 0 0 0 0
0 0 0 90 0 0 0 0 0
100 0 0 0 0 0 90 0 0
"""


def test_bvh_chain_golden_positions(tmp_path):
    clip = read_bvh(write(tmp_path, "chain.bvh", CHAIN_BVH))
    assert clip.joint_names == ("hips", "spine")
    assert clip.parents.tolist() == [-1, 0]
    assert clip.num_frames == 3
    assert clip.fps == 30.0  # 1 / 0.0333333 snapped to the integer rate
    np.testing.assert_allclose(clip.offsets, [[0, 0, 0], [0, 0.1, 0]])
    # Rest: the child sits 10 cm up.
    np.testing.assert_allclose(clip.positions[0], [[0, 0, 0], [0, 0.1, 0]], atol=1e-12)
    # 90 degrees about z at the root moves the +y offset to -x.
    np.testing.assert_allclose(clip.positions[1], [[0, 0, 0], [-0.1, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(clip.rotations[1, 1], axis_rotation("z", np.pi / 2), atol=1e-12)
    # Root translated 1 m along x; the child's own rotation does not move the child itself.
    np.testing.assert_allclose(clip.positions[2], [[1, 0, 0], [1, 0.1, 0]], atol=1e-12)
    np.testing.assert_allclose(clip.rotations[2, 1], axis_rotation("z", np.pi / 2), atol=1e-12)


def test_bvh_end_sites_optional(tmp_path):
    path = write(tmp_path, "chain.bvh", CHAIN_BVH)
    clip = read_bvh(path, include_end_sites=True)
    assert clip.joint_names == ("hips", "spine", "spine_end")
    assert clip.parents.tolist() == [-1, 0, 1]
    # Frame 2: spine has Zrotation 90, so its End Site offset (0, 5, 0) cm points along -x.
    np.testing.assert_allclose(clip.positions[2, 2], [1 - 0.05, 0.1, 0], atol=1e-12)
    np.testing.assert_allclose(clip.rotations[:, 2], clip.rotations[:, 1])


def two_joint_bvh(channels: str, values: str) -> str:
    count = len(channels.split())
    return f"""HIERARCHY
ROOT a
{{
  OFFSET 0 0 0
  CHANNELS {count} {channels}
  JOINT b
  {{
    OFFSET 100 0 0
    CHANNELS 0
  }}
}}
MOTION
Frames: 1
Frame Time: 0.01
{values}
"""


@pytest.mark.parametrize(
    ("channels", "expected"),
    [
        # Listed order is the multiplication order: Rx @ Rz, so z acts first on (1, 0, 0).
        ("Xrotation Zrotation", [0, 0, 1]),
        ("Zrotation Xrotation", [0, 1, 0]),
    ],
)
def test_bvh_channel_order(tmp_path, channels, expected):
    clip = read_bvh(write(tmp_path, "order.bvh", two_joint_bvh(channels, "90 90")), scale="m")
    np.testing.assert_allclose(clip.positions[0, 1], np.array(expected) * 100, atol=1e-9)


def test_bvh_euler_matches_matrix_product(tmp_path):
    angles = np.array([30.0, -50.0, 70.0])
    text = two_joint_bvh("Yrotation Xrotation Zrotation", " ".join(map(str, angles)))
    clip = read_bvh(write(tmp_path, "yxz.bvh", text))
    rad = np.deg2rad(angles)
    expected = axis_rotation("y", rad[0]) @ axis_rotation("x", rad[1]) @ axis_rotation("z", rad[2])
    np.testing.assert_allclose(clip.rotations[0, 0], expected, atol=1e-12)
    np.testing.assert_allclose(clip.rotations[0, 0], euler_to_matrix(rad, "yxz"), atol=1e-12)


def test_bvh_position_channels_anywhere(tmp_path):
    # A 6-channel joint in the middle of the chain, position channels in an unusual order.
    text = """HIERARCHY
ROOT a
{
  OFFSET 0 0 0
  CHANNELS 3 Zrotation Xrotation Yrotation
  JOINT b
  {
    OFFSET 0 10 0
    CHANNELS 6 Zrotation Yposition Xrotation Xposition Yrotation Zposition
    JOINT c
    {
      OFFSET 0 10 0
      CHANNELS 0
    }
  }
}
MOTION
Frames: 1
Frame Time: 0.01
0 0 0  0 2 0 1 0 3
"""
    path = write(tmp_path, "mid6.bvh", text)
    added = read_bvh(path, "m")
    # b's translation = OFFSET + (Xposition, Yposition, Zposition) = (0, 10, 0) + (1, 2, 3).
    np.testing.assert_allclose(added.positions[0, 1], [1, 12, 3], atol=1e-12)
    np.testing.assert_allclose(added.positions[0, 2], [1, 22, 3], atol=1e-12)
    replaced = read_bvh(path, "m", position_channels="replace")
    np.testing.assert_allclose(replaced.positions[0, 1], [1, 2, 3], atol=1e-12)


def test_bvh_fk_matches_per_frame_reference(tmp_path):
    # Random 3-joint chain with mixed channel orders, checked against homogeneous 4x4 matrices.
    rng = np.random.default_rng(0)
    orders = ["Zrotation Yrotation Xrotation", "Xrotation Yrotation Zrotation", "Yrotation"]
    offsets = [[1.0, 2.0, 3.0], [0.0, 12.0, 0.0], [4.0, 0.0, -2.0]]
    frames = rng.uniform(-180, 180, size=(5, 3 + 3 + 3 + 1))
    frames[:, :3] = rng.normal(size=(5, 3)) * 50  # root positions
    text = f"""HIERARCHY
ROOT r
{{
  OFFSET {" ".join(map(str, offsets[0]))}
  CHANNELS 6 Xposition Yposition Zposition {orders[0]}
  JOINT s
  {{
    OFFSET {" ".join(map(str, offsets[1]))}
    CHANNELS 3 {orders[1]}
    JOINT t
    {{
      OFFSET {" ".join(map(str, offsets[2]))}
      CHANNELS 1 {orders[2]}
    }}
  }}
}}
MOTION
Frames: 5
Frame Time: 0.01
""" + "\n".join(" ".join(f"{v:.6f}" for v in row) for row in frames)
    clip = read_bvh(write(tmp_path, "random.bvh", text), scale=0.01)

    def local(order: str, angles: np.ndarray, translation: np.ndarray) -> np.ndarray:
        m = np.eye(4)
        for axis, angle in zip([c[0].lower() for c in order.split()], angles):
            m[:3, :3] = m[:3, :3] @ axis_rotation(axis, np.deg2rad(angle))
        m[:3, 3] = translation
        return m

    for f, row in enumerate(np.round(frames, 6)):
        m0 = local(orders[0], row[3:6], np.array(offsets[0]) + row[:3])
        m1 = m0 @ local(orders[1], row[6:9], offsets[1])
        m2 = m1 @ local(orders[2], row[9:10], offsets[2])
        for j, m in enumerate((m0, m1, m2)):
            np.testing.assert_allclose(clip.positions[f, j], m[:3, 3] * 0.01, atol=1e-9)
            np.testing.assert_allclose(clip.rotations[f, j], m[:3, :3], atol=1e-9)
    lengths = bone_lengths(clip)
    assert np.abs(lengths - lengths[0]).max() < 1e-12


@pytest.mark.parametrize(
    ("scale", "factor"),
    [(0.01, 0.01), ("cm", 0.01), ("m", 1.0), ("mm", 0.001), ("in", 0.0254), (0.5, 0.5)],
)
def test_bvh_units(tmp_path, scale, factor):
    clip = read_bvh(write(tmp_path, "chain.bvh", CHAIN_BVH), scale=scale)
    np.testing.assert_allclose(clip.positions[2, 0], [100 * factor, 0, 0], atol=1e-12)
    np.testing.assert_allclose(clip.offsets[1], [0, 10 * factor, 0], atol=1e-12)


def human_sized_bvh(unit_per_metre: float) -> str:
    """A 2 m leaf-to-leaf span (two 1 m limbs) in the given unit."""
    d = unit_per_metre
    return f"""HIERARCHY
ROOT hips
{{
  OFFSET 0 0 0
  CHANNELS 3 Xposition Yposition Zposition
  JOINT head
  {{
    OFFSET 0 {d} 0
    CHANNELS 3 Zrotation Yrotation Xrotation
  }}
  JOINT foot
  {{
    OFFSET 0 {-d} 0
    CHANNELS 3 Zrotation Yrotation Xrotation
  }}
}}
MOTION
Frames: 1
Frame Time: 0.01
0 0 0 0 0 0 0 0 0
"""


@pytest.mark.parametrize("unit_per_metre", [1.0, 100.0, 1000.0, 1 / 0.0254])
def test_bvh_auto_units(tmp_path, unit_per_metre):
    clip = read_bvh(write(tmp_path, "h.bvh", human_sized_bvh(unit_per_metre)), scale="auto")
    np.testing.assert_allclose(clip.positions[0, 1], [0, 1, 0], atol=1e-9)


def test_bvh_max_frames(tmp_path):
    path = write(tmp_path, "chain.bvh", CHAIN_BVH)
    clip = read_bvh(path, max_frames=2)
    assert clip.num_frames == 2
    np.testing.assert_allclose(clip.positions, read_bvh(path).positions[:2])
    assert read_bvh(path, max_frames=0).num_frames == 0


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("ROOT a\n{\n}\nMOTION\n", r"bad\.bvh:1: missing HIERARCHY"),
        (CHAIN_BVH.split("MOTION")[0], r"bad\.bvh:\d+: missing MOTION"),
        (
            CHAIN_BVH.replace("0 0 0 90 0 0 0 0 0", "0 0 0 90 0 0 0 0"),
            r"bad\.bvh:20: frame 1 has 8 values, expected 9",
        ),
        (CHAIN_BVH.replace("Frames: 3", "Frames: 4"), r"'Frames: 4' but .* 3 frame lines"),
        (CHAIN_BVH.replace("Frames: 3", "Frames: 2"), r"'Frames: 2' but .* 3 frame lines"),
        (
            CHAIN_BVH.replace("100 0 0", "100 abc 0"),
            r"bad\.bvh:21: non-numeric value 'abc' in frame 2",
        ),
        (CHAIN_BVH.replace("100 0 0", "100 nan 0"), r"bad\.bvh:21: non-finite"),
        (CHAIN_BVH.replace("OFFSET 0 10 0", "OFFSET 0 x 0"), r"bad\.bvh:8: expected a number"),
        (CHAIN_BVH.replace("Xposition", "Wposition"), r"bad\.bvh:5: unknown channel"),
        (CHAIN_BVH.replace("Frame Time: 0.0333333", "Frame Time: 0"), r"invalid frame time"),
        (CHAIN_BVH.replace("    End Site", "    Foo Site"), r"bad\.bvh:10: expected JOINT"),
        (CHAIN_BVH.replace("}\nMOTION", "MOTION"), r"bad\.bvh:14: unexpected end of HIERARCHY"),
    ],
)
def test_bvh_malformed(tmp_path, text, match):
    with pytest.raises(ValueError, match=match):
        read_bvh(write(tmp_path, "bad.bvh", text))


def test_bvh_bad_arguments(tmp_path):
    path = write(tmp_path, "chain.bvh", CHAIN_BVH)
    with pytest.raises(ValueError, match="unknown unit 'furlong'"):
        read_bvh(path, scale="furlong")
    with pytest.raises(ValueError, match="positive number"):
        read_bvh(path, scale=-1.0)
    with pytest.raises(ValueError, match="position_channels"):
        read_bvh(path, position_channels="absolute")


# --------------------------------------------------------------------------------------------
# ASF / AMC

# length 0.5: one file unit is 2 inches = 0.0508 m.
UNIT = 0.0254 / 0.5

ASF = """# test skeleton
:version 1.10
:name TEST
:units
  mass 1.0
  length 0.5
  angle deg
:documentation
  free text that is ignored
:root
  order TX TY TZ RX RY RZ
  axis XYZ
  position 0 0 0
  orientation 0 0 0
:bonedata
  begin
    id 1
    name upper
    direction 0 1 0
    length 10
    axis 0 0 0 XYZ
    dof rx ry rz
    limits (-180.0 180.0)
           (-90 90)
           (-inf inf)
  end
  begin
    id 2
    name lower
    direction 1 0 0
    length 5
    axis 0 0 90 XYZ
    dof rx
    limits (-10.0 170.0)
  end
  begin
    id 3
    name side
    direction 0 0 2
    length 4
    axis 0 0 0 XYZ
  end
:hierarchy
  begin
    root upper side
    upper lower
  end
"""

AMC = """#!OML:ASF test.asf
:FULLY-SPECIFIED
:DEGREES
1
root 0 0 0 0 0 0
upper 0 0 0
lower 0
2
root 0 0 0 0 0 0
upper 0 0 90
lower 0
3
root 0 0 0 0 0 0
upper 0 0 0
lower 90
4
root 10 20 30 0 0 0
upper 0 0 0
lower 0
"""


@pytest.fixture
def skeleton(tmp_path):
    return read_asf(write(tmp_path, "test.asf", ASF))


def test_asf_parse(skeleton):
    assert [b.name for b in skeleton.bones] == ["upper", "lower", "side"]
    assert skeleton.length_scale == pytest.approx(UNIT)
    assert skeleton.root_order == ("tx", "ty", "tz", "rx", "ry", "rz")
    lower = skeleton.bone("lower")
    assert lower.length == pytest.approx(5 * UNIT)
    assert lower.dofs == ("rx",)
    np.testing.assert_allclose(lower.limits, np.deg2rad([[-10, 170]]))
    np.testing.assert_allclose(skeleton.bone("upper").limits[2], [-np.inf, np.inf])
    # direction is normalised; the length carries the size.
    np.testing.assert_allclose(skeleton.bone("side").direction, [0, 0, 1])
    np.testing.assert_allclose(lower.axis_matrix, axis_rotation("z", np.pi / 2), atol=1e-12)
    assert skeleton.parent == {"upper": "root", "side": "root", "lower": "upper"}
    names, parents, offsets = skeleton.joint_layout()
    assert names == ("root", "upper", "lower", "lower_end", "side", "side_end")
    assert parents.tolist() == [-1, 0, 1, 2, 0, 4]
    np.testing.assert_allclose(offsets[3], [5 * UNIT, 0, 0])


def test_amc_golden_positions(tmp_path, skeleton):
    clip = read_amc(write(tmp_path, "test.amc", AMC), skeleton)
    assert clip.fps == 120.0
    assert clip.num_frames == 4
    i = clip.index
    up, lo = 10 * UNIT, 5 * UNIT
    # Rest: upper runs +y from the root, lower +x from upper's end; joints sit at bone starts.
    p = clip.positions[0]
    np.testing.assert_allclose(p[i("upper")], [0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(p[i("lower")], [0, up, 0], atol=1e-12)
    np.testing.assert_allclose(p[i("lower_end")], [lo, up, 0], atol=1e-12)
    np.testing.assert_allclose(p[i("side_end")], [0, 0, 4 * UNIT], atol=1e-12)
    # rz 90 on upper (identity axis frame): +y -> -x, and the child bone +x -> +y.
    p = clip.positions[1]
    np.testing.assert_allclose(p[i("lower")], [-up, 0, 0], atol=1e-12)
    np.testing.assert_allclose(p[i("lower_end")], [-up, lo, 0], atol=1e-12)
    # rx 90 on lower is about its axis-frame x, which `axis 0 0 90` turns onto world +y:
    # L = C Rx C^-1 = Ry(90), taking the bone's +x to -z.
    p = clip.positions[2]
    np.testing.assert_allclose(p[i("lower_end")], [0, up, -lo], atol=1e-12)
    np.testing.assert_allclose(
        clip.rotations[2, i("lower")], axis_rotation("y", np.pi / 2), atol=1e-12
    )
    # Root translation is in file units.
    np.testing.assert_allclose(clip.positions[3, 0], np.array([10, 20, 30]) * UNIT, atol=1e-12)
    lengths = bone_lengths(clip)
    assert np.abs(lengths - lengths[0]).max() < 1e-12


def single_bone_asf(dof: str, axis: str = "0 0 0 XYZ", extra_units: str = "") -> str:
    return f""":units
  length 1.0
{extra_units}:root
  order TX TY TZ RX RY RZ
  axis XYZ
:bonedata
  begin
    name b
    direction 1 0 0
    length 1
    axis {axis}
    dof {dof}
  end
:hierarchy
  begin
    root b
  end
"""


@pytest.mark.parametrize(
    ("dof", "expected"),
    [
        # Values are applied in dof order: `rz rx` rotates about z first.
        ("rz rx", [0, 0, 1]),
        ("rx rz", [0, 1, 0]),
    ],
)
def test_amc_dof_order(tmp_path, dof, expected):
    skeleton = read_asf(write(tmp_path, "s.asf", single_bone_asf(dof)))
    clip = read_amc(write(tmp_path, "s.amc", "1\nroot 0 0 0 0 0 0\nb 90 90\n"), skeleton)
    np.testing.assert_allclose(
        clip.positions[0, clip.index("b_end")], np.array(expected) * 0.0254, atol=1e-12
    )


def test_asf_axis_order(tmp_path):
    # `axis 90 0 90 XYZ` is Rz(90) @ Ry(0) @ Rx(90): x is applied first.
    skeleton = read_asf(write(tmp_path, "s.asf", single_bone_asf("rx", axis="90 0 90 XYZ")))
    expected = axis_rotation("z", np.pi / 2) @ axis_rotation("x", np.pi / 2)
    np.testing.assert_allclose(skeleton.bone("b").axis_matrix, expected, atol=1e-12)
    skeleton = read_asf(write(tmp_path, "t.asf", single_bone_asf("rx", axis="90 0 90 ZYX")))
    expected = axis_rotation("x", np.pi / 2) @ axis_rotation("z", np.pi / 2)
    np.testing.assert_allclose(skeleton.bone("b").axis_matrix, expected, atol=1e-12)


def test_amc_root_order_and_radians(tmp_path):
    text = single_bone_asf("rx", extra_units="  angle rad\n").replace(
        "order TX TY TZ RX RY RZ", "order RZ TX TY TZ RX RY"
    )
    skeleton = read_asf(write(tmp_path, "s.asf", text))
    assert skeleton.angle_unit == "rad"
    half_pi = np.pi / 2
    amc = f"1\nroot {half_pi} 1 2 3 0 0\nb 0\n"
    clip = read_amc(write(tmp_path, "s.amc", amc), skeleton)
    np.testing.assert_allclose(clip.positions[0, 0], np.array([1, 2, 3]) * 0.0254, atol=1e-12)
    np.testing.assert_allclose(clip.rotations[0, 0], axis_rotation("z", half_pi), atol=1e-12)
    # An AMC :DEGREES header overrides the ASF angle unit.
    clip = read_amc(write(tmp_path, "d.amc", ":DEGREES\n1\nroot 90 1 2 3 0 0\nb 0\n"), skeleton)
    np.testing.assert_allclose(clip.rotations[0, 0], axis_rotation("z", half_pi), atol=1e-12)


def test_asf_scale_override_and_max_frames(tmp_path):
    skeleton = read_asf(write(tmp_path, "test.asf", ASF), scale=1.0)
    assert skeleton.bone("upper").length == 10.0
    clip = read_amc(write(tmp_path, "test.amc", AMC), skeleton, fps=60.0, max_frames=3)
    assert clip.num_frames == 3
    assert clip.fps == 60.0
    np.testing.assert_allclose(clip.positions[1, clip.index("lower")], [-10, 0, 0], atol=1e-12)


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        (":hierarchy", ":nothing", r"bad\.asf:\d+: missing :hierarchy"),
        ("    length 5\n", "    length five\n", r"bad\.asf:\d+: non-numeric value in length"),
        ("dof rx\n", "dof rx tx\n", r"bad\.asf:\d+: unsupported dof"),
        ("    upper lower\n", "    upper lower ghost\n", r"bad\.asf:\d+: unknown bone 'ghost'"),
        ("    root upper side\n", "    root upper\n", r"not connected to root.*side"),
        ("axis 0 0 90 XYZ", "axis 0 0 90 XYY", r"permutation of XYZ"),
        ("    length 4\n", "", r"bad\.asf:\d+: bone block without \['length'\]"),
        ("    limits (-10.0 170.0)\n", "    limits (-10.0 170.0) (0 1)\n", r"1 dofs but 2 limit"),
    ],
)
def test_asf_malformed(tmp_path, old, new, match):
    assert old in ASF
    with pytest.raises(ValueError, match=match):
        read_asf(write(tmp_path, "bad.asf", ASF.replace(old, new)))


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("upper 0 0 90\n", "upper 0 90\n", r"bad\.amc:10: bone 'upper' has 2 values, expected 3"),
        ("upper 0 0 90\n", "upper 0 zz 90\n", r"bad\.amc:10: non-numeric value"),
        ("lower 90\n", "lower 90\nghost 1\n", r"bad\.amc:16: bone 'ghost' is not animated"),
        ("lower 90\n", "", r"bad\.amc:12: frame 3 lacks bones \['lower'\]"),
        ("lower 90\n", "lower 90\nlower 1\n", r"appears twice in frame 3"),
        ("\n4\n", "\n5\n", r"bad\.amc:\d+: frame number 5 does not follow 3"),
        ("1\nroot", "root 0 0 0 0 0 0\n1\nroot", r"bad\.amc:4: bone data before the first frame"),
    ],
)
def test_amc_malformed(tmp_path, skeleton, old, new, match):
    assert old in AMC
    with pytest.raises(ValueError, match=match):
        read_amc(write(tmp_path, "bad.amc", AMC.replace(old, new, 1)), skeleton)


# --------------------------------------------------------------------------------------------
# MotionClip


def small_clip(num_frames: int = 6) -> MotionClip:
    rotations = np.broadcast_to(np.eye(3), (num_frames, 2, 3, 3))
    positions = np.zeros((num_frames, 2, 3))
    positions[:, 0, 0] = np.arange(num_frames)
    return MotionClip(
        joint_names=("a", "b"),
        parents=np.array([-1, 0]),
        rotations=rotations,
        positions=positions,
        fps=30.0,
        source="memory",
        offsets=np.zeros((2, 3)),
    )


def test_clip_frames():
    clip = small_clip()
    assert clip.num_frames == 6 and clip.num_joints == 2
    assert clip.index("b") == 1
    sub = clip.subsample(2)
    assert sub.fps == 15.0
    np.testing.assert_array_equal(sub.positions[:, 0, 0], [0, 2, 4])
    part = clip.slice(1, 4)
    assert part.fps == 30.0
    np.testing.assert_array_equal(part.positions[:, 0, 0], [1, 2, 3])
    np.testing.assert_array_equal(clip.slice(-2, 6).positions[:, 0, 0], [4, 5])


def test_clip_validation():
    clip = small_clip()
    with pytest.raises(ValueError, match="no joint named 'c'"):
        clip.index("c")
    with pytest.raises(ValueError, match="positive integer"):
        clip.subsample(0)
    with pytest.raises(ValueError, match="selects no frames"):
        clip.slice(4, 4)
    fields = dict(
        joint_names=clip.joint_names,
        parents=clip.parents,
        rotations=clip.rotations,
        positions=clip.positions,
        fps=clip.fps,
        source="memory",
        offsets=clip.offsets,
    )
    cases = [
        ({"joint_names": ("a", "a")}, "duplicate joint names"),
        ({"parents": np.array([-1, 1])}, r"parents\[1\] = 1"),
        ({"parents": np.array([-1.0, 0.0])}, "int array"),
        ({"rotations": clip.rotations[:, :1]}, "rotations must have shape"),
        ({"positions": clip.positions[:3]}, "positions must have shape"),
        ({"offsets": np.zeros(3)}, "offsets must have shape"),
        ({"fps": 0.0}, "fps must be a positive"),
        ({"positions": np.full_like(clip.positions, np.nan)}, "NaN"),
    ]
    for change, match in cases:
        with pytest.raises(ValueError, match=match):
            MotionClip(**{**fields, **change})


# --------------------------------------------------------------------------------------------
# Real data


@pytest.mark.shareddata
def test_real_clips_plausible():
    hdm = sorted(glob.glob(str(MOCAP_DATA / "hdm05" / "dev" / "*.amc")))
    cmu = MOCAP_DATA / "cmu" / "002_01.bvh"
    if not hdm or not cmu.is_file():
        pytest.skip(f"mocap data not present under {MOCAP_DATA}")

    skeleton = read_asf(MOCAP_DATA / "hdm05" / "dev" / "HDM_mm.asf")
    clip = read_amc(hdm[0], skeleton, max_frames=200)
    assert clip.num_frames == 200 and clip.fps == 120.0
    y = clip.positions[..., 1]  # ASF world is Y up
    feet = [clip.index(n) for n in ("lfoot", "rfoot", "ltoes", "rtoes", "ltoes_end", "rtoes_end")]
    _, parents, offsets = skeleton.joint_layout()
    rest = np.zeros_like(offsets)
    for j in range(1, len(parents)):
        rest[j] = rest[parents[j]] + offsets[j]
    assert 1.5 < np.ptp(rest[:, 1]) < 1.9  # rest-pose height
    assert np.abs(np.median(y[:, feet].min(axis=1))) < 0.1  # feet near the floor
    lengths = bone_lengths(clip)
    assert np.abs(lengths - lengths[0]).max() < 1e-6

    clip = read_bvh(cmu, max_frames=200)
    assert clip.fps == 60.0 and clip.num_joints == 101
    y = clip.positions[..., 1]
    feet = [j for j, n in enumerate(clip.joint_names) if "_Foot" in n or "Toe" in n]
    floor = y[1:, feet].min(axis=1)  # frame 0 may be a calibration pose
    assert 0.0 < np.median(floor) < 0.15
    assert 1.5 < np.median(y[1:, clip.index("CC_Base_L_Eye")] - floor) < 1.9
    thigh = [clip.index(f"CC_Base_{s}_Thigh") for s in "LR"]
    calf = [clip.index(f"CC_Base_{s}_Calf") for s in "LR"]
    femur = np.linalg.norm(clip.positions[0, calf] - clip.positions[0, thigh], axis=-1)
    assert femur[0] == pytest.approx(femur[1], abs=1e-3) and 0.35 < femur[0] < 0.55
    lengths = bone_lengths(clip)
    assert np.abs(lengths - lengths[0]).max() < 1e-6
