"""Pinhole depth camera: intrinsics, depth image <-> camera-frame points, projection.

OpenCV convention: x right, y down, z forward; pixel (u, v) = column, row; depth is metric z
(not ray length). Kinect v1 defaults: 640x480 with fx = fy = 575.8, cx = 319.5, cy = 239.5;
other resolutions scale these so that the field of view stays the same.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch

__all__ = [
    "Intrinsics",
    "depth_to_points",
    "masked_points",
    "points_to_pixels",
    "pixel_grid",
    "depth_mm_to_m",
]

KINECT_V1_640 = (640, 480, 575.8, 575.8, 319.5, 239.5)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a depth image.

    Attributes:
        width: image width in pixels.
        height: image height in pixels.
        fx: focal length along x, pixels.
        fy: focal length along y, pixels.
        cx: principal point column (pixel centres at integers).
        cy: principal point row.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def kinect_v1(cls, width: int = 320) -> Intrinsics:
        """Kinect v1 depth camera at ``width`` (640 native; 320, 160 keep the aspect)."""
        return cls(*KINECT_V1_640).resized(width, width * 3 // 4)

    def resized(self, width: int, height: int) -> Intrinsics:
        """Intrinsics of the same camera resampled to ``width`` x ``height``.

        Pixel centres stay consistent: a pixel edge at 0 maps to 0, so ``c' = (c + 0.5) s - 0.5``.
        """
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            width,
            height,
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
        )

    def cropped(self, u0: int, v0: int, width: int, height: int) -> Intrinsics:
        """Intrinsics of the window of ``width`` x ``height`` pixels whose corner is (u0, v0)."""
        return Intrinsics(width, height, self.fx, self.fy, self.cx - u0, self.cy - v0)

    def validate(self) -> None:
        """Raise ``ValueError`` unless sizes and focal lengths are positive and finite."""
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(isinstance(v, (int, float)) and v == v and abs(v) != float("inf") for v in vals):
            raise ValueError(f"intrinsics must be finite numbers, got {vals}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    def as_dict(self) -> dict:
        return asdict(self)

    def matrix(self, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
        """3x3 camera matrix K."""
        return torch.tensor(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]],
            dtype=dtype,
            device=device,
        )


def pixel_grid(height: int, width: int, dtype: torch.dtype = torch.float32, device=None):
    """Pixel coordinates ``(u, v)``, each (H, W): column and row indices."""
    v, u = torch.meshgrid(
        torch.arange(height, dtype=dtype, device=device),
        torch.arange(width, dtype=dtype, device=device),
        indexing="ij",
    )
    return u, v


def depth_to_points(depth: torch.Tensor, intr: Intrinsics) -> torch.Tensor:
    """Back-project a metric depth image to camera-frame points.

    Args:
        depth: (B, H, W) metric z in metres; 0 where there is no reading.
        intr: intrinsics of an H x W image.
    Returns:
        (B, H, W, 3); pixels without a reading give (0, 0, 0).
    """
    if depth.shape[-2:] != (intr.height, intr.width):
        raise ValueError(
            f"depth is {tuple(depth.shape[-2:])} (H, W) but intrinsics are for "
            f"{intr.height}x{intr.width}"
        )
    u, v = pixel_grid(intr.height, intr.width, depth.dtype, depth.device)
    x = (u - intr.cx) / intr.fx * depth
    y = (v - intr.cy) / intr.fy * depth
    return torch.stack([x, y, depth], -1)


def masked_points(depth: torch.Tensor, mask: torch.Tensor, intr: Intrinsics) -> torch.Tensor:
    """The camera-frame points of the ``mask`` pixels of one depth image: (N, 3), in the
    mask's row-major order; ``depth_to_points(depth[None], intr)[0][mask]`` to the bit, for
    the pixels a person covers instead of the whole image.

    Args:
        depth: (H, W) metric z in metres; mask: (H, W) bool.
    """
    if depth.shape != (intr.height, intr.width) or mask.shape != depth.shape:
        raise ValueError(
            f"depth {tuple(depth.shape)} and mask {tuple(mask.shape)} must both be "
            f"{intr.height}x{intr.width}"
        )
    v, u = mask.nonzero(as_tuple=True)
    z = depth[v, u]
    x = (u.to(depth.dtype) - intr.cx) / intr.fx * z
    y = (v.to(depth.dtype) - intr.cy) / intr.fy * z
    return torch.stack([x, y, z], -1)


def points_to_pixels(points: torch.Tensor, intr: Intrinsics) -> torch.Tensor:
    """Project camera-frame points to continuous pixel coordinates.

    Args:
        points: (..., 3) with z > 0 for points in front of the camera.
    Returns:
        (..., 2) as (u, v); points with z <= 0 give non-finite values (mask them by z).
    """
    z = points[..., 2]
    u = intr.fx * points[..., 0] / z + intr.cx
    v = intr.fy * points[..., 1] / z + intr.cy
    return torch.stack([u, v], -1)


def depth_mm_to_m(depth_mm: torch.Tensor) -> torch.Tensor:
    """uint16 millimetres (0 = no reading) -> float metres in the default float dtype."""
    return depth_mm.to(torch.get_default_dtype()) * 1e-3
