"""The lean 2D form of a scan that a keyframe keeps: obstacle points and free ranges.

A keyframe must be enough to (re)build the global grid at its optimised pose with the same rule
as NavTopo's location grids (``navtopo.local_grid``): obstacles are the returns in the shared
floor/ceiling band, and free space is traced towards every return, stopping at the first
occupied cell. Every channel of one azimuth traces the same 2D line, so only the farthest return
per azimuth matters for free space: ``free_ranges`` keeps that range per azimuth bin (1° bins
centred on whole degrees, as the simulated lidar's columns are), 720 bytes as float16.
Obstacle points are thinned by a 0.1 m voxel filter (one mean point per occupied voxel).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from navkit.scan import HeightBand, azimuth_bins, obstacle_points

AZIMUTH_BINS = 360


def voxel_filter_2d(points: ArrayLike, voxel: float) -> NDArray[np.float32]:
    """(N, >=2) -> (M, 2) float32: the mean x, y of the points in each occupied voxel."""
    xy = np.asarray(points, dtype=np.float64)
    if len(xy) == 0:  # a scan with no returns (open space beyond range): reshape(0, -1) would raise
        return np.zeros((0, 2), np.float32)
    xy = xy.reshape(len(xy), -1)[:, :2]
    cells = np.floor(xy / voxel).astype(np.int64)
    keys = (cells[:, 0] << 32) + cells[:, 1]  # one int64 per voxel: 1D unique is ~10x faster
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    mean_x = np.bincount(inverse, weights=xy[:, 0]) / counts
    mean_y = np.bincount(inverse, weights=xy[:, 1]) / counts
    return np.stack([mean_x, mean_y], axis=-1).astype(np.float32)


def free_ranges(points: ArrayLike, bins: int = AZIMUTH_BINS) -> NDArray[np.float16]:
    """(N, >=2) returns in the robot frame -> (bins,) float16 farthest 2D range per azimuth bin.

    Bin ``b`` is centred on azimuth ``b * 2π / bins``; 0 means no return in that bin.
    """
    p = np.asarray(points, dtype=np.float64)
    ranges = np.zeros(bins)
    if len(p) == 0:
        return ranges.astype(np.float16)
    r = np.hypot(p[:, 0], p[:, 1])
    np.maximum.at(ranges, azimuth_bins(p, bins), r)
    return ranges.astype(np.float16)


def free_endpoints(ranges: ArrayLike) -> NDArray[np.float64]:
    """(B,) ranges per azimuth bin -> (M, 2) endpoints in the robot frame (bins with a return)."""
    r = np.asarray(ranges, dtype=np.float64)
    azimuth = np.arange(len(r)) * (2.0 * np.pi / max(len(r), 1))
    keep = r > 0
    return np.stack([r[keep] * np.cos(azimuth[keep]), r[keep] * np.sin(azimuth[keep])], axis=-1)


def keyframe_scan(
    points: ArrayLike,
    band: HeightBand | None = None,
    voxel: float = 0.1,
    bins: int = AZIMUTH_BINS,
) -> tuple[NDArray[np.float32], NDArray[np.float16]]:
    """(N, 3) lidar returns in the robot frame (floor hits included) -> the keyframe's scan:
    (M, 2) float32 voxel-filtered obstacle points and (bins,) float16 free ranges."""
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    obstacles = voxel_filter_2d(obstacle_points(p, band), voxel)
    return obstacles, free_ranges(p, bins)
