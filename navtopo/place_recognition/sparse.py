"""Sparse 3D convolutions in plain torch, for a CPU.

The voxels of a batch are integer coordinates ``[batch, x, y, z]``. Each is hashed to one
int64 key that is *linear* in the coordinates, ``key = ((b*S + x+O)*S + y+O)*S + z+O``, and
the voxels are kept sorted by key. A neighbour at offset (dx, dy, dz) then has key
``key + (dx*S + dy)*S + dz`` (docs/NOTES.md: ~5x faster than per-offset coordinate lookups), and
for one offset these wanted keys are sorted too, so one linear merge against the sorted keys
finds every voxel's neighbour (a compiled loop: 6x faster than ``torch.searchsorted`` for a
5^3 kernel over 34k voxels).

Three layers, as in MinkowskiEngine's MinkLoc3D:

* ``SubmanifoldConv3d``: k^3 kernel, output on the input voxels only (no dilation of the
  active set), inputs only from active voxels; equals a dense ``conv3d`` (padding k//2)
  read at the active sites.
* ``DownsampleConv3d``: kernel 2, stride 2; output voxel c gathers inputs 2c + {0,1}^3,
  equal to a dense ``conv3d(stride=2, kernel_size=2)`` at the active coarse sites.
* ``UpsampleConv3d``: transposed kernel 2, stride 2, written onto a given finer voxel set
  (the FPN's lateral level), equal to ``conv_transpose3d`` read at those voxels.

Each layer is an "im2col" gather of neighbour features (a zero row stands for a missing
neighbour) followed by one matrix product: few large BLAS calls suit two CPU cores.
Neighbour maps depend only on the voxels, so ``VoxelSet`` caches them across layers.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numba
import numpy as np
import torch
from torch import Tensor, nn

SPATIAL_BITS = 13
SPAN = 1 << SPATIAL_BITS
HALF_SPAN = SPAN // 2
MAX_COORDINATE = HALF_SPAN - 8  # |coordinate| bound: a kernel offset never wraps into the next axis


def coordinate_keys(coords: Tensor) -> Tensor:
    """(N, 4) int64 ``[batch, x, y, z]`` -> (N,) int64 keys, linear in the coordinates."""
    shifted = coords[:, 1:] + HALF_SPAN
    return ((coords[:, 0] * SPAN + shifted[:, 0]) * SPAN + shifted[:, 1]) * SPAN + shifted[:, 2]


def kernel_offsets(kernel_size: int) -> Tensor:
    """(K, 3) int64 offsets of a cubic kernel, ordered as ``itertools.product`` over x, y, z
    (the same order as the flattened spatial axes of a dense ``conv3d`` weight)."""
    radius = kernel_size // 2
    span = range(-radius, kernel_size - radius)
    return torch.tensor(list(itertools.product(span, span, span)), dtype=torch.int64)


@dataclass(eq=False)
class VoxelSet:
    """Unique active voxels of a batch, sorted by key; ``stride`` is the level (1, 2, 4, ...)."""

    coords: Tensor  # (N, 4) int64 [batch, x, y, z] in units of this level's voxels
    keys: Tensor  # (N,) int64, ascending
    batch_size: int
    stride: int = 1
    _neighbours: dict[int, Tensor] = field(default_factory=dict, repr=False)
    _coarser: CoarserLevel | None = field(default=None, repr=False)

    @staticmethod
    def from_coords(coords: Tensor, batch_size: int, stride: int = 1) -> VoxelSet:
        """Deduplicate and sort (N, 4) int64 coordinates."""
        if coords.numel() and (coords[:, 1:].abs().max() > MAX_COORDINATE):
            raise ValueError(f"voxel coordinates must lie within ±{MAX_COORDINATE}")
        keys, first = _unique_keys(coordinate_keys(coords))
        return VoxelSet(coords[first], keys, batch_size, stride)

    def __len__(self) -> int:
        return int(self.keys.shape[0])

    @property
    def batch_index(self) -> Tensor:
        return self.coords[:, 0]

    def neighbour_index(self, kernel_size: int) -> Tensor:
        """(N, K) int64: row of each voxel's neighbour per kernel offset, N where absent."""
        if kernel_size not in self._neighbours:
            offsets = kernel_offsets(kernel_size)
            deltas = (offsets[:, 0] * SPAN + offsets[:, 1]) * SPAN + offsets[:, 2]
            rows = _merge_lookup(self.keys.numpy(), deltas.numpy())
            self._neighbours[kernel_size] = torch.from_numpy(rows)
        return self._neighbours[kernel_size]

    def coarser(self) -> CoarserLevel:
        """The stride-2 voxel set above this one and how the two link (cached)."""
        if self._coarser is None:
            spatial = torch.div(self.coords[:, 1:], 2, rounding_mode="floor")
            parent_coords = torch.cat([self.coords[:, :1], spatial], dim=1)
            keys, first, parent = _unique_keys(coordinate_keys(parent_coords), True)
            coarse = VoxelSet(parent_coords[first], keys, self.batch_size, self.stride * 2)
            odd = self.coords[:, 1:] - 2 * spatial
            slot = parent * 8 + odd[:, 0] * 4 + odd[:, 1] * 2 + odd[:, 2]
            children = torch.full((len(coarse) * 8,), len(self), dtype=torch.int64)
            children[slot] = torch.arange(len(self))
            self._coarser = CoarserLevel(coarse, slot, children)
        return self._coarser


