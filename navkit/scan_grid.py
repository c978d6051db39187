"""One lidar scan's occupancy grid: a point cloud in the robot frame -> a 2D grid around it, and
planning in it (``ScanGrid``). NavTopo keeps one such grid per location (``navtopo.local_grid``:
cropping, warping, overlap); the start-up's exploring moves (``navkit.explore``) and a path into a
room no map saw into are planned in one.

Grid layout (one convention, used by every function here and by ``scan_matching``):

* A grid is a square ``uint8`` array ``(size, size)``, ``size = 2 * round(radius / resolution)``,
  centred on the observation point (the robot's position when the cloud was taken) and
  axis-aligned with the robot frame at that moment (x forward, y left).
* ``grid[row, col]``: ``col`` grows with +x, ``row`` grows with +y. Cell ``(row, col)`` covers
  ``x in [(col - size/2) * res, (col - size/2 + 1) * res)``, likewise ``y`` with ``row``; the
  observation point ``(0, 0)`` is the corner shared by the four central cells. (Shown as an
  image, +y points down: use ``origin="lower"`` to see the map the usual way up.) Cell <-> metre
  conversions go through ``grid_frame(config)``, the shared ``navkit.raster.GridFrame`` centred on
  the observation point.
* Cells are ``UNKNOWN`` (0), ``FREE`` (1) or ``OCCUPIED`` (2).

Building a grid (``grid_from_points``): points between ``floor_height`` and ``ceiling_height``
(metres above the floor under the robot) are obstacles and their cells ``OCCUPIED``; then a ray is
traced in 2D from the observation point to *every* return, floor hits included (a floor hit at
range r proves the floor free up to r), marking cells ``FREE`` and stopping at the first occupied
cell. Directions with no return (open sky, beyond max range) stay ``UNKNOWN``: unlike the
reference implementation, "no return" never means "free".
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

from navkit import grid_search
from navkit.grid_planning import PlannedPath, Search, plan_path, theta_star_search, within_length
from navkit.raster import FREE, OCCUPIED, GridFrame, inside
from navkit.scan import CEILING_HEIGHT, FLOOR_HEIGHT, MAX_GAP_DEG, obstacle_points, trace_scan

Grid = NDArray[np.uint8]


MAX_GRID_SIZE = 4096  # cells a side of a location grid (300 by default): 16 MB a grid at most


class GridConfig(BaseModel):
    """Geometry of a location grid and the height band that counts as an obstacle.

    Heights are metres above the floor under the robot (``Observation.points`` z). The defaults
    suit the benchmark robot (lidar at 0.6 m, 16 channels over [-15°, 15°], 15 m range):

    * ``floor_height`` 0.15 m: above floor returns (flat floor at z = 0, plus noise and the
      lidar's small tilt errors), below anything the robot cannot drive over, so a 0.3 m box
      is an obstacle. Lower it for robots with very low clearance.
    * ``ceiling_height`` 1.8 m (mount height 0.6 m + 1.2 m): above any robot's body and a
      person's shoulders, below ceilings (2.4 m and up in buildings; 2.6 m in the scenarios),
      so a ceiling is not an obstacle while door frames, shelves and tables are.
    * ``radius`` 15 m covers the sensor's range, so no return is cut off.
    * ``max_gap_deg`` 2.5°: above the lidar's 1° azimuth step, so the fan of rays leaves no
      unknown holes at long range, while a sector without returns stays unknown.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    resolution: float = Field(default=0.1, gt=0.0, description="metres per cell")
    radius: float = Field(default=15.0, gt=0.0, description="half the side of the grid, metres")
    floor_height: float = Field(default=FLOOR_HEIGHT, description="lowest obstacle height above the floor, m")
    ceiling_height: float = Field(default=CEILING_HEIGHT, description="highest obstacle height above the floor, m")
    max_gap_deg: float = Field(
        default=MAX_GAP_DEG,
        ge=0.0,
        description="free space is filled between returns at most this far apart in azimuth; "
        "wider gaps are directions without returns and stay unknown",
    )

    @model_validator(mode="after")
    def _band_not_empty(self) -> GridConfig:
        if self.ceiling_height <= self.floor_height:
            raise ValueError(f"ceiling_height ({self.ceiling_height}) must be above floor_height ({self.floor_height})")
        return self

    @model_validator(mode="after")
    def _size_bounded(self) -> GridConfig:
        # every location keeps a grid: a resolution of a micrometre would pass validation and then
        # fail the mapping stage on an array it cannot allocate
        half = self.radius / self.resolution
        if not (math.isfinite(half) and 2 <= 2 * round(half) <= MAX_GRID_SIZE):
            raise ValueError(
                f"radius {self.radius} m at resolution {self.resolution} m is a grid of {2 * half:.3g} cells a side "
                f"(2 to {MAX_GRID_SIZE} allowed)"
            )
        return self

    @property
    def size(self) -> int:
        """Cells per side: ``2 * round(radius / resolution)`` (300 by default)."""
        return 2 * int(round(self.radius / self.resolution))


def grid_frame(config: GridConfig | None = None) -> GridFrame:
    """The frame of a location grid (the module docstring's layout): cell ``(row, col)`` of a point
    ``(x, y)`` is ``(floor(y / res) + size // 2, floor(x / res) + size // 2)``; ``to_cell`` of points
    (N, 2+) gives integer cells (N, 2) ``[row, col]`` (no bounds check), ``to_world`` the centres."""
    config = config or GridConfig()
    return GridFrame.centred(config.size, config.resolution)


def grid_from_points(points: ArrayLike, config: GridConfig | None = None) -> Grid:
    """A location grid from one lidar cloud.

    points: (N, 3) returns in the robot frame (x forward, y left, z up from the floor), floor
    hits included; non-finite rows are ignored. Returns a ``(size, size)`` uint8 grid centred on
    the robot (see the module docstring for the layout and cell values).
    """
    config = config or GridConfig()
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    size = config.size
    grid = np.zeros((size, size), dtype=np.uint8)
    half = size // 2

    obstacles = obstacle_points(p, config)
    cells = grid_frame(config).to_cell(obstacles)
    seen = inside(cells, grid.shape)
    grid[cells[seen, 0], cells[seen, 1]] = OCCUPIED

    # continuous cell coordinates of every return, as the ray tracer takes them (its cells are
    # floor of these: not grid_frame's floor(x / res) + half, which can differ by one at a cell's
    # edge); returns ending in one cell trace the same cells (up to a sub-cell change of
    # direction), so keep one per end cell
    ends = p[:, :2] / config.resolution + half
    end_cells = np.floor(ends).astype(np.int64)
    _, first = np.unique(end_cells[:, 0] * (1 << 32) + end_cells[:, 1], return_index=True)
    ends = ends[first]
    trace_scan(
        grid,
        ends[:, 0].copy(),
        ends[:, 1].copy(),
        float(half),
        np.radians(config.max_gap_deg),
        0.1,
    )
    return grid


@dataclass(frozen=True)
class ScanGrid:
    """One scan's grid (``local_grid.grid_from_points``, robot frame) and the local planner's levels
    on it: with the margin, then the robot's radius alone (a narrow door); in the scan's free space,
    then between the walls it saw (a door seen at a slant leaves little free space). Each kind of
    space's exact transform is made when a level first needs it (a plan that the scan's free space
    serves never transforms the rest)."""

    grid: NDArray[np.uint8]
    frame: GridFrame
    wide: float  # the first radius of the levels: the robot's with a margin
    tight: float  # the second: the robot's radius and half a cell

    @classmethod
    def of(cls, points: NDArray, grid_config: GridConfig, wide: float, tight: float) -> ScanGrid:
        """The scan's grid and its levels at radii ``wide`` (the robot's with a margin) and ``tight``."""
        grid = grid_from_points(points, grid_config)
        # the scan grid placed by its corner at -radius (floor((x + radius) / res)), as the exploring
        # moves have always been planned: not grid_frame's floor(x / res) + half, which can differ by
        # a cell at a cell's edge
        frame = GridFrame(np.array([-grid_config.radius, -grid_config.radius]), grid_config.resolution)
        return cls(grid, frame, wide, tight)

    @functools.cached_property
    def free_squared(self) -> NDArray[np.int32]:
        """The scan's free space's ``grid_search.clearance_squared``."""
        return grid_search.clearance_squared(self.grid == FREE)

    @functools.cached_property
    def open_squared(self) -> NDArray[np.int32]:
        """``clearance_squared`` of the cells the scan did not see occupied."""
        return grid_search.clearance_squared(self.grid != OCCUPIED)

    def mask(self, index: int) -> NDArray[np.bool_]:
        """Level ``index`` of (wide, tight) x (free, not occupied): the cells the robot's centre may take."""
        radius = self.wide if index < 2 else self.tight
        return grid_search.clear_of(self.open_squared if index % 2 else self.free_squared, radius, self.frame.resolution)

    def plan(self, end: NDArray, snap_cells: int = 5) -> PlannedPath | None:
        """A path from the robot (the origin) to ``end`` (2,, robot frame) on the first level that has one."""
        return plan_path(self.mask, self.frame, np.zeros(2), end, snap_cells=snap_cells, levels=4)

    def plan_seen_first(
        self,
        end: NDArray,
        detour: float,
        medial: float | None = None,
        snap_cells: int = 5,
        search: Search = theta_star_search,
    ) -> PlannedPath | None:
        """As ``plan``, the scan's free space tried first at both radii and, with ``medial``, along
        a passage's middle at that radius, then the same three in the space not seen occupied
        (``LocalPlanner``'s levels: a door the scan shows open before a way round through space it
        did not see; a door the scan shows 0.7 m wide, passed at the middle only, is passed so
        beside unseen space too); a way through unseen space longer than
        ``detour`` times the straight line plus 1 m is passed over for the next level (None: every
        level's was). ``search``: the cell search
        (``plan_path``'s; a local planner passes its own)."""
        longest = detour * float(np.hypot(*end[:2])) + 1.0
        seen = 3 if medial is not None else 2

        def level(index: int) -> NDArray[np.bool_]:
            unseen, index = divmod(index, seen)  # the free space, then the space not seen occupied
            if index < 2:
                passable = self.mask(2 * index + unseen)
            else:
                squared = self.open_squared if unseen else self.free_squared
                passable = grid_search.passable(squared, self.tight, self.frame.resolution, medial)
            if not unseen:
                return passable
            # unseen space, searched only as far as a way that long reaches (the ends may snap)
            bound = within_length(self.frame, self.grid.shape, np.zeros(2), end, longest + 2 * snap_cells * self.frame.resolution)
            return passable & bound

        for index in range(2 * seen):
            found = plan_path([level(index)], self.frame, np.zeros(2), end, snap_cells=snap_cells, search=search)
            if found is None or (index >= seen and found.length > longest):
                # a way far round through unseen space is passed over for the next level, as a local
                # plan's (``LocalPlanner.plan``): a robot before a door 0.8 m wide, its pose 0.16 m
                # off, had the wide level's way round through the room's unseen walls refused and the
                # tight one through the door never tried; the edge went (office02, noisy)
                continue
            return PlannedPath(found.points, index)
        return None
