"""Body parameters of the cylinder model: segment lengths, cross-section radii, hip width.

A body is what skeleton calibration (Wei section 6) and personalization (Helten section III)
estimate, and what ``runtime-track --body`` loads. The geometry of segment k is an elliptic
cylinder along the segment axis from ``-extent[k, 0]`` to ``length[k] + extent[k, 1]``, with
semi-axes ``radii[k]`` along the two cross-section directions of ``cross_section_axes``,
centred ``offsets[k]`` away from the joint axis along those same directions: bones do not run
through the middle of the flesh (the spine lies behind the trunk's centre, the femur inside
the thigh's), so a body measured on a mesh needs both to put its joints where the skeleton's are.
Each shank also carries a foot: a capsule rigid with the shank (no joint of its own), lying on
the sole and reaching ``feet[side, 0]`` forward of the shank axis with radius ``feet[side, 1]``.
Wei's 15 cylinders have no feet; without them a standing person's feet are depth the model
cannot explain, and the data terms tilt the shanks forward to reach them (8 cm at the ankles).
The chest leans ``chest_tilt`` forward on the abdomen (a fixed rest rotation about the body's x
axis, not a joint): the base of the neck lies in front of the lumbar spine's line (4 cm on
anny bodies), and a straight trunk put the neck and the shoulders that hang from it there.
Each clavicle rests ``clavicle_rest`` = (elevation, protraction) away from the horizontal
lateral line, added to both clavicles' joint angles (mirrored, like their axes): anny's
shoulders sit some 7 cm below the base of the neck, 20 degrees under a horizontal clavicle, and
a skeleton without the offset pinned its clavicles at their limits or shrugged them to fit. The
upper arms start from that rest rotation turned back, so arm angles keep their meaning.

Defaults describe an average adult of about 1.75 m (rounded anthropometric figures):
stature = ankle height + shank + thigh + pelvis + abdomen + chest + neck + head.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .skeleton import NUM_SEGMENTS, SEGMENT_AXIS, SEGMENT_NAMES

# The segments that carry the feet (left, right): the shanks.
FOOT_SEGMENTS = (SEGMENT_NAMES.index("l_shank"), SEGMENT_NAMES.index("r_shank"))

__all__ = [
    "BodyShape",
    "DEFAULT_LENGTHS",
    "DEFAULT_RADII",
    "DEFAULT_EXTENTS",
    "DEFAULT_HIP_HALF_WIDTH",
    "DEFAULT_FEET",
    "FOOT_SEGMENTS",
    "cross_section_axes",
    "BODY_FORMAT",
    "BODY_VERSION",
]

BODY_FORMAT = "depthmocap-body"
# Version 2 added section centre offsets and feet; version 1 files load with zero offsets and
# the default feet scaled to the body's stature. Version 3 added the chest tilt, version 4 the
# clavicle rest angles (earlier versions: 0).
BODY_VERSION = 4

# Joint-to-joint lengths in metres, in SEGMENT_NAMES order.
DEFAULT_LENGTHS = np.array(
    [0.10, 0.20, 0.22, 0.10, 0.22, 0.18, 0.18, 0.29, 0.29, 0.26, 0.26, 0.43, 0.43, 0.42, 0.42]
)
# Semi-axes (first, second cross-section direction); for vertical segments (x = lateral,
# z = depth). Pelvis, abdomen and chest are the elliptic torso.
DEFAULT_RADII = np.array(
    [
        [0.16, 0.11],
        [0.14, 0.10],
        [0.17, 0.11],
        [0.055, 0.055],
        [0.08, 0.095],
        [0.05, 0.05],
        [0.05, 0.05],
        [0.05, 0.05],
        [0.05, 0.05],
        [0.04, 0.04],
        [0.04, 0.04],
        [0.08, 0.08],
        [0.08, 0.08],
        [0.055, 0.055],
        [0.055, 0.055],
    ]
)
# Geometry beyond the joints: (before the origin, beyond the end). The pelvis reaches below
# the hip joints, forearms cover the hand, shanks reach the sole.
DEFAULT_EXTENTS = np.array(
    [
        [0.08, 0.0],
        [0.0, 0.0],
        [0.0, 0.0],
        [0.0, 0.0],
        [0.0, 0.02],
        [0.0, 0.0],
        [0.0, 0.0],
        [0.0, 0.0],
        [0.0, 0.0],
        [0.0, 0.10],
        [0.0, 0.10],
        [0.0, 0.0],
        [0.0, 0.0],
        [0.0, 0.07],
        [0.0, 0.07],
    ]
)
DEFAULT_HIP_HALF_WIDTH = 0.09
L, E = DEFAULT_LENGTHS, DEFAULT_EXTENTS
_DEFAULT_STATURE = float(L[11] + L[13] + E[13, 1] + L[:5].sum() + E[4, 1])  # as BodyShape.stature
del L, E
# Foot of each side (left, right): (toe tip forward of the shank axis, radius), metres.
DEFAULT_FEET = np.array([[0.19, 0.035], [0.19, 0.035]])
# Clavicle rest angles beyond this (rad) are no body: anny bodies measure 0.3-0.4 rad down.
_MAX_CLAVICLE_REST = 0.8


def cross_section_axes() -> np.ndarray:
    """Unit directions of the two semi-axes of each segment, in its frame: (15, 2, 3).

    Vertical segments use (x, z); the horizontal clavicles use (y, z).
    """
    axes = np.zeros((NUM_SEGMENTS, 2, 3))
    vertical = np.abs(SEGMENT_AXIS[:, 1]) > 0.5
    axes[vertical, 0] = (1.0, 0.0, 0.0)
    axes[~vertical, 0] = (0.0, 1.0, 0.0)
    axes[:, 1] = (0.0, 0.0, 1.0)
    return axes


@dataclass
class BodyShape:
    """Parameters of one or many bodies, batch-first and broadcastable.

    Attributes:
        lengths: (..., 15) joint-to-joint length of each segment, metres.
        radii: (..., 15, 2) cross-section semi-axes of each segment, metres.
        extents: (..., 15, 2) geometry before the origin / beyond the end, metres.
        hip_half_width: (...) lateral distance of each hip joint from the hip centre, metres.
        offsets: (..., 15, 2) centre of each cross-section relative to the joint axis, along
            the two cross-section directions, metres (None: zeros, the cylinder on the axis).
        feet: (..., 2, 2) left and right foot: (toe tip forward of the shank axis, radius),
            metres (None: the default feet scaled by stature).
        chest_tilt: (...) forward lean of the chest on the abdomen, radians (None: upright).
        clavicle_rest: (..., 2) rest (elevation, protraction) of both clavicles, radians, added
            to their joint angles (None: zeros, horizontal clavicles).
    """

    lengths: torch.Tensor
    radii: torch.Tensor
    extents: torch.Tensor
    hip_half_width: torch.Tensor
    offsets: torch.Tensor | None = None
    feet: torch.Tensor | None = None
    chest_tilt: torch.Tensor | None = None
    clavicle_rest: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if self.offsets is None:
            self.offsets = torch.zeros_like(self.radii)
        if self.feet is None:
            default = torch.as_tensor(
                DEFAULT_FEET, dtype=self.radii.dtype, device=self.radii.device
            )
            ratio = self.stature() / _DEFAULT_STATURE
            self.feet = default * ratio[..., None, None]
        if self.chest_tilt is None:
            self.chest_tilt = torch.zeros_like(self.hip_half_width)
        if self.clavicle_rest is None:
            self.clavicle_rest = self.hip_half_width.new_zeros(*self.hip_half_width.shape, 2)

    @classmethod
    def default(
        cls, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
    ) -> BodyShape:
        """The average adult of the module docstring, unbatched."""

        def t(a):  # a copy: in-place edits of one body must not reach the module's defaults
            return torch.tensor(a, dtype=dtype, device=device)

        return cls(
            t(DEFAULT_LENGTHS), t(DEFAULT_RADII), t(DEFAULT_EXTENTS), t(DEFAULT_HIP_HALF_WIDTH)
        )

    def to(self, dtype: torch.dtype | None = None, device=None) -> BodyShape:
        """Same body with tensors on ``device`` / in ``dtype``."""
        return BodyShape(*(x.to(device=device, dtype=dtype) for x in self._fields()))

    def _fields(self) -> tuple[torch.Tensor, ...]:
        return (
            self.lengths, self.radii, self.extents, self.hip_half_width, self.offsets, self.feet,
            self.chest_tilt, self.clavicle_rest,
        )  # fmt: skip

    def scaled(self, factor: float | torch.Tensor) -> BodyShape:
        """Uniformly scaled body (every length and radius times ``factor``)."""
        f = torch.as_tensor(factor, dtype=self.lengths.dtype, device=self.lengths.device)
        return BodyShape(
            self.lengths * f[..., None],
            self.radii * f[..., None, None],
            self.extents * f[..., None, None],
            self.hip_half_width * f,
            self.offsets * f[..., None, None],
            self.feet * f[..., None, None],
            self.chest_tilt,
            self.clavicle_rest,
        )

    def girthed(self, factor: float | torch.Tensor) -> BodyShape:
        """The body made ``factor`` times as wide and deep, its lengths kept: every radius,
        cross-section offset and the hip half-width times ``factor`` (the segments' end caps,
        and so the stature, stay)."""
        f = torch.as_tensor(factor, dtype=self.lengths.dtype, device=self.lengths.device)
        return BodyShape(
            self.lengths,
            self.radii * f[..., None, None],
            self.extents,
            self.hip_half_width * f,
            self.offsets * f[..., None, None],
            self.feet,
            self.chest_tilt,
            self.clavicle_rest,
        )

    def select(self, index: slice | torch.Tensor) -> BodyShape:
        """The bodies at ``index`` of a batch of bodies (fields without the batch dimension,
        such as a scaled batch's chest tilt, are shared and kept as they are)."""
        if self.lengths.dim() != 2:
            shape = tuple(self.lengths.shape)
            raise ValueError(f"select needs a batch of bodies, lengths are {shape}")
        unbatched = (1, 2, 2, 0, 2, 2, 0, 1)  # each field's dimensions for one body
        fields = zip(self._fields(), unbatched, strict=True)
        return BodyShape(*(x[index] if x.dim() > d else x for x, d in fields))

    def stature(self) -> torch.Tensor:
        """Standing height (...,): sole to top of head with all joint angles zero."""
        L, E = self.lengths, self.extents
        legs = L[..., 11] + L[..., 13] + E[..., 13, 1]
        trunk = L[..., 0] + L[..., 1] + L[..., 2] + L[..., 3] + L[..., 4] + E[..., 4, 1]
        return legs + trunk

    def validate(self) -> None:
        """Raise ``ValueError`` on wrong shapes or non-positive / non-finite sizes."""
        if self.lengths.shape[-1] != NUM_SEGMENTS:
            raise ValueError(
                f"body lengths must end in {NUM_SEGMENTS}, got {tuple(self.lengths.shape)}"
            )
        for name, x in (
            ("radii", self.radii),
            ("extents", self.extents),
            ("offsets", self.offsets),
        ):
            if tuple(x.shape[-2:]) != (NUM_SEGMENTS, 2):
                raise ValueError(
                    f"body {name} must end in ({NUM_SEGMENTS}, 2), got {tuple(x.shape)}"
                )
        if tuple(self.feet.shape[-2:]) != (2, 2):
            raise ValueError(f"body feet must end in (2, 2), got {tuple(self.feet.shape)}")
        names = ("lengths", "radii", "extents", "hip_half_width", "offsets", "feet", "chest_tilt",
                 "clavicle_rest")  # fmt: skip
        for name, x in zip(names, self._fields()):
            if not bool(torch.isfinite(x).all()):
                raise ValueError(f"body {name} has non-finite values")
        if bool((self.lengths <= 0).any()) or bool((self.radii <= 0).any()):
            raise ValueError("body lengths and radii must be positive")
        if bool((self.feet <= 0).any()):
            raise ValueError("body feet must have positive lengths and radii")
        if bool((self.extents < 0).any()) or bool((self.hip_half_width <= 0).any()):
            raise ValueError("body extents must be >= 0 and hip_half_width > 0")
        if bool((self.chest_tilt.abs() > 0.6).any()):
            raise ValueError("body chest_tilt must lie within +-0.6 rad")
        if self.clavicle_rest.shape[-1:] != (2,):
            shape = tuple(self.clavicle_rest.shape)
            raise ValueError(f"body clavicle_rest must end in 2, got {shape}")
        if bool((self.clavicle_rest.abs() > _MAX_CLAVICLE_REST).any()):
            raise ValueError(f"body clavicle_rest must lie within +-{_MAX_CLAVICLE_REST} rad")

    # -- body file (JSON): what calibration and personalization write --------------------
    def to_json_dict(self) -> dict:
        """A single body as a JSON-ready dict with per-segment named entries."""
        if self.lengths.dim() != 1:
            raise ValueError("only a single (unbatched) body can be written to a body file")
        segs = {
            name: {
                "length": float(self.lengths[k]),
                "radii": [float(r) for r in self.radii[k]],
                "extents": [float(e) for e in self.extents[k]],
                "offsets": [float(o) for o in self.offsets[k]],
            }
            for k, name in enumerate(SEGMENT_NAMES)
        }
        for side, k in enumerate(FOOT_SEGMENTS):
            segs[SEGMENT_NAMES[k]]["foot"] = [float(f) for f in self.feet[side]]
        return {
            "format": BODY_FORMAT,
            "version": BODY_VERSION,
            "units": "m",
            "hip_half_width": float(self.hip_half_width),
            "chest_tilt": float(self.chest_tilt),
            "clavicle_rest": [float(a) for a in self.clavicle_rest],
            "segments": segs,
        }

    @classmethod
    def from_json_dict(cls, data: dict, dtype: torch.dtype = torch.float32) -> BodyShape:
        """Parse and validate a body-file dict; clear ``ValueError`` on anything off."""
        if not isinstance(data, dict) or data.get("format") != BODY_FORMAT:
            raise ValueError(f"not a body file (expected format '{BODY_FORMAT}')")
        version = data.get("version")
        if not isinstance(version, int) or version > BODY_VERSION or version < 1:
            raise ValueError(f"body file version {version!r} is not supported (<= {BODY_VERSION})")
        segs = data.get("segments")
        if not isinstance(segs, dict):
            raise ValueError("body file has no 'segments' table")
        missing = [n for n in SEGMENT_NAMES if n not in segs]
        if missing:
            raise ValueError(f"body file lacks segments: {', '.join(missing)}")
        try:
            lengths = [float(segs[n]["length"]) for n in SEGMENT_NAMES]
            radii = [[float(r) for r in segs[n]["radii"]] for n in SEGMENT_NAMES]
            extents = [
                [float(e) for e in segs[n].get("extents", (0.0, 0.0))] for n in SEGMENT_NAMES
            ]
            offsets = [
                [float(o) for o in segs[n].get("offsets", (0.0, 0.0))] for n in SEGMENT_NAMES
            ]
            hw = float(data["hip_half_width"])
            tilt = float(data.get("chest_tilt", 0.0))
            clavicle = [float(a) for a in data.get("clavicle_rest", (0.0, 0.0))]
            feet = [segs[SEGMENT_NAMES[k]].get("foot") for k in FOOT_SEGMENTS]
            feet = None if any(f is None for f in feet) else [[float(x) for x in f] for f in feet]
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"body file is malformed: {err}") from None
        t = lambda a: torch.tensor(a, dtype=dtype)  # noqa: E731
        body = cls(t(lengths), t(radii), t(extents), t(hw), t(offsets), feet and t(feet), t(tilt),
                   t(clavicle))  # fmt: skip
        body.validate()
        return body

    def save(self, path: str | Path) -> None:
        """Write the body file (JSON)."""
        Path(path).write_text(json.dumps(self.to_json_dict(), indent=2))

    @classmethod
    def load(cls, path: str | Path, dtype: torch.dtype = torch.float32) -> BodyShape:
        """Read a body file; ``ValueError`` with the path on malformed content."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise FileNotFoundError(f"body file not found: {path}") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise ValueError(f"{path}: not valid JSON ({err})") from None
        try:
            return cls.from_json_dict(data, dtype)
        except ValueError as err:
            raise ValueError(f"{path}: {err}") from None