@dataclass(eq=False)
class CoarserLevel:
    """Link between a voxel set and its stride-2 parent set ``coarse``.

    ``slot`` (N,): ``8 * parent_row + 4*(x&1) + 2*(y&1) + (z&1)`` of each fine voxel (the
    order of a dense kernel-2 weight's spatial axes); ``children`` (8 * len(coarse),): the
    fine row in each slot, N where empty. Each is the other's inverse.
    """

    coarse: VoxelSet
    slot: Tensor
    children: Tensor


def _unique_keys(keys: Tensor, return_inverse: bool = False):
    """Sorted unique keys, the row of one occurrence of each, optionally the inverse map."""
    unique, inverse = torch.unique(keys, sorted=True, return_inverse=True)
    first = torch.full((len(unique),), len(keys), dtype=torch.int64)
    first.scatter_reduce_(0, inverse, torch.arange(len(keys)), reduce="amin")
    if return_inverse:
        return unique, first, inverse
    return unique, first


@numba.njit(cache=True)
def _merge_lookup(keys: np.ndarray, deltas: np.ndarray) -> np.ndarray:  # pragma: no cover
    """(N, K) row of ``keys[i] + deltas[k]`` in the ascending ``keys``, N where absent."""
    n = keys.shape[0]
    rows = np.full((n, deltas.shape[0]), n, dtype=np.int64)
    for k in range(deltas.shape[0]):
        j = 0
        for i in range(n):
            wanted = keys[i] + deltas[k]
            while j < n and keys[j] < wanted:
                j += 1
            if j < n and keys[j] == wanted:
                rows[i, k] = j
    return rows


@dataclass(eq=False)
class SparseTensor:
    """Features (N, C) on the voxels of a ``VoxelSet``."""

    feats: Tensor
    voxels: VoxelSet

    def replace(self, feats: Tensor) -> SparseTensor:
        return SparseTensor(feats, self.voxels)


def _pad(rows: Tensor) -> Tensor:
    """Append one zero row: index ``len(rows)`` then reads zeros (an absent neighbour)."""
    return torch.cat([rows, rows.new_zeros(1, rows.shape[1])], dim=0)


class _GatherOnce(torch.autograd.Function):
    """``pad(src)[index]`` where every source row is read at most once; ``inverse`` maps each
    source row to the output row that reads it (``len(index)`` if none). The backward pass is
    then a gather too, not the slow scatter-add of ``Tensor.__getitem__``'s backward."""

    @staticmethod
    def forward(ctx, src: Tensor, index: Tensor, inverse: Tensor) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(inverse)
        return _pad(src).index_select(0, index)

    @staticmethod
    def backward(ctx, grad: Tensor):  # type: ignore[override]
        (inverse,) = ctx.saved_tensors
        return _pad(grad).index_select(0, inverse), None, None


class _NeighbourConv(torch.autograd.Function):
    """Submanifold convolution ``out[i] = sum_k feats[nbr(i, d_k)] @ W_k``.

    Neighbourhood is symmetric (j = nbr(i, d) iff i = nbr(j, -d)) and reversing the offsets of
    ``kernel_offsets`` negates them, so the input gradient is the same gather applied to the
    output gradient with the kernel reversed and transposed: no scatter-add."""

    @staticmethod
    def forward(ctx, feats: Tensor, weight: Tensor, index: Tensor) -> Tensor:  # type: ignore[override]
        columns = _pad(feats).index_select(0, index.reshape(-1)).reshape(index.shape[0], -1)
        ctx.save_for_backward(columns, weight, index)
        return columns @ weight.reshape(-1, weight.shape[2])

    @staticmethod
    def backward(ctx, grad_out: Tensor):  # type: ignore[override]
        columns, weight, index = ctx.saved_tensors
        grad_feats = grad_weight = None
        if ctx.needs_input_grad[1]:
            grad_weight = (columns.T @ grad_out).reshape(weight.shape)
        if ctx.needs_input_grad[0]:
            gathered = _pad(grad_out).index_select(0, index.reshape(-1))
            mirrored = weight.flip(0).transpose(1, 2).reshape(-1, weight.shape[1])
            grad_feats = gathered.reshape(index.shape[0], -1) @ mirrored
        return grad_feats, grad_weight, None


