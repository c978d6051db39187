"""The global occupancy grid of the metric baseline, and its ROS map_server form.

A log-odds grid (Moravec & Elfes 1985; update and clamping as in OctoMap, Hornung et al. 2013)
at 0.1 m, with bounds that grow as keyframes arrive. Each keyframe is integrated at its
(optimised) pose by the rule NavTopo's location grids use, so the comparison is fair: obstacle
cells from the points in the shared floor/ceiling band, free cells along the rays to every
return, stopped at the first occupied cell, with the same gaps filled between neighbouring
azimuths — the compiled tracer of ``navkit.scan`` does the tracing, in a window of the
global grid around the keyframe. Each cell is updated at most once per keyframe (hit wins over
miss), so a wall seen from 40 keyframes is not erased by the many rays that graze it.

Layout: ``cells[row, col]``, ``col`` grows with +x and ``row`` with +y; ``origin`` is the
world position of the lower-left corner of cell (0, 0) (the ROS map origin). Cell values are
``navkit.raster``'s: ``UNKNOWN`` 0, ``FREE`` 1, ``OCCUPIED`` 2.

Saved as a ROS map_server map (``map.png`` + ``map.yaml``, mode trinary): occupied 0, free 254,
unknown 205, row 0 of the image the largest y, ``negate: 0``, ``occupied_thresh: 0.65``,
``free_thresh: 0.196``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import cast

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from navkit import geometry as se2
from navkit.raster import FREE, OCCUPIED, UNKNOWN, GridFrame, inside, read_map_server, trinary_image, write_map_server
from navkit.scan import MAX_GAP_DEG, trace_scan

from .scan2d import free_endpoints


class OccupancyConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    resolution: float = Field(0.1, ge=0.01, le=10.0, description="metres per cell (a finer grid of a building outgrows memory)")
    max_range: float = Field(15.0, description="m; the lidar's range, sizes the tracing window")
    log_odds_hit: float = Field(0.85, description="p = 0.7 (OctoMap)")
    log_odds_miss: float = Field(-0.4, description="p = 0.4 (OctoMap)")
    log_odds_min: float = Field(-2.0, description="clamp, p = 0.12")
    log_odds_max: float = Field(3.5, description="clamp, p = 0.97")
    occupied_prob: float = Field(0.65, description="above: OCCUPIED (ROS map_saver's 65)")
    free_prob: float = Field(0.25, description="below: FREE (ROS map_saver's 25)")
    growth_step: float = Field(5.0, description="m added at a time when the bounds grow")
    max_gap_deg: float = Field(MAX_GAP_DEG, description="as NavTopo's grids: fill between close azimuths")


def _logit(p: float) -> float:
    return float(np.log(p / (1.0 - p)))


@dataclass
class GridMap:
    """A trinary grid in the map frame: the navigation map as saved and loaded.

    cells: (H, W) uint8, UNKNOWN / FREE / OCCUPIED, ``cells[row, col]`` with row 0 the lowest y.
    origin: (2,) world x, y of the lower-left corner of cell (0, 0). resolution: m per cell.
    """

    cells: NDArray[np.uint8]
    origin: NDArray[np.float64]
    resolution: float

    @property
    def nbytes(self) -> int:
        """Bytes of the cells, the origin and the resolution."""
        return int(self.cells.nbytes + self.origin.nbytes + 8)

    @property
    def frame(self) -> GridFrame:
        """Where the grid lies (``navkit.raster.GridFrame``: the one cell <-> metre conversion)."""
        return GridFrame(self.origin, self.resolution)

    def cell_of(self, xy: ArrayLike) -> NDArray[np.int64]:
        """World points (N, 2) -> cells (N, 2) as ``[row, col]`` (no bounds check)."""
        return self.frame.to_cell(np.asarray(xy, dtype=np.float64).reshape(-1, 2))

    def centres(self, mask: NDArray[np.bool_]) -> NDArray[np.float64]:
        """World centres (N, 2) of the cells where ``mask`` is set."""
        return self.frame.centres(mask)

    def save(self, yaml_path: str | Path, image_format: str = "png") -> Path:
        """Write ``<name>.png`` (or ``.pgm``) and ``<name>.yaml`` (map_server, trinary, through
        ``navkit.raster.write_map_server``); returns the YAML path. PNG by default: map_server reads
        it, and it is the lossless compression NavTopo's location grids are stored with, so both
        systems' maps on disk compare like for like."""
        comment = f"navtopo-bench metric_grid, {self.resolution} m/cell"
        return write_map_server(yaml_path, trinary_image(self.cells), self.frame, image_format=image_format, comment=comment)

    @classmethod
    def load(cls, yaml_path: str | Path) -> GridMap:
        """Read a map_server map (``navkit.raster.read_map_server``: its pixels classified by the
        YAML's thresholds into the three values); ``MapFileError`` names the file, key and reason."""
        read = read_map_server(yaml_path)
        return cls(read.cells, read.frame.origin, read.frame.resolution)


