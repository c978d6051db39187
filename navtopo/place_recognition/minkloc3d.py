"""MinkLoc3D: a sparse 3D convolutional feature pyramid with GeM pooling.

After Komorowski, "MinkLoc3D: Point Cloud Based Large-Scale Place Recognition", WACV 2021
(its MinkFPN, Sec. 3): quantise the cloud, a 5^3 convolution, three stride-2 stages with
residual blocks, a top-down (FPN) path that upsamples the coarsest level and adds the
lateral 1x1 projection of the level above it, then generalised-mean pooling into a 256-d
descriptor. MinkowskiEngine does not build on this CPU-only stack, so the sparse
convolutions are the plain-torch ones of :mod:`.sparse` (hashed voxel keys).

Two changes for this setting (docs/NOTES.md, "Place recognition on 2 CPU cores"):

* 0.2 m voxels of the scan with floor hits (z < 0.15 m) dropped: ~1,100 voxels per scan;
* a BatchNorm on the pooled 256-d vector before L2 normalisation: without it the batch-hard
  triplet loss collapsed to the margin within 90 s of training.

The input feature of every voxel is 1 (the geometry is in the coordinates), as in MinkLoc3D.
The network is not yaw-invariant: training turns every scan by a random yaw.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from .clouds import DEFAULT_CROP, CropConfig, crop_cloud
from .learned import LearnedDescriptor
from .registry import Cloud, register_descriptor
from .sparse import (
    DownsampleConv3d,
    SparseBatchNorm,
    SparseGeM,
    SparseLinear,
    SparseTensor,
    SubmanifoldConv3d,
    UpsampleConv3d,
    VoxelSet,
    sparse_relu,
)


class ResidualBlock(nn.Module):
    """conv3-BN-ReLU-conv3-BN plus identity, then ReLU (ResNet BasicBlock)."""

    def __init__(self, channels: int):
        super().__init__()
        self.conv1 = SubmanifoldConv3d(channels, channels, 3)
        self.norm1 = SparseBatchNorm(channels)
        self.conv2 = SubmanifoldConv3d(channels, channels, 3)
        self.norm2 = SparseBatchNorm(channels)

    def forward(self, x: SparseTensor) -> SparseTensor:
        out = sparse_relu(self.norm1(self.conv1(x)))
        out = self.norm2(self.conv2(out))
        return sparse_relu(out.replace(out.feats + x.feats))


class MinkLoc3DNet(nn.Module):
    """MinkFPN + GeM + BatchNorm + L2 normalisation: ``VoxelSet`` (stride 1) -> (B, feature_size).

    Levels: conv0 at the voxel size, then stages at strides 2, 4, 8 (``planes``); the top-down
    path ends at stride 4 (0.8 m with 0.2 m voxels), where GeM pools.
    """

    def __init__(
        self,
        planes: Sequence[int] = (32, 64, 64),
        conv0_kernel: int = 5,
        feature_size: int = 256,
    ):
        super().__init__()
        if len(planes) < 2:
            raise ValueError("MinkLoc3DNet needs at least two stages")
        self.conv0 = SubmanifoldConv3d(1, planes[0], conv0_kernel)
        self.norm0 = SparseBatchNorm(planes[0])
        self.downs = nn.ModuleList()
        self.down_norms = nn.ModuleList()
        self.blocks = nn.ModuleList()
        previous = planes[0]
        for channels in planes:
            self.downs.append(DownsampleConv3d(previous, channels))
            self.down_norms.append(SparseBatchNorm(channels))
            self.blocks.append(ResidualBlock(channels))
            previous = channels
        self.top_lateral = SparseLinear(planes[-1], feature_size)
        self.upsample = UpsampleConv3d(feature_size, feature_size)
        self.lateral = SparseLinear(planes[-2], feature_size)
        self.pool = SparseGeM()
        self.descriptor_norm = nn.BatchNorm1d(feature_size)

    def forward(self, voxels: VoxelSet) -> Tensor:
        ones = torch.ones(len(voxels), 1)
        x = sparse_relu(self.norm0(self.conv0(SparseTensor(ones, voxels))))
        levels = []
        for down, norm, block in zip(self.downs, self.down_norms, self.blocks, strict=True):
            x = block(sparse_relu(norm(down(x))))
            levels.append(x)
        top = self.top_lateral(levels[-1])
        lateral = self.lateral(levels[-2])
        merged = self.upsample(top, lateral.voxels)
        merged = merged.replace(merged.feats + lateral.feats)
        pooled = self.pool(merged)
        return nn.functional.normalize(self.descriptor_norm(pooled), dim=1)


def voxelize_batch(clouds: Sequence[Cloud], voxel_size: float, crop: CropConfig = DEFAULT_CROP) -> VoxelSet:
    """Crop each cloud and quantise it to ``voxel_size`` voxels (deduplicated by ``VoxelSet``),
    batch index first.

    A cloud with no points left gets one voxel at the origin so that every batch element has
    a descriptor (a blank scan: nothing to recognise, but no NaNs).
    """
    blocks = []
    for index, cloud in enumerate(clouds):
        points = crop_cloud(cloud, crop)
        cells = np.floor(points / voxel_size).astype(np.int64)
        if len(cells) == 0:
            cells = np.zeros((1, 3), dtype=np.int64)
        blocks.append(np.concatenate([np.full((len(cells), 1), index, np.int64), cells], axis=1))
    coords = torch.from_numpy(np.concatenate(blocks)) if blocks else torch.zeros((0, 4), dtype=torch.int64)
    return VoxelSet.from_coords(coords, batch_size=len(clouds))


@register_descriptor("minkloc3d")
class MinkLoc3D(LearnedDescriptor):
    """MinkLoc3D descriptor (256-d); see the module docstring.

    ``make_descriptor("minkloc3d")`` loads ``weights/minkloc3d.pt``; ``weights=None`` gives an
    untrained network (tests, training from scratch).
    """

    def __init__(
        self,
        weights: str | Path | None = "default",
        threads: int | None = None,
        voxel_size: float = 0.2,
        planes: Sequence[int] = (32, 64, 64),
        conv0_kernel: int = 5,
        feature_size: int = 256,
        min_z: float = 0.15,
        max_range: float = 15.0,
    ):
        self.voxel_size = float(voxel_size)
        self.crop = CropConfig(min_z=min_z, max_range=max_range)
        self.dim = int(feature_size)
        self.architecture = {
            "voxel_size": self.voxel_size,
            "planes": [int(p) for p in planes],
            "conv0_kernel": int(conv0_kernel),
            "feature_size": self.dim,
            "min_z": float(min_z),
            "max_range": float(max_range),
        }
        self.network = MinkLoc3DNet(planes, conv0_kernel, feature_size)
        super().__init__(weights, threads)

    def collate(self, clouds: Sequence[Cloud]) -> VoxelSet:
        return voxelize_batch(clouds, self.voxel_size, self.crop)