class _KernelConv(nn.Module):
    """Weight (K, C_in, C_out), initialised like ``nn.Conv3d`` (Kaiming uniform, a=sqrt(5))."""

    def __init__(self, in_channels: int, out_channels: int, kernel_volume: int, bias: bool):
        super().__init__()
        self.in_channels, self.out_channels = in_channels, out_channels
        self.weight = nn.Parameter(torch.empty(kernel_volume, in_channels, out_channels))
        self.bias = nn.Parameter(torch.zeros(out_channels)) if bias else None
        bound = 1.0 / math.sqrt(in_channels * kernel_volume)
        nn.init.uniform_(self.weight, -bound, bound)
        if self.bias is not None:
            nn.init.uniform_(self.bias, -bound, bound)

    def _add_bias(self, out: Tensor) -> Tensor:
        return out + self.bias if self.bias is not None else out


class SubmanifoldConv3d(_KernelConv):
    """k^3 convolution (k odd) evaluated on the active voxels only (stride 1)."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 3, bias=False):
        if kernel_size % 2 != 1:
            raise ValueError("SubmanifoldConv3d needs an odd kernel size")
        super().__init__(in_channels, out_channels, kernel_size**3, bias)
        self.kernel_size = kernel_size

    def forward(self, x: SparseTensor) -> SparseTensor:
        index = x.voxels.neighbour_index(self.kernel_size)
        return x.replace(self._add_bias(_NeighbourConv.apply(x.feats, self.weight, index)))


class DownsampleConv3d(_KernelConv):
    """Kernel 2, stride 2: each coarse voxel sums its (up to 8) children, one weight each."""

    def __init__(self, in_channels: int, out_channels: int, bias: bool = False):
        super().__init__(in_channels, out_channels, 8, bias)

    def forward(self, x: SparseTensor) -> SparseTensor:
        link = x.voxels.coarser()
        columns = _GatherOnce.apply(x.feats, link.children, link.slot)
        columns = columns.reshape(len(link.coarse), 8 * self.in_channels)
        out = columns @ self.weight.reshape(-1, self.out_channels)
        return SparseTensor(self._add_bias(out), link.coarse)


class UpsampleConv3d(_KernelConv):
    """Transposed kernel 2, stride 2, onto ``fine`` (whose ``coarser()`` level is ``x``'s)."""

    def __init__(self, in_channels: int, out_channels: int, bias: bool = False):
        super().__init__(in_channels, out_channels, 8, bias)

    def forward(self, x: SparseTensor, fine: VoxelSet) -> SparseTensor:
        link = fine.coarser()
        if link.coarse is not x.voxels:
            raise ValueError("UpsampleConv3d: x must live on fine.coarser().coarse")
        # every coarse voxel's output for all 8 child slots, then each fine voxel reads its own
        # (grouping fine voxels by slot saves multiplications but measured no faster)
        weight = self.weight.permute(1, 0, 2).reshape(self.in_channels, -1)
        per_slot = (x.feats @ weight).reshape(-1, self.out_channels)
        out = _GatherOnce.apply(per_slot, link.slot, link.children)
        return SparseTensor(self._add_bias(out), fine)


class SparseBatchNorm(nn.BatchNorm1d):
    """BatchNorm over all active voxels of a batch (as MinkowskiEngine's)."""

    def forward(self, x: SparseTensor) -> SparseTensor:  # type: ignore[override]
        return x.replace(super().forward(x.feats))


def sparse_relu(x: SparseTensor) -> SparseTensor:
    return x.replace(torch.relu(x.feats))


class SparseLinear(nn.Linear):
    """A 1x1x1 convolution."""

    def forward(self, x: SparseTensor) -> SparseTensor:  # type: ignore[override]
        return x.replace(super().forward(x.feats))


class SparseGeM(nn.Module):
    """Generalised-mean pooling per batch element: ``(mean x^p)^(1/p)``, p learned (init 3)."""

    def __init__(self, p: float = 3.0, eps: float = 1e-6):
        super().__init__()
        self.p = nn.Parameter(torch.tensor([p]))
        self.eps = eps

    def forward(self, x: SparseTensor) -> Tensor:
        batch = x.voxels.batch_index
        powered = x.feats.clamp(min=self.eps).pow(self.p)
        sums = powered.new_zeros(x.voxels.batch_size, powered.shape[1]).index_add_(0, batch, powered)
        counts = torch.bincount(batch, minlength=x.voxels.batch_size).clamp(min=1)
        mean = sums / counts[:, None].to(sums.dtype)
        return mean.clamp(min=self.eps).pow(1.0 / self.p)