class OccupancyGrid:
    """Log-odds grid with growing bounds. ``logodds[row, col]`` float32, 0 = unknown."""

    def __init__(self, config: OccupancyConfig | None = None):
        self.config = config or OccupancyConfig()
        self.resolution = self.config.resolution
        self.logodds = np.zeros((0, 0), np.float32)
        self.origin: NDArray[np.float64] = np.zeros(2)
        self._cell0 = np.zeros(2, np.int64)  # world cell index of logodds[0, 0]: [row, col]
        self.keyframes = 0

    @classmethod
    def from_keyframes(
        cls,
        poses: ArrayLike,
        scans: list[tuple[NDArray, NDArray]],
        config: OccupancyConfig | None = None,
    ) -> OccupancyGrid:
        """A grid of keyframes (poses (K, 3) in the map frame; scans of (points, free_ranges))."""
        grid = cls(config)
        for pose, (points, ranges) in zip(np.asarray(poses), scans, strict=True):
            grid.integrate(pose, points, ranges)
        return grid

    def _window(self, pose: NDArray) -> tuple[int, int, int]:
        """Top-left global cell (row0, col0) and half side of the tracing window at ``pose``.

        The sensor is snapped to the nearest cell corner (within 0.07 m): the shared tracer
        starts rays at the window's central corner.
        """
        res = self.resolution
        half = int(np.ceil(self.config.max_range / res)) + 2
        corner_col = int(np.round(pose[0] / res))  # global corner index, world frame
        corner_row = int(np.round(pose[1] / res))
        return corner_row - half, corner_col - half, half

    def _corner(self, cell: NDArray[np.int64]) -> NDArray[np.float64]:
        """World x, y (2,) of the lower-left corner of the global cell ``[row, col]``."""
        return cast("NDArray[np.float64]", cell[::-1] * self.resolution)

    def _ensure(self, row0: int, col0: int, rows: int, cols: int) -> None:
        """Grow the grid so that world cells [row0, row0+rows) x [col0, col0+cols) exist.

        World cell (r, c) covers y in [r res, (r+1) res), x likewise: the grid's origin is always
        a whole number of cells, so cells never shift when the bounds grow.
        """
        step = int(np.ceil(self.config.growth_step / self.resolution))
        height, width = self.logodds.shape
        if height == 0:
            top, left = row0 - step, col0 - step
            self.logodds = np.zeros((rows + 2 * step, cols + 2 * step), np.float32)
            self._cell0 = np.array([top, left])
            self.origin = self._corner(self._cell0)
            return
        top, left = int(self._cell0[0]), int(self._cell0[1])
        grow_down = max(0, top - row0)
        grow_left = max(0, left - col0)
        grow_up = max(0, (row0 + rows) - (top + height))
        grow_right = max(0, (col0 + cols) - (left + width))
        if grow_down or grow_left or grow_up or grow_right:
            grow_down += step if grow_down else 0
            grow_left += step if grow_left else 0
            grow_up += step if grow_up else 0
            grow_right += step if grow_right else 0
            self.logodds = np.pad(self.logodds, ((grow_down, grow_up), (grow_left, grow_right)))
            self._cell0 = np.array([top - grow_down, left - grow_left])
            self.origin = self._corner(self._cell0)

    def integrate(self, pose: ArrayLike, points: ArrayLike, ranges: ArrayLike) -> None:
        """Add one keyframe. pose: (3,) map frame; points: (M, 2) obstacle points and ranges:
        (B,) free range per azimuth bin, both in the keyframe frame (see ``scan2d``)."""
        pose = np.asarray(pose, dtype=np.float64)
        res = self.resolution
        row0, col0, half = self._window(pose)
        size = 2 * half
        window = np.zeros((size, size), np.uint8)
        # obstacle cells
        obstacles = se2.transform_points(pose, np.asarray(points, dtype=np.float64).reshape(-1, 2))
        # the window's frame: global cell (row0, col0) is its cell (0, 0); the map frame's origin is
        # the corner of global cell (0, 0)
        cells = GridFrame(np.zeros(2), res).shifted(row0, col0).to_cell(obstacles)
        in_window = inside(cells, window.shape)
        window[cells[in_window, 0], cells[in_window, 1]] = OCCUPIED
        # free rays, in continuous window-cell coordinates
        ends = se2.transform_points(pose, free_endpoints(ranges)) / res - [col0, row0]
        if len(ends):
            trace_scan(
                window,
                np.ascontiguousarray(ends[:, 0]),
                np.ascontiguousarray(ends[:, 1]),
                float(half),
                np.radians(self.config.max_gap_deg),
                0.1,
            )
        self._ensure(row0, col0, size, size)
        r = row0 - self._cell0[0]
        c = col0 - self._cell0[1]
        view = self.logodds[r : r + size, c : c + size]
        update = np.where(
            window == OCCUPIED,
            np.float32(self.config.log_odds_hit),
            np.where(window == FREE, np.float32(self.config.log_odds_miss), np.float32(0.0)),
        )
        view += update
        np.clip(view, self.config.log_odds_min, self.config.log_odds_max, out=view)
        self.keyframes += 1

    def to_trinary(self) -> NDArray[np.uint8]:
        """(H, W) uint8 UNKNOWN / FREE / OCCUPIED over the whole grid."""
        cells = np.full(self.logodds.shape, UNKNOWN, np.uint8)
        cells[self.logodds > _logit(self.config.occupied_prob)] = OCCUPIED
        cells[self.logodds < _logit(self.config.free_prob)] = FREE
        return cells

    def to_map(self, crop: bool = True) -> GridMap:
        """The trinary map, cropped to the bounding box of its known cells (plus one cell)."""
        cells = self.to_trinary()
        origin = self.origin.copy()
        if crop and cells.size:
            known = cells != UNKNOWN
            rows = np.flatnonzero(known.any(axis=1))
            cols = np.flatnonzero(known.any(axis=0))
            if rows.size:
                r0, r1 = max(rows[0] - 1, 0), min(rows[-1] + 2, cells.shape[0])
                c0, c1 = max(cols[0] - 1, 0), min(cols[-1] + 2, cells.shape[1])
                cells = np.ascontiguousarray(cells[r0:r1, c0:c1])
                origin = self._corner(self._cell0 + [r0, c0])
        return GridMap(cells, origin, self.resolution)

    @property
    def nbytes(self) -> int:
        """Bytes of the log-odds array and its origin."""
        return int(self.logodds.nbytes + self.origin.nbytes)


