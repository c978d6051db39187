"""Point-cloud helpers shared by the descriptors: cropping, yaw rotation, polar coordinates.

The simulated lidar sits 0.6 m above the floor and sees the floor; floor hits carry no
place information and dominate the voxel count, so every descriptor drops points below
``min_z`` (docs/NOTES.md: 0.15 m) and beyond the sensor range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .registry import Cloud


@dataclass(frozen=True)
class CropConfig:
    """Which returns a descriptor reads: heights in metres above the floor, horizontal range."""

    min_z: float = 0.15
    max_z: float = 4.0
    max_range: float = 15.0


DEFAULT_CROP = CropConfig()


def crop_cloud(points: Cloud, crop: CropConfig = DEFAULT_CROP) -> Cloud:
    """Keep finite points with ``min_z <= z < max_z`` and horizontal range ``< max_range``."""
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    horizontal = np.hypot(points[:, 0], points[:, 1])
    keep = (
        np.isfinite(points).all(axis=1)
        & (points[:, 2] >= crop.min_z)
        & (points[:, 2] < crop.max_z)
        & (horizontal < crop.max_range)
    )
    return points[keep]


def rotate_yaw(points: Cloud, yaw: float) -> Cloud:
    """Rotate points (N, 3) about the z axis by ``yaw`` radians (counter-clockwise)."""
    c, s = np.cos(yaw), np.sin(yaw)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=np.float32)
    return (np.asarray(points, dtype=np.float32) @ rotation.T).astype(np.float32)


def polar_bins(
    points: Cloud, rings: int, sectors: int, max_range: float
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
    """Ring and sector index of each point and a mask of points inside ``max_range``.

    Sector 0 starts at azimuth -pi (behind the robot) and sectors grow counter-clockwise, so
    turning the scan by ``+360/sectors`` degrees moves every point one sector up (mod sectors).
    """
    radius = np.hypot(points[:, 0], points[:, 1])
    azimuth = np.arctan2(points[:, 1], points[:, 0])
    ring = np.floor(radius / (max_range / rings)).astype(np.int64)
    sector = np.floor((azimuth + np.pi) / (2.0 * np.pi) * sectors).astype(np.int64) % sectors
    inside = ring < rings
    return ring, sector, inside
