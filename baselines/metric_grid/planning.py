"""The metric baseline's global planner: A* string-pulled to an any-angle path (or Lazy Theta*,
``PlanningConfig.search``) on the map's free cells (DESIGN.md).

As a Nav2 user's global planner on a static map: the map's known free cells eroded by the robot
radius plus a margin (and half a cell, so the clearance holds to the cell boundary), then by the
radius and half a cell, then a passage narrower than that along the free space's medial axis at the
radius (a door of the robot's width whose jambs the map drew a cell into it: NavTopo's local planner
has the same level); then, if allowed, the same with unknown cells counted as free. The masks are
eroded once, when the map is loaded; a start or goal inside the eroded zone snaps to the nearest
passable cell within ``snap_radius``. Obstacles the map lacks (``obstacles.UnmappedObstacles``) are blocked in
every mask: with any of them remembered the masks are eroded again at each plan, only as far as the
fallbacks need (``navkit.grid_planning.plan_path`` asks for them one by one). The path found is eased
off the mapped walls where the free space allows, up to ``keep_clear`` beyond the first level's
clearance (``navkit.grid_planning.ease_path``; its first ``keep_clear_horizon`` metres: the robot
plans again every ``replan_period``).

Raster convention (``occupancy.GridMap``): ``cells[row, col]``, row ↔ y, col ↔ x; points and paths
are (N, 2) metric in the map frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from navkit import grid_search
from navkit.grid_planning import PlannedPath, plan_path
from navkit.grid_search import Cell, CellPath
from navkit.raster import FREE, OCCUPIED, GridFrame, inside

from .config import PlanningConfig
from .occupancy import GridMap

CLEARANCE_CAP = 255  # squared cells
BLOCKED_TILE = 32  # cells: new obstacles' masks are remade tile by tile
SIGHT_REACH = 16  # cells: with new obstacles, line of sight leaps at most this far from ones remade
SEARCHES = grid_search.SEARCHES  # PlanningConfig.search


class GridPlanner:
    """The search on a loaded map, with the eroded masks of its fallback levels prepared once."""

    def __init__(self, grid_map: GridMap, robot_radius: float, config: PlanningConfig) -> None:
        self.grid_map = grid_map
        self.config = config
        res = grid_map.resolution
        wide = robot_radius + res / 2 + config.inflation_margin
        tight = robot_radius + res / 2
        # (base free mask, radius, medial) in the order they are tried: with the margin, without it,
        # then a passage narrower than that along its middle (``grid_search.passable``: a door of the
        # robot's width whose jambs the map drew a cell into it); eroded masks cached per attempt
        steps: list[tuple[float, float | None]] = [(wide, None), (tight, None)]
        if config.medial_passages:
            steps.append((tight, robot_radius))
        kinds = ("known", "unknown") if config.unknown_fallback else ("known",)
        self.attempts: list[tuple[str, float, float | None]] = [(kind, r, m) for kind in kinds for r, m in steps]
        squared = {kind: grid_search.clearance_squared(self._base(kind)) for kind in kinds}
        # the known free space's clearance, for easing paths: squared cells, capped in 8 bits (1.6 m
        # at 0.1 m cells, more than any easing asks)
        self._clearance = np.minimum(squared["known"], CLEARANCE_CAP).astype(np.uint8)
        self.wide = wide
        self.prefer = wide + config.keep_clear if config.keep_clear > 0 else 0.0  # 0: no easing
        self.hold = tight  # points on a narrow passage's medial line stay there
        # the first level's line-of-sight raster (the Chebyshev clearance line of sight leaps on),
        # whose nonzero cells are its mask: made with the masks, as most plans search that level
        # only; the fallbacks' masks bit-packed (an eighth of a byte a cell), each keeping its
        # line-of-sight raster once searched, until ``forget``
        self._shape = grid_map.cells.shape
        self._packed: dict[tuple[str, float, float | None], NDArray[np.uint8]] = {
            key: np.packbits(grid_search.passable(squared[key[0]], key[1], res, key[2]), axis=None) for key in self.attempts[1:]
        }
        first = self.attempts[0]
        self._sight: dict[tuple[str, float, float | None], NDArray[np.uint8]] = {
            first: grid_search.sight_raster(grid_search.passable(squared[first[0]], first[1], res, first[2]))
        }
        # with ``goal_field``: per level, the goal cell its last search went to, and the field rooted
        # at a goal once a second plan asked for it
        self._asked: dict[int, Cell] = {}  # level -> the goal cell its last search went to
        self._fields: dict[int, tuple[Cell, grid_search.GoalField]] = {}  # level -> (goal cell, field)
        # with new obstacles: (level, tile) -> (the tile window's blocked cells, the mask made there)
        self._tiles: dict[tuple[Any, ...], tuple[bytes, NDArray[np.bool_]]] = {}

    def mask(self, key: tuple[str, float, float | None]) -> NDArray[np.bool_]:
        """The eroded mask (H, W) of level ``key`` (made from what is kept: not stored as such)."""
        if key in self._sight:
            return self._sight[key] > 0
        return np.unpackbits(self._packed[key], count=self._shape[0] * self._shape[1]).reshape(self._shape).view(np.bool_)

    def forget(self) -> None:
        """Drop what plans made (the fallbacks' line-of-sight rasters, goal fields, tiles round new
        obstacles): a trial's first plan makes what it needs, as NavTopo's does (what was made when
        the map was loaded stays: the masks, the first level's line-of-sight raster)."""
        first = self.attempts[0]
        self._sight = {first: self._sight[first]}
        self._asked.clear()
        self._fields.clear()
        self._tiles.clear()

    def roomy_at(self, points: NDArray) -> NDArray[np.bool_]:
        """Points (N, 2, map frame) -> the known free space there leaves the first level's clearance
        and a cell more (True off the map): where a path passes narrower (a door the map draws a
        cell wider than it is still counts), its passage is checked against the scan."""
        cells = self.grid_map.frame.to_cell(np.asarray(points, dtype=np.float64)[:, :2])
        on_map = inside(cells, self._clearance.shape)
        need = (self.wide / self.grid_map.resolution + 1.0) ** 2
        out = np.ones(len(cells), bool)
        out[on_map] = self._clearance[cells[on_map, 0], cells[on_map, 1]] >= need
        return out

    @property
    def nbytes(self) -> int:
        """Bytes of the bit-packed masks, the clearance raster, the line-of-sight rasters of the
        levels searched and the goal's fields if kept (the planner's derived state)."""
        kept: list[NDArray[Any]] = [*self._packed.values(), self._clearance, *self._sight.values()]
        kept += [np.frombuffer(bits, np.uint8) for bits, _ in self._tiles.values()] + [made for _, made in self._tiles.values()]
        return sum(int(array.nbytes) for array in kept) + sum(field.nbytes for _, field in self._fields.values())

    def _base(self, kind: str, window: tuple[slice, slice] = (slice(None), slice(None))) -> NDArray[np.bool_]:
        """The free space a level erodes (known free cells, or all not occupied), in ``window``."""
        cells = self.grid_map.cells[window]
        return cells == FREE if kind == "known" else cells != OCCUPIED

    def plan(self, start_xy: ArrayLike, goal_xy: ArrayLike, obstacles: NDArray) -> PlannedPath | None:
        """The path from start to goal (both (2,), map frame) on the first level that has one, or
        None; ``obstacles`` (N, 2) map-frame points whose cells are blocked in every mask."""
        grid = self.grid_map
        snap = int(np.ceil(self.config.snap_radius / grid.resolution))
        frame = grid.frame
        blocked = self._blocked_cells(frame, obstacles) if len(obstacles) else None
        if blocked is not None and not len(blocked):
            blocked = None  # every point off the map

        def mask(level: int) -> NDArray[np.bool_]:
            key = self.attempts[level]
            return self.mask(key) if blocked is None else self.with_blocked(key, blocked)

        def sight(level: int) -> NDArray[np.uint8] | None:
            # a static mask's line-of-sight raster is kept once made (remade for every search it
            # was most of a plan's search time on a large map); a mask with obstacles is new each
            # time: a search patches the static one round them (``sight_with_blocked``)
            key = self.attempts[level]
            if key not in self._sight:
                self._sight[key] = grid_search.sight_raster(self.mask(key))
            return self._sight[key] if blocked is None else None

        searched = SEARCHES[self.config.search]

        def search(
            level: int, passable: NDArray[np.bool_], start: Cell, goal: Cell, raster: NDArray[np.uint8] | None
        ) -> CellPath | None:
            if self.config.goal_field:
                field = self._goal_field(level, goal)
                if field is not None:  # down the map's field, round new obstacles if any
                    # (pulled cell by cell where they are: cheaper than patching the raster)
                    found = grid_search.field_path(passable, field, start, raster)
                    if found is not None or blocked is None:
                        return found
            if blocked is not None:
                raster = self.sight_with_blocked(self.attempts[level], passable, blocked)
            return searched(passable, start, goal, raster)

        return plan_path(
            mask,
            frame,
            start_xy,
            goal_xy,
            snap,
            levels=len(self.attempts),
            clearance=self._clearance,
            prefer_m=self.prefer,
            hold_m=self.hold,
            horizon_m=self.config.keep_clear_horizon,
            sight=sight,
            search=search,
        )

    def _goal_field(self, level: int, goal: Cell) -> grid_search.GoalField | None:
        """The field rooted at ``goal`` on ``level``'s mask as the map has it (no new obstacles): kept
        from an earlier plan, or made now if the plan before this one asked for the same goal (a
        first plan of a goal searches: most goals are planned to many times, a field costs a
        whole-map Dijkstra); None otherwise."""
        goal = (int(goal[0]), int(goal[1]))
        if level in self._fields and self._fields[level][0] == goal:
            return self._fields[level][1]
        if self._asked.get(level) == goal:
            self._fields[level] = (goal, grid_search.goal_field(self.mask(self.attempts[level]), goal))
            return self._fields[level][1]
        self._fields.pop(level, None)  # another goal: its field goes
        self._asked[level] = goal
        return None

    def with_blocked(self, key: tuple[str, float, float | None], blocked: NDArray[np.int64]) -> NDArray[np.bool_]:
        """The eroded mask of level ``key`` with the ``blocked`` cells ((K, 2) rows and columns on the
        map, ``_blocked_cells``) made walls: the mask
        made again only round them. A blocked cell changes the mask no farther than the level's
        radius and three cells (its clearance, the medial axis's neighbours, the diagonal bridges),
        so round each ``BLOCKED_TILE``-cell tile holding blocked cells the window grown by that much
        is made again, from the base free space of the window grown by as much again (every cell
        pasted has its nearest wall inside, or more room than the radius): the same mask as a
        whole-map transform, at the cost of the tiles' windows. A tile whose window holds the same
        blocked cells as at the last plan is pasted as made then (remembered obstacles grow where
        the robot is; the others stay as they were)."""
        if not len(blocked):
            return self.mask(key)
        kind, radius, medial = key
        height, width = self._shape
        grow = int(np.ceil(radius / self.grid_map.resolution)) + 3
        out = self.mask(key)
        tiles: dict[tuple[Any, ...], tuple[bytes, NDArray[np.bool_]]] = {}
        for r0, c0, paste in self._tile_windows(key, blocked):
            crop = (max(paste[0] - grow, 0), min(paste[1] + grow, height), max(paste[2] - grow, 0), min(paste[3] + grow, width))
            window = (slice(crop[0], crop[1]), slice(crop[2], crop[3]))
            inside_window = (blocked >= (crop[0], crop[2])).all(axis=1) & (blocked < (crop[1], crop[3])).all(axis=1)
            local = np.zeros((crop[1] - crop[0], crop[3] - crop[2]), bool)
            local[blocked[inside_window, 0] - crop[0], blocked[inside_window, 1] - crop[2]] = True
            here = np.packbits(local, axis=None).tobytes()
            made = self._tiles.get((key, r0, c0))
            if made is None or made[0] != here:
                free = self._base(kind, window) & ~local
                remade = grid_search.passable(grid_search.clearance_squared(free), radius, self.grid_map.resolution, medial)
                made = (here, remade[paste[0] - crop[0] : paste[1] - crop[0], paste[2] - crop[2] : paste[3] - crop[2]].copy())
            tiles[(key, r0, c0)] = made
            out[paste[0] : paste[1], paste[2] : paste[3]] = made[1]
        self._tiles = {k: v for k, v in self._tiles.items() if k[0] != key} | tiles  # other levels' stay
        return out

    def _tile_windows(
        self, key: tuple[str, float, float | None], blocked: NDArray[np.int64]
    ) -> list[tuple[int, int, tuple[int, int, int, int]]]:
        """(tile row, tile column, paste window (r0, r1, c0, c1)) of each ``BLOCKED_TILE``-cell tile
        holding ``blocked`` cells: the tile grown by as far as they change level ``key``'s mask."""
        height, width = self._shape
        grow = int(np.ceil(key[1] / self.grid_map.resolution)) + 3
        out = []
        for tile_row, tile_col in np.unique(blocked // BLOCKED_TILE, axis=0):
            r0, c0 = int(tile_row) * BLOCKED_TILE, int(tile_col) * BLOCKED_TILE
            paste = (
                max(r0 - grow, 0),
                min(r0 + BLOCKED_TILE + grow, height),
                max(c0 - grow, 0),
                min(c0 + BLOCKED_TILE + grow, width),
            )
            out.append((r0, c0, paste))
        return out

    def sight_with_blocked(
        self, key: tuple[str, float, float | None], mask: NDArray[np.bool_], blocked: NDArray[np.int64]
    ) -> NDArray[np.uint8]:
        """A line-of-sight raster of ``mask`` (``with_blocked(key, blocked)``) made from the static
        level's (``_sight[key]``) without a pass over the whole map: its nonzero cells are the mask,
        and each cell's value is at most its Chebyshev clearance, all that line of sight's leaps
        need (``grid_search._clear_line_of_sight``). Away from the remade windows the obstacles are
        more than ``SIGHT_REACH`` cells off, so the static value capped at that holds; round each
        window, grown by as much, the clearance of the new mask there (the window's edge counted as
        blocked: lower, never higher)."""
        height, width = self._shape
        out = np.minimum(self._sight[key], SIGHT_REACH)
        made = np.zeros(self._shape, bool)  # cells a window's clearance was written to
        for _, _, paste in self._tile_windows(key, blocked):
            window = (
                slice(max(paste[0] - SIGHT_REACH, 0), min(paste[1] + SIGHT_REACH, height)),
                slice(max(paste[2] - SIGHT_REACH, 0), min(paste[3] + SIGHT_REACH, width)),
            )
            # the new mask's own clearance there (it may have cells the static one lacks: a bridge
            # round a diagonal touch the obstacles made), the least where windows overlap
            here = grid_search.sight_raster(mask[window])
            out[window] = np.where(made[window], np.minimum(out[window], here), here)
            made[window] = True
        return out

    def why_no_path(self, start_xy: ArrayLike, goal_xy: ArrayLike, obstacles: NDArray) -> str:
        """One line on a plan that found nothing: from and to (map frame), the levels tried, and on
        the most lenient whether the start and the goal had a passable cell within the snap radius
        (neither: both in walls or off the map; both: no way joins them, e.g. a sealed room)."""
        grid = self.grid_map
        kind, radius, medial = self.attempts[-1]
        free = self._base(kind)
        if len(obstacles):
            cells = self._blocked_cells(grid.frame, obstacles)
            free = free.copy()
            free[cells[:, 0], cells[:, 1]] = False
        lenient = grid_search.passable(grid_search.clearance_squared(free), radius, grid.resolution, medial)
        snap = int(np.ceil(self.config.snap_radius / grid.resolution))
        start, goal = np.asarray(start_xy, dtype=np.float64)[:2], np.asarray(goal_xy, dtype=np.float64)[:2]
        start_ok = grid_search.nearest_free(lenient, grid.frame.to_cell(start), snap) is not None
        goal_ok = grid_search.nearest_free(lenient, grid.frame.to_cell(goal), snap) is not None
        if start_ok and goal_ok:
            why = "no way joins the start and the goal"
        else:
            ends = " and ".join(name for name, ok in (("the start", start_ok), ("the goal", goal_ok)) if not ok)
            why = f"{ends} had no passable cell within {self.config.snap_radius:g} m"
        levels = ", ".join(
            f"{kind} {radius:.2f} m" + ("" if medial is None else f" or {medial:.2f} m on the medial axis")
            for kind, radius, medial in self.attempts
        )
        blocked = f"; {len(obstacles)} remembered obstacle points blocked" if len(obstacles) else ""
        return (
            f"no path from ({start[0]:.2f}, {start[1]:.2f}) to ({goal[0]:.2f}, {goal[1]:.2f}) in the map frame, "
            f"{len(self.attempts)} levels tried (free space, clearance: {levels}): {why}{blocked}"
        )

    def _blocked_cells(self, frame: GridFrame, obstacles: NDArray) -> NDArray[np.int64]:
        """(K, 2) the map's cells (row, col, each once) that hold one of the points (N, 2); points off
        the map are dropped."""
        cells = frame.to_cell(obstacles)
        return np.unique(cells[inside(cells, self.grid_map.cells.shape)], axis=0)