def wall_mask(free_mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The wall cells of a ground-truth raster: cells that are not free but touch free space
    (8-neighbourhood)."""
    free = free_mask.astype(np.uint8)
    touching = cv2.dilate(free, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT) > 0
    return touching & ~free_mask


def map_quality(
    occupied_mask: NDArray[np.bool_],
    origin: ArrayLike,
    res: float,
    gt_wall_mask: NDArray[np.bool_],
    gt_origin: ArrayLike,
    gt_res: float,
    tol: float = 0.2,
) -> tuple[float, float]:
    """(wall_recall, occupied_precision) of a map against ground truth.

    wall_recall: share of GT wall cells with a mapped occupied cell within ``tol`` metres;
    occupied_precision: share of mapped occupied cells within ``tol`` of a GT wall cell.
    Distances are between cell centres; both masks are ``[row, col]`` with row 0 the lowest y.
    A figure with nothing to count is NaN.
    """
    mapped = GridFrame(np.asarray(origin, dtype=np.float64), res).centres(occupied_mask)
    walls = GridFrame(np.asarray(gt_origin, dtype=np.float64), gt_res).centres(gt_wall_mask)
    if len(walls) == 0 or len(mapped) == 0:
        recall = float("nan") if len(walls) == 0 else 0.0
        precision = float("nan") if len(mapped) == 0 else 0.0
        return recall, precision
    to_mapped, _ = cKDTree(mapped).query(walls, distance_upper_bound=tol + 1e-9)
    to_walls, _ = cKDTree(walls).query(mapped, distance_upper_bound=tol + 1e-9)
    return float(np.isfinite(to_mapped).mean()), float(np.isfinite(to_walls).mean())
