"""Rasters: the cell values every grid of the benchmark uses and the one grid frame.

Cell values (``uint8``): ``UNKNOWN`` 0, ``FREE`` 1, ``OCCUPIED`` 2 — NavTopo's location grids, the
metric baseline's global grid and the maps they save and load.

Raster convention: ``cells[row, col]``, row ↔ y, col ↔ x, both growing with the index; the centre
of cell (r, c) lies at ``origin + ((c + 0.5) * resolution, (r + 0.5) * resolution)``, so ``origin``
is the outer (lower-left) corner of cell (0, 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

UNKNOWN = 0
FREE = 1
OCCUPIED = 2


@dataclass(frozen=True)
class GridFrame:
    """Where a raster lies: ``origin`` (2,) the outer corner of cell (0, 0), metres per cell."""

    origin: NDArray[np.float64]
    resolution: float

    def to_cell(self, xy: ArrayLike) -> NDArray[np.int64]:
        """Points (2,) or (N, 2) -> cells [row, col] containing them (no bounds check)."""
        from navkit import grid_search

        return grid_search.world_to_cell(xy, self.origin, self.resolution)

    def to_world(self, cells: ArrayLike) -> NDArray[np.float64]:
        """Cells (2,) or (K, 2) [row, col] -> their centres [x, y]."""
        from navkit import grid_search

        return grid_search.cell_to_world(cells, self.origin, self.resolution)
