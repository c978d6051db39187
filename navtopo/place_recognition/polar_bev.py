"""A polar bird's-eye-view CNN: heading-invariant by construction.

The scan is binned into ``height_bins x rings x sectors`` occupancy (8 x 30 rings of 0.5 m x
120 sectors of 3 degrees). Turning the robot in place shifts the image along the sector axis
(circularly), so every convolution pads circularly in azimuth and each ring is pooled over all
sectors with GeM. A shift by a multiple of the total azimuth stride (4 sectors, 12 degrees)
therefore leaves the descriptor exactly unchanged (up to binning); other headings are nearly
so, and random yaw augmentation in training teaches the rest. The rings stay apart (a linear
layer reads them in order) because distance to the structure is what tells places apart.

docs/NOTES.md ("Place recognition on 2 CPU cores"): this design trained ~3x faster per step than
the MinkLoc3D network and reached recall@1 0.98 after one minute on generated corridor worlds;
it stands beside MinkLoc3D (the paper's choice) and Scan Context in the registry.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from .clouds import CropConfig, crop_cloud, polar_bins
from .learned import LearnedDescriptor
from .registry import Cloud, register_descriptor


class RingGeM(nn.Module):
    """GeM over the sector axis: (B, C, R, S) -> (B, C, R)."""

    def __init__(self, p: float = 3.0, eps: float = 1e-6):
        super().__init__()
        self.p = nn.Parameter(torch.tensor([p]))
        self.eps = eps

    def forward(self, x: Tensor) -> Tensor:
        return x.clamp(min=self.eps).pow(self.p).mean(dim=3).pow(1.0 / self.p)


class PolarBEVNet(nn.Module):
    """(B, height_bins, rings, sectors) occupancy -> (B, feature_size) L2-normalised.

    3x3 conv-BN-ReLU layers of ``channels`` widths with ``strides`` (rings, sectors) each.
    """

    def __init__(
        self,
        height_bins: int = 8,
        rings: int = 30,
        channels: Sequence[int] = (32, 32, 64, 64, 128, 128),
        strides: Sequence[Sequence[int]] = ((1, 1), (2, 2), (1, 1), (2, 2), (1, 1), (2, 1)),
        feature_size: int = 256,
    ):
        super().__init__()
        if len(strides) != len(channels):
            raise ValueError("PolarBEVNet: one (ring, sector) stride per layer")
        layers: list[nn.Module] = []
        previous, remaining_rings = height_bins, rings
        for width, stride in zip(channels, strides, strict=True):
            layers += [
                nn.Conv2d(previous, width, 3, stride=(stride[0], stride[1]), padding=(1, 0), bias=False),
                nn.BatchNorm2d(width),
                nn.ReLU(inplace=True),
            ]
            remaining_rings = (remaining_rings - 1) // stride[0] + 1
            previous = width
        self.layers = nn.ModuleList(layers)
        self.pool = RingGeM()
        self.project = nn.Linear(previous * remaining_rings, feature_size)
        self.descriptor_norm = nn.BatchNorm1d(feature_size)

    def forward(self, bev: Tensor) -> Tensor:
        x = bev
        for layer in self.layers:
            if isinstance(layer, nn.Conv2d):
                x = nn.functional.pad(x, (1, 1, 0, 0), mode="circular")  # azimuth wraps
            x = layer(x)
        pooled = self.pool(x).flatten(1)
        return nn.functional.normalize(self.descriptor_norm(self.project(pooled)), dim=1)


def polar_occupancy(
    points: Cloud,
    height_bins: int,
    rings: int,
    sectors: int,
    crop: CropConfig,
) -> np.ndarray:
    """(height_bins, rings, sectors) float32 0/1 occupancy of a robot-frame cloud.

    Heights ``[min_z, max_z)`` split evenly; rings cover ``[0, max_range)``.
    """
    points = crop_cloud(points, crop)
    ring, sector, inside = polar_bins(points, rings, sectors, crop.max_range)
    level = (points[:, 2] - crop.min_z) / (crop.max_z - crop.min_z) * height_bins
    level = np.clip(level.astype(np.int64), 0, height_bins - 1)
    grid = np.zeros((height_bins, rings, sectors), dtype=np.float32)
    grid[level[inside], ring[inside], sector[inside]] = 1.0
    return grid


@register_descriptor("polar_bev")
class PolarBEV(LearnedDescriptor):
    """Polar bird's-eye-view CNN descriptor (256-d, heading-invariant)."""

    def __init__(
        self,
        weights: str | Path | None = "default",
        threads: int | None = None,
        height_bins: int = 8,
        rings: int = 30,
        sectors: int = 120,
        channels: Sequence[int] = (32, 32, 64, 64, 128, 128),
        strides: Sequence[Sequence[int]] = ((1, 1), (2, 2), (1, 1), (2, 2), (1, 1), (2, 1)),
        feature_size: int = 256,
        min_z: float = 0.15,
        max_z: float = 3.35,
        max_range: float = 15.0,
    ):
        self.height_bins, self.rings, self.sectors = int(height_bins), int(rings), int(sectors)
        self.crop = CropConfig(min_z=min_z, max_z=max_z, max_range=max_range)
        self.dim = int(feature_size)
        self.architecture = {
            "height_bins": self.height_bins,
            "rings": self.rings,
            "sectors": self.sectors,
            "channels": [int(c) for c in channels],
            "strides": [[int(r), int(c)] for r, c in strides],
            "feature_size": self.dim,
            "min_z": float(min_z),
            "max_z": float(max_z),
            "max_range": float(max_range),
        }
        self.network = PolarBEVNet(height_bins, rings, channels, strides, feature_size)
        super().__init__(weights, threads)

    def collate(self, clouds: Sequence[Cloud]) -> Tensor:
        grids = [polar_occupancy(c, self.height_bins, self.rings, self.sectors, self.crop) for c in clouds]
        if not grids:
            return torch.zeros((0, self.height_bins, self.rings, self.sectors))
        return torch.from_numpy(np.stack(grids))
