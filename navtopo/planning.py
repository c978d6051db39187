"""Two-level path planning of NavTopo (Muravyev & Yakovlev, Sec. "Path Planning").

Global: Dijkstra over the graph of locations, an edge weighted by the length of its relative pose,
from the goal's vertex (so that the way from wherever the robot is follows the predecessors, and a
replan after leaving the path costs nothing); edges found impassable during a trial are left out.

Local: a metric path in the frame of the current location ``v_cur``, on its *union grid*: the
current location's grid and its neighbours' grids, warped into ``v_cur``'s frame by the edges'
relative poses (occupied wins over free, free over unknown), with obstacles the current scan sees
that the map does not explain blocked on top. The path is planned with the shared grid planner
(``navkit.grid_planning.plan_path``: free cells eroded by the robot radius plus a margin, then the
radius alone, then unknown cells counted as free) to a target:

* ``smoothing: none`` (the paper's): the next vertex of the global path, or the goal in ``v_goal``;
* ``smoothing: lookahead`` (beyond the paper): the farthest point along the global path — the
  polyline through the vertices' positions to the goal, all in ``v_cur``'s frame — that still lies
  in the union grid's known free space; Theta*'s any-angle segments shortcut the vertices between.

Union grids are built on demand and kept in a small LRU cache (a location and its neighbours: the
neighbourhood, not the map), so that memory and planning time do not grow with the map.
Frames: a union grid is centred on ``v_cur``'s observation point and axis-aligned with its frame
(``navtopo.local_grid``'s convention: row ↔ y, col ↔ x); every point here is in ``v_cur``'s frame.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from navkit import grid_search
from navkit.geometry import compose, inverse, transform_points
from navkit.grid_planning import PlannedPath, densify, densify_legs, plan_path, within_length
from navkit.passages import segment_distances
from navkit.raster import FREE, OCCUPIED, UNKNOWN, GridFrame, inside
from navkit.scan_grid import GridConfig
from navtopo.graph import TopologicalGraph
from navtopo.local_grid import CroppedGrid, mean_direction, warp_window, warped_bounds


class PlanningConfig(BaseModel):
    """Two-level planning; distances in metres."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    smoothing: Literal["none", "lookahead"] = Field(
        "lookahead",
        description="local target: the next vertex of the global path (none, the paper's) or the farthest "
        "point of the global path in the union grid's known free space (lookahead)",
    )
    inflation_margin: float = Field(0.1, ge=0, description="beyond the robot radius and half a cell; as the baseline's")
    union_radius: float = Field(25.0, gt=0, description="half the side of the union grid's canvas")
    union_cache: int = Field(3, ge=1, description="union grids kept (an LRU cache over the neighbourhood)")
    window_m: float = Field(
        0.0,
        ge=0,
        description="m of the route ahead whose locations join the current location's union grid beside its "
        "neighbours (placed along the route's edges, within union_radius): the lookahead reaches past the "
        "neighbours and a new obstacle ahead is checked against their grids; 0: the neighbours alone (the paper's)",
    )
    search: Literal["astar", "jps", "theta_star"] = Field(
        "jps",
        description="the local search (navkit.grid_search.SEARCHES, the baseline's): jump point search string-pulled "
        "to any angle (jps), the same with A* (astar), or Lazy Theta* (theta_star); paths within 0.1 % of each "
        'other, jps the fastest (BENCHMARKS.md, "Design choices: the search algorithm")',
    )
    target_step: float = Field(0.2, gt=0, description="spacing of the points tried along the global path (lookahead)")
    target_clearance: float = Field(0.05, ge=0, description="a lookahead target keeps this much more than the path's margin")
    target_turn_back: float = Field(
        1.0,
        gt=0,
        description="m: where the global path comes back this much nearer the robot than it has been, the lookahead "
        "stops (a path out to a vertex and back, round a place the graph joins the long way)",
    )
    target_cut: bool = Field(
        True,
        description="lookahead: the route's points are cut to the farthest one the robot has a straight way to "
        "through the known free space (its vertices' positions left behind, as a string pulled tight), so a location "
        "made in a doorway or a room beside the way does not draw the path into it",
    )
    target_cut_reach: float = Field(
        2.0,
        gt=0,
        description="m: a route point is left behind only if the straight way passes this near it (within its "
        "location, whose grid the maintainer moves through; a location the route only reaches round a loop is not)",
    )
    keep_clear: float = Field(
        0.0,
        ge=0,
        description="m beyond the first level's clearance that a local path is eased off the known walls where the "
        "free space allows (navkit.grid_planning.ease_path, as the baseline's paths are; 0, the default: the shortest "
        'path; 0.2 m cost 0.01-0.05 of efficiency on generated door scenes, BENCHMARKS.md, "Design choices: paths '
        'eased off walls")',
    )
    ease_tight: bool = Field(
        True,
        description="a local path found only without the first level's margin (a door narrower than it allows) "
        "is eased up to the first level's clearance where the free space allows, its points less clear than the "
        "robot held (the door): the shortest such path hugged the corridor's wall on its way to the door, its "
        "stretch off the first level's cells longer than a passage the scan check takes, and cut the jamb's "
        "corner at the radius (a held-out mirror building's trial 1, precise: collision). The default since "
        "generated tuning mirror 151's collision went with it (BENCHMARKS.md, 'NavTopo with the corrections' "
        "agreement and eased tight paths as the defaults'); False: the shortest tight path",
    )
    snap_radius: float = Field(1.0, ge=0, description="a start or goal in the inflated zone moves to the nearest free cell")
    align_walls: bool = Field(
        True,
        description="a union grid's axes turned along the walls of its locations (a door across whole rows or "
        "columns of cells, not a staircase of them); False: the location's own axes",
    )
    medial_passages: bool = Field(
        True,
        description="when no path keeps the robot radius plus half a cell from every wall cell, a passage along "
        "its medial axis at the radius plus medial_margin from the wall cells' centres (a door of the robot's width "
        "and a little more whose jambs a scan drew a cell into it)",
    )
    medial_margin: float = Field(0.0, ge=0, description="m beyond the robot radius on a passage's medial axis")
    unknown_detour: float = Field(
        1.5,
        ge=1.0,
        description="a path found only through unknown cells (the last fallbacks) longer than this times the "
        "straight way to its target, plus 1 m, is refused: a way no location saw, far round, is a guess (round a "
        "shut door it led robots to and fro between two locations); the transition fails instead",
    )
    replan_period: float = Field(2.0, gt=0, description="s of simulated time between local replans in one location")
    new_obstacle_distance: float = Field(0.25, gt=0, description="a return this far from every mapped wall is a new obstacle")
    new_obstacle_range: float = Field(
        10.0,
        gt=0,
        description="m; only nearer returns can be new obstacles (a door shut after mapping seen from 10 m, not 6: "
        "docs/DESIGN.md)",
    )


# ---------------------------------------------------------------------------------------------
# global


@dataclass
class GlobalPlanner:
    """Dijkstra from the goal's vertex over the graph minus the removed edges."""

    graph: TopologicalGraph
    removed: set[frozenset[int]] = field(default_factory=set)
    goal: int | None = None
    _distance: NDArray[np.float64] | None = None
    _toward_goal: NDArray[np.int64] | None = None  # next vertex on the way to the goal

    def set_goal(self, vertex: int) -> None:
        self.goal = vertex
        self._search()

    def remove_edge(self, u: int, v: int) -> None:
        """An edge found impassable: left out of every later search (of this trial)."""
        self.removed.add(frozenset((u, v)))
        self._search()

    def reset(self) -> None:
        self.removed.clear()
        self.goal = None
        self._distance = self._toward_goal = None

    def _search(self) -> None:
        assert self.goal is not None
        # from the goal: each vertex's predecessor is its next vertex toward the goal
        self._distance, self._toward_goal = self.graph.dijkstra(self.goal, self.removed)

    def path(self, start: int) -> list[int] | None:
        """Vertices from ``start`` to the goal, or None if the goal cannot be reached."""
        assert self._distance is not None and self._toward_goal is not None and self.goal is not None
        if not np.isfinite(self._distance[start]):
            return None
        path = [start]
        while path[-1] != self.goal:
            path.append(int(self._toward_goal[path[-1]]))
        return path

    def distance(self, start: int) -> float:
        assert self._distance is not None
        return float(self._distance[start])

    def distance_without(self, start: int, u: int, v: int) -> float:
        """The graph distance from ``start`` to the goal were the edge (u, v) removed too (inf: none)."""
        assert self.goal is not None
        return float(self.graph.dijkstra(self.goal, self.removed | {frozenset((u, v))})[0][start])

    @property
    def nbytes(self) -> int:
        arrays = [a for a in (self._distance, self._toward_goal) if a is not None]
        return int(sum(a.nbytes for a in arrays))


def bypasses(
    graph: TopologicalGraph,
    unions: UnionGrids,
    local: LocalPlanner,
    vertex: int,
    blocked_xy: NDArray,
    removed: Collection[frozenset[int]] = (),
) -> list[tuple[int, int, NDArray[np.float64], float]]:
    """Ways round a location whose position new obstacles cover (``blocked_xy``, (N, 2) in
    ``vertex``'s frame): each two of its neighbours, not joined already (nor by an edge ``removed``),
    that the local planner joins through ``vertex``'s union grid round the obstacles, as
    ``(p, q, T_pq, metres of the way)``. A door shut on the spot a location was made at shuts every
    edge into it, though the rooms and corridors round it may still join (a corridor's far part and
    a room whose door lies beyond the shut one)."""
    union = unions.get(vertex)
    neighbours = graph.neighbours(vertex)
    found = []
    for i, (p, pose_p) in enumerate(neighbours):
        for q, pose_q in neighbours[i + 1 :]:
            if graph.has_edge(p, q) or frozenset((p, q)) in removed:
                continue
            planned = local.plan(union, pose_p, pose_q[:2], blocked_xy)
            if planned is not None:
                found.append((p, q, compose(inverse(pose_p), pose_q), planned.length))
    return found


# ---------------------------------------------------------------------------------------------
# the union grid


CLEARANCE_CAP = 255  # squared cells: a union grid's clearance is kept in 8 bits


@dataclass
class UnionGrid:
    """A location's grid united with its neighbours', in the location's frame, cropped to the known
    cells; the clearance of each kind of free space, its passable masks (bit-packed) and their parts
    are made on first use; points are told clear of the walls from the cells round them."""

    vertex: int
    cells: NDArray[np.uint8]  # (H, W) UNKNOWN / FREE / OCCUPIED
    frame: GridFrame  # of the cells in the grid's axes (``yaw``): points go through ``to_cell`` / ``to_point``
    yaw: float = 0.0  # the grid's axes in the location's frame: turned so that the walls run along them
    _clearance: dict[str, NDArray[np.uint8]] = field(default_factory=dict)
    _masks: dict[tuple[str, float, bool], NDArray[np.uint8]] = field(default_factory=dict)  # bit-packed
    _open: dict[tuple[str, float, bool], NDArray[np.bool_]] = field(default_factory=dict)  # unpacked, in use
    _parts: dict[tuple[str, float, bool], NDArray[np.integer]] = field(default_factory=dict)

    def to_cell(self, xy: NDArray) -> NDArray[np.int64]:
        """Points (N, 2+) of the location's frame -> cells (N, 2) [row, col] (no bounds check)."""
        return self.frame.to_cell(_turned(np.asarray(xy, dtype=np.float64)[..., :2], -self.yaw))

    def to_point(self, cells: NDArray) -> NDArray[np.float64]:
        """Cells (N, 2) [row, col] -> their centres (N, 2) in the location's frame."""
        return _turned(self.frame.to_world(cells), self.yaw)

    def to_grid_axes(self, xy: NDArray) -> NDArray[np.float64]:
        """Points (N, 2+) of the location's frame in the grid's axes (``frame``'s metres)."""
        return _turned(np.asarray(xy, dtype=np.float64)[..., :2], -self.yaw)

    def from_grid_axes(self, xy: NDArray) -> NDArray[np.float64]:
        return _turned(np.asarray(xy, dtype=np.float64)[..., :2], self.yaw)

    def _free(self, kind: str, cells: NDArray[np.uint8] | None = None) -> NDArray[np.bool_]:
        cells = self.cells if cells is None else cells
        return cells == FREE if kind == "known" else cells != OCCUPIED

    def mask(self, kind: str, radius: float, medial: float | None = None) -> NDArray[np.bool_]:
        """Cells the robot's centre may take: known free (``known``) or not occupied (``unknown``), eroded
        by ``radius`` (``grid_search.passable``: ``inflate_free``, with cells that touch only diagonally
        joined), kept once made, bit-packed. One distance transform a kind
        serves every radius (a first plan asks for two: each its own transform was most of its time);
        it is kept as squared cells in 8 bits, capped at 255 (1.59 m at 0.1 m cells, beyond any
        planning radius; a larger radius gets a transform of its own). The masks asked for are kept
        unpacked too, read-only, until ``release`` (``LocalPlanner`` releases the grid it planned in
        last when it plans in another): a replan asks for the same two or three, and unpacking each
        was a tenth of a millisecond.

        ``medial``: also the cells of the free space's medial axis (``medial_axis``) at least this far
        from every non-free cell's centre: a passage too narrow for ``radius`` (a door of the robot's
        width and a little more, its jambs a cell into it) passed along its middle."""
        key = (kind, radius, medial is not None)
        if key not in self._masks:
            radius_cells = radius / self.frame.resolution
            if medial is None and radius_cells * radius_cells > CLEARANCE_CAP - 1:
                # beyond the 8-bit cap: a transform of its own
                made = grid_search.passable(grid_search.clearance_squared(self._free(kind)), radius, self.frame.resolution)
            else:
                made = grid_search.passable(self._squared(kind), radius, self.frame.resolution, medial)
            self._masks[key] = np.packbits(made, axis=None)
        if key not in self._open:
            cells = np.unpackbits(self._masks[key], count=self.cells.size).view(np.bool_).reshape(self.cells.shape)
            cells.flags.writeable = False
            self._open[key] = cells
        return self._open[key]

    def release(self) -> None:
        """Drop the unpacked masks (``mask``): the grid is no longer the one planned in."""
        self._open.clear()

    def parts(self, kind: str, radius: float, medial: float | None = None) -> NDArray[np.integer]:
        """(H, W) labels of the connected parts of ``mask(kind, radius, medial)`` (0: not passable),
        kept once made."""
        key = (kind, radius, medial is not None)
        if key not in self._parts:
            self._parts[key] = _parts(self.mask(kind, radius, medial))
        return self._parts[key]

    def _squared(self, kind: str) -> NDArray[np.uint8]:
        if kind not in self._clearance:
            squared = grid_search.clearance_squared(self._free(kind))
            self._clearance[kind] = np.minimum(squared, CLEARANCE_CAP).astype(np.uint8)
        return self._clearance[kind]

    def clearance(self, kind: str) -> NDArray[np.uint8]:
        """(H, W) squared distance in cells from each cell's centre to the nearest non-free cell of
        ``kind``'s (``grid_search.clearance_squared``, capped at ``CLEARANCE_CAP``)."""
        return self._squared(kind)

    def fits(self, xy: NDArray, kind: str, radius: float) -> bool:
        """Whether the point (2,) is ``radius`` clear of the non-free cells of ``kind`` (True off the
        grid), from the cells round it alone: no transform of the whole grid for one cell. That is
        ``mask(kind, radius)`` there but for the cells the mask adds where two of its cells touch only
        diagonally (``grid_search.four_connected``), a little less clear."""
        cell = self.to_cell(np.asarray(xy, dtype=np.float64)[None, :2])[0]
        height, width = self.cells.shape
        if not (0 <= cell[0] < height and 0 <= cell[1] < width):
            return True
        reach = int(np.ceil(radius / self.frame.resolution))
        free = np.zeros((2 * reach + 1, 2 * reach + 1), bool)  # outside the grid counts as not free
        r0, c0 = cell[0] - reach, cell[1] - reach
        rows = slice(max(r0, 0), min(cell[0] + reach + 1, height))
        cols = slice(max(c0, 0), min(cell[1] + reach + 1, width))
        free[rows.start - r0 : rows.stop - r0, cols.start - c0 : cols.stop - c0] = self._free(kind, self.cells[rows, cols])
        if not free[reach, reach]:
            return False
        squared = np.square(np.argwhere(~free) - reach).sum(axis=1)  # to each non-free cell round it
        return bool(grid_search.clear_of(squared, radius, self.frame.resolution).all())

    def clear_of_walls(self, xy: NDArray, metres: float, outside: bool) -> NDArray[np.bool_]:
        """Points (N, 2) of the location's frame at least ``metres`` from every occupied cell's
        centre (``outside``: the answer off the grid), from the cells round each point alone
        (``grid_search.far_from``)."""
        return grid_search.far_from(self.cells == OCCUPIED, self.to_cell(xy), metres, self.frame.resolution, outside)

    def values_at(self, xy: NDArray, array: NDArray, outside: float | np.floating) -> NDArray:
        """``array`` (H, W) sampled at points (N, 2) of the location's frame; ``outside`` off the grid."""
        cells = self.to_cell(xy)
        on_grid = inside(cells, array.shape)
        out = np.full(len(cells), outside, dtype=array.dtype)
        out[on_grid] = array[cells[on_grid, 0], cells[on_grid, 1]]
        return out

    def passable_at(self, kind: str, radius: float) -> Callable[[NDArray], NDArray[np.bool_]]:
        """Points (N, 2) of the location's frame -> on ``mask(kind, radius)`` (True off the grid)."""
        mask = self.mask(kind, radius)
        return lambda xy: self.values_at(xy, mask, True)

    @property
    def nbytes(self) -> int:
        parts = [*self._clearance.values(), *self._masks.values(), *self._open.values(), *self._parts.values()]
        total = self.cells.nbytes + sum(part.nbytes for part in parts)
        return int(total)


def build_union_grid(
    graph: TopologicalGraph,
    vertex: int,
    grid_config: GridConfig,
    radius: float,
    align: bool = True,
    members: list[tuple[int, NDArray[np.float64]]] | None = None,
) -> UnionGrid:
    """``vertex``'s grid and its neighbours', warped into its frame by the edges (see the module
    docstring); with ``align``, into its frame turned so that the walls run along the grid's axes.
    ``members``: other locations instead of the neighbours, each with its pose in ``vertex``'s frame
    (two locations a shortcut would join)."""
    size = 2 * int(round(radius / grid_config.resolution))
    res = grid_config.resolution
    others = graph.neighbours(vertex) if members is None else members
    placed = [(graph.vertices[m].grid, pose) for m, pose in [(vertex, np.zeros(3)), *others]]
    yaw = union_yaw(placed) if align else 0.0
    # warp(grid, T) is the grid seen from frame T given in the grid's own frame: the union's axes
    # (``vertex``'s origin, turned by ``yaw``) lie at inverse(T_vertex_member) (0, 0, yaw) in ``member``'s frame
    axes = np.array([0.0, 0.0, yaw])
    warped = [(grid, compose(inverse(pose), axes)) for grid, pose in placed]
    boxes = np.array([warped_bounds(grid, pose, res, size, margin=3) for grid, pose in warped]).reshape(-1, 4)
    boxes = boxes[(boxes[:, 1] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 2])]
    if not len(boxes):
        return UnionGrid(vertex, np.zeros((1, 1), np.uint8), GridFrame(np.zeros(2), res), yaw)
    # only the window that the members can reach is warped (a few hundred cells a side of the
    # canvas's 2 * radius / resolution): a location's union grid cost ~1.2 ms, now a few tenths
    window = (int(boxes[:, 0].min()), int(boxes[:, 1].max()), int(boxes[:, 2].min()), int(boxes[:, 3].max()))
    cells = np.full((window[1] - window[0], window[3] - window[2]), UNKNOWN, np.uint8)
    for grid, pose in warped:
        # UNKNOWN < FREE < OCCUPIED: the largest value is the union (a wall seen from any location stands)
        np.maximum(cells, warp_window(grid, pose, res, size, window), out=cells)
    known_rows = np.flatnonzero((cells != UNKNOWN).any(axis=1))
    known_cols = np.flatnonzero((cells != UNKNOWN).any(axis=0))
    if known_rows.size == 0:
        return UnionGrid(vertex, np.zeros((1, 1), np.uint8), GridFrame(np.zeros(2), res), yaw)
    r0 = max(window[0] + known_rows[0] - 2, 0) - window[0]
    r1 = min(window[0] + known_rows[-1] + 3, size) - window[0]
    c0 = max(window[2] + known_cols[0] - 2, 0) - window[2]
    c1 = min(window[2] + known_cols[-1] + 3, size) - window[2]
    # the corner of the kept part's first cell on the canvas centred on the vertex's observation point;
    # a map-style frame from there (floor((x - origin) / res)), as the union grids have always been read
    origin = np.array([(window[2] + c0 - size // 2) * res, (window[0] + r0 - size // 2) * res])
    return UnionGrid(vertex, np.ascontiguousarray(cells[r0:r1, c0:c1]), GridFrame(origin, res), yaw)


def union_yaw(placed: list[tuple[CroppedGrid, NDArray[np.float64]]]) -> float:
    """The yaw (radians, in [-45°, 45°)) that turns a location's frame so that the walls of the
    grids ``placed`` (each with its pose in that frame) run along its axes
    (``local_grid.wall_direction``): a door or a corridor then crosses whole rows or columns of
    cells, where at a slant its jambs' cells stand in a staircase and the planner, which moves from
    cell to cell without cutting corners, finds it a cell or so narrower."""
    directions = [grid.wall_axis for grid, _ in placed]
    angles = [angle + float(pose[2]) for (angle, _), (_, pose) in zip(directions, placed, strict=True)]
    return mean_direction(angles, [weight for _, weight in directions])


# locations of the route ahead joined to a union grid: (vertex, its pose in the current location's frame)
Window = tuple[tuple[int, tuple[float, float, float]], ...]


class UnionGrids:
    """Union grids of the locations visited lately (an LRU cache).

    The milliseconds spent building them are kept until ``take_build_ms``: a grid is built for
    planning even when the new-obstacle check asks for it first (in the same tick, before the plan's
    clock starts), so the navigator adds them to the next plan's time."""

    def __init__(self, graph: TopologicalGraph, grid_config: GridConfig, config: PlanningConfig) -> None:
        self.graph = graph
        self.grid_config = grid_config
        self.config = config
        self._cache: OrderedDict[tuple[int, tuple[int, ...]], UnionGrid] = OrderedDict()
        self._build_ms = 0.0

    def get(self, vertex: int, ahead: Window = ()) -> UnionGrid:
        """``vertex``'s union grid: its neighbours' grids, and those of ``ahead`` (locations of the
        route ahead with their poses in ``vertex``'s frame, ``window``)."""
        key = (vertex, tuple(member for member, _ in ahead))
        union = self._cache.get(key)
        if union is None:
            started = time.perf_counter()
            members = None
            if ahead:
                neighbours = self.graph.neighbours(vertex)
                near = {vertex, *(member for member, _ in neighbours)}
                extra = [(member, np.asarray(pose, dtype=np.float64)) for member, pose in ahead if member not in near]
                members = [*neighbours, *extra]
            union = build_union_grid(
                self.graph, vertex, self.grid_config, self.config.union_radius, self.config.align_walls, members
            )
            self._build_ms += (time.perf_counter() - started) * 1e3
            self._cache[key] = union
            if len(self._cache) > self.config.union_cache:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(key)
        return union

    def window(self, route: list[int], positions: NDArray[np.float64]) -> Window:
        """The locations of ``route`` (from the current one) within ``window_m`` along it and
        ``union_radius`` of the current one, each with its position (``TopologicalGraph.path_poses``), for ``get``."""
        reach = self.config.window_m
        if reach <= 0 or len(route) < 3:
            return ()
        along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(positions[:, :2], axis=0).T))])
        keep = (along <= reach) & (np.hypot(positions[:, 0], positions[:, 1]) <= self.config.union_radius)
        keep[0] = False
        return tuple((int(route[i]), (float(p[0]), float(p[1]), float(p[2]))) for i, p in enumerate(positions) if keep[i])

    def forget(self, vertices: set[int]) -> None:
        """Drop the union grids of ``vertices`` (their neighbours changed)."""
        for key in [key for key in self._cache if key[0] in vertices]:
            del self._cache[key]

    def take_build_ms(self) -> float:
        """Milliseconds spent building union grids since the last call."""
        spent, self._build_ms = self._build_ms, 0.0
        return spent

    def clear(self) -> None:
        self._cache.clear()

    @property
    def nbytes(self) -> int:
        return sum(union.nbytes for union in self._cache.values())


# ---------------------------------------------------------------------------------------------
# the local planner


def _short_by(planned: PlannedPath, target: NDArray) -> float:
    """How far (m, grid axes) the path ends from ``target``."""
    return float(np.hypot(*(planned.points[-1] - target)))


class LocalPlanner:
    """Plans in the current location's union grid, to the target the smoothing mode picks."""

    def __init__(self, grids: UnionGrids, robot_radius: float, config: PlanningConfig) -> None:
        self.grids = grids
        self.config = config
        resolution = grids.grid_config.resolution
        self.wide = robot_radius + resolution / 2 + config.inflation_margin
        self.tight = robot_radius + resolution / 2
        # the fallbacks in order: known free space with the margin, without; then a narrow passage
        # along its middle (``UnionGrid.mask``'s medial); then the same with unknown cells as free
        self.medial = robot_radius + config.medial_margin if config.medial_passages else None
        steps: list[tuple[float, float | None]] = [(self.wide, None), (self.tight, None)]
        if self.medial is not None:
            steps.append((self.tight, self.medial))
        self.levels: list[tuple[str, float, float | None]] = [(kind, r, m) for kind in ("known", "unknown") for r, m in steps]
        # the last new obstacles asked for, with their union grid and their cells on it (``_passable``)
        self._blocked: tuple[UnionGrid, bytes, NDArray[np.int64]] | None = None
        self._planned_in: UnionGrid | None = None  # the grid whose unpacked masks are kept (``_passable``)

    def target(
        self, union: UnionGrid, start: NDArray, route: NDArray[np.float64], blocked_xy: NDArray | None = None
    ) -> NDArray[np.float64]:
        """Where the local path goes (v_cur's frame). ``route`` (K, 2): the global path's points
        after the robot: the next vertices' positions and, last, the goal. ``blocked_xy``: new
        obstacles (a shut door the grids show open), where the route leaves the free space too."""
        return self.aim(union, start, route, blocked_xy)[0]

    def aim(
        self,
        union: UnionGrid,
        start: NDArray,
        route: NDArray[np.float64],
        blocked_xy: NDArray | None = None,
        skip: int = 0,
        resume: NDArray | None = None,
    ) -> tuple[NDArray[np.float64], int]:
        """``target``, looking from the route's point ``skip`` on, and the index of the first route
        point not yet passed: the points before the target (cut, ``target_cut``, or on the way to
        it) stay passed for the next plans along the same route (``skip``). Without that a target
        far along the route, planned to by another corridor, was followed by one at a passed route
        point behind the robot (the straight way back to it crossed a wall from the new spot), and
        the robot went to and fro between the two until the time ran out (a shopping mall, noisy).

        ``resume`` (2,): the last target along this route, where the route is taken up instead
        (``Navigator._local_path`` asks for it where the route point ``skip`` is reached only through
        unknown cells). A robot within a metre of it has reached it: ``resume`` is passed over, as a
        path to it again would stop the robot where it stands."""
        skip = min(max(skip, 0), len(route) - 1)
        route = route[skip:]
        if resume is None or skip == 0 or float(np.hypot(*(np.asarray(resume)[:2] - start[:2]))) <= 1.0:
            target, passed = self._aim(union, start, route, blocked_xy)
            return target, skip + passed
        target, passed = self._aim(union, start, np.vstack([np.asarray(resume, np.float64)[None, :2], route]), blocked_xy)
        return target, skip + max(passed - 1, 0)  # the resume point is no route point

    def _aim(
        self, union: UnionGrid, start: NDArray, route: NDArray[np.float64], blocked_xy: NDArray | None
    ) -> tuple[NDArray[np.float64], int]:
        """``aim`` along ``route`` from its first point: the target and the route points it passed."""
        if self.config.smoothing == "none" or len(route) == 1:
            return route[0], 0
        cut = 0
        # lookahead: the farthest point of the polyline robot -> route in the union grid's known free
        # space (eroded as the paths are, plus a little), and no nearer than the next vertex (or 1 m),
        # before the polyline first leaves that space beyond there: a route that comes back near
        # the robot (round a loop) must not pull the target to its far end across a wall or a shut door
        reach = self.wide + self.config.target_clearance
        passable = self._passable(union, "known", reach, blocked_xy=blocked_xy)
        if self.config.target_cut:
            cut = self._farthest_in_sight(union, passable, start, route)
            route = route[cut:]
        samples, legs = densify_legs(np.vstack([start[None, :2], route]), self.config.target_step)
        free = union.values_at(samples, passable, False)
        beyond_next = np.hypot(*(samples - start[:2]).T) >= min(float(np.hypot(*(route[0] - start[:2]))), 1.0)
        first = int(np.argmax(beyond_next)) if beyond_next.any() else len(samples)
        leaves = np.flatnonzero(~free[first:])
        end = first + (int(leaves[0]) if len(leaves) else len(samples) - first)
        # a path that goes out to a vertex and comes back past the robot (two locations at one place
        # joined only through a third) ends there too: a target on its way back, beside the robot,
        # takes the robot toward the far vertex's neighbour without reaching the vertex that lets
        # it change location, and the next plan turns it round again (loop_office, precise)
        distance = np.hypot(*(samples - start[:2]).T)
        back = np.flatnonzero(distance < np.maximum.accumulate(distance) - self.config.target_turn_back)
        if len(back):
            end = min(end, int(back[0]))
        if end <= np.count_nonzero(legs == 0) - 1 and self._wall_between(union, start[:2], route[0]):
            # a wall stands between the robot and the next route point (the robot beside a wall
            # whose end the way goes round): a point on the straight way short of the wall is a
            # dead end, and from there the next plan goes round again, and so to and fro (a
            # shopping mall's aisle, noisy: 80 s between two such targets until the time ran out)
            return route[0], cut
        candidates = np.flatnonzero(free[:end] & beyond_next[:end])
        if not len(candidates):
            return route[0], cut
        # a target on leg k (from route point k - 1 to k) has passed the route points before it
        return samples[candidates[-1]], cut + int(legs[candidates[-1]])

    @staticmethod
    def _wall_between(union: UnionGrid, a: NDArray, b: NDArray) -> bool:
        """Does the straight way from ``a`` to ``b`` (2,) cross a mapped wall cell of the union grid?"""
        way = densify(np.vstack([a[None], b[None]]), union.frame.resolution / 2)
        return bool((union.values_at(way, union.cells, UNKNOWN) == OCCUPIED).any())

    def _farthest_in_sight(self, union: UnionGrid, passable: NDArray[np.bool_], start: NDArray, route: NDArray) -> int:
        """The index of the last route point (K, 2) the straight way from ``start`` reaches through
        ``passable`` cells, passing every point before it within ``target_cut_reach`` and ahead of the
        robot (0 when none but the first does: the route is followed from there)."""
        open_points = union.values_at(route, passable, False)
        for k in np.flatnonzero(open_points[1:])[::-1] + 1:
            way = route[k] - start[:2]
            along = (route[:k] - start[:2]) @ way / max(float(way @ way), 1e-12)
            skipped = segment_distances(start[None, :2], route[k][None], route[:k])[0]
            if skipped.max() > self.config.target_cut_reach or along.min() <= 0.0:
                # a location off the way, or behind the robot (a route out to a neighbour and back:
                # the maintainer moves through each location in turn, the way must pass them)
                continue
            way = densify(np.vstack([start[None, :2], route[k][None]]), self.config.target_step)
            if union.values_at(way, passable, False)[1:].all():
                return int(k)
        return 0

    def _passable(
        self, union: UnionGrid, kind: str, radius: float, medial: float | None = None, blocked_xy: NDArray | None = None
    ) -> NDArray[np.bool_]:
        """The union grid's cached ``mask(kind, radius, medial)``, with new obstacles (N, 2+) blocked as
        far as ``radius`` (``grid_search.without_disks``: each obstacle on the grid blocks the cells
        within ``radius`` of its cell's centre). The obstacles' cells are kept for the last union
        grid and obstacles asked for: a replan asks for the same ones at several radii and levels."""
        if self._planned_in is not union:
            if self._planned_in is not None:
                self._planned_in.release()
            self._planned_in = union
        if blocked_xy is None or not len(blocked_xy):
            return union.mask(kind, radius, medial)
        key = np.ascontiguousarray(np.asarray(blocked_xy, dtype=np.float64)[:, :2]).tobytes()
        if self._blocked is None or self._blocked[0] is not union or self._blocked[1] != key:
            cells = union.to_cell(np.asarray(blocked_xy)[:, :2])
            self._blocked = (union, key, cells[inside(cells, union.cells.shape)])
        return grid_search.without_disks(union.mask(kind, radius, medial), self._blocked[2], radius, union.frame.resolution)

    def search(
        self,
        level: int,
        passable: NDArray[np.bool_],
        start: tuple[int, int],
        goal: tuple[int, int],
        sight: NDArray[np.uint8] | None,
    ) -> NDArray[np.int64] | None:  # plan_path's ``Search``: the configured one on every level
        return grid_search.SEARCHES[self.config.search](passable, start, goal, sight)

    def way_between(self, graph: TopologicalGraph, u: int, v: int, pose_uv: NDArray[np.float64]) -> float | None:
        """The length (m) of the way this planner drives from u's observation point to v's (at
        ``pose_uv`` in u's frame) through the known free space of the two locations' grids united,
        or None if there is none: an edge's length as Dijkstra weighs it, and whether a shortcut
        between two locations can be driven (``mapping.GraphMaintainer``). The same levels and end
        snapping as a local plan: a location made in a doorway, its observation point nearer a jamb
        than the clearance, has its way (a way searched from that cell alone had none for a third of
        office02's edges)."""
        union = build_union_grid(
            graph, u, self.grids.grid_config, self.config.union_radius, self.config.align_walls, members=[(v, pose_uv)]
        )
        planned = self.plan(union, np.zeros(3), np.asarray(pose_uv, dtype=np.float64)[:2], known_only=True)
        return None if planned is None else planned.length

    def _prefer(self, radius: float, medial: float | None) -> float:
        """The clearance a level's path is eased toward (``ease_path``'s ``prefer_m``; 0: as found):
        ``keep_clear`` beyond the first level's; with ``ease_tight``, a tight level's up to the first
        level's; never a medial path (fitted to the scan as found, ``narrow_part``)."""
        if medial is not None:
            return 0.0
        if self.config.keep_clear:
            return self.wide + self.config.keep_clear
        return self.wide if self.config.ease_tight and radius < self.wide else 0.0

    def detour(self, start: NDArray, target: NDArray) -> float:
        """The longest way through unknown cells a plan from ``start`` to ``target`` takes (m):
        ``unknown_detour`` times the straight way, plus 1 m."""
        return self.config.unknown_detour * float(np.hypot(*(np.asarray(target)[:2] - np.asarray(start)[:2]))) + 1.0

    def plan(
        self,
        union: UnionGrid,
        start: NDArray,
        target: NDArray,
        blocked_xy: NDArray | None = None,
        known_only: bool = False,
        probe: bool = False,
        detour_m: float | None = None,
    ) -> PlannedPath | None:
        """A path from ``start`` (3,) to ``target`` (2,) in the union grid, new obstacles blocked; None
        if there is none, or only ones through unknown cells far round (``unknown_detour``: such a way
        found on one level is passed over for the next; ``detour_m``: the longest such way, in metres,
        instead). ``known_only``: no level through unknown cells.
        ``probe``: asked whether the new obstacles shut the way (``blocked_leg``), which they often do.

        The levels are tried in order (``navkit.grid_planning.plan_path`` on each): a level whose
        snapped start and goal lie in different parts of its passable cells (4-connected, as the
        search moves: no corner cut) is passed over without a search, which would visit every cell
        it can reach before it gave up (tens of milliseconds on a union grid's unknown levels). On
        the known levels the parts are the union's own, kept once made, the new obstacles left out
        (ends they part are parted by these too), but for a ``probe``: ends that the obstacles
        alone part are rare in a plan, and left to its search over the known free space, where
        labelling the parts afresh at every plan cost more (0.15 ms a plan on a 1.2 km lattice); in
        a probe, where a door seen shut parts them, failed searches took loop_office_door's p95
        from about 5.5 to 8.5 ms."""
        snap = int(np.ceil(self.config.snap_radius / union.frame.resolution))
        # a target the robot does not fit at even next to unknown space (a goal estimated into a
        # wall) is approached as near as the free space allows, never driven into
        target = np.asarray(target, dtype=np.float64)[:2]
        fits = union.fits(target, "unknown", self.tight) or (
            self.medial is not None and union.fits(target, "unknown", self.medial)
        )
        if fits and blocked_xy is not None and len(blocked_xy):
            # nor next to returns the map lacks, which block the cells round them as far: a goal
            # converted 0.24 m off toward a wall the location saw only from afar (unknown cells, its
            # wall cells 0.3 m beyond the scan's) was planned to exactly, the path blocked at every
            # tick and planned again, and the robot turned on the spot 0.5 m from the goal until it
            # was stuck (a held-out mirror building, noisy)
            nearest = np.hypot(*(np.asarray(blocked_xy, dtype=np.float64)[:, :2] - target).T).min()
            fits = bool(nearest >= self.tight)
        ends = union.to_grid_axes(np.vstack([start[None, :2], target[None]]))
        end_cells = union.frame.to_cell(ends)
        # an end snaps to a level's cells only over no wall: the way to them is driven straight (a
        # robot in a room no location saw, the pose 0.2 m off, snapped to a corridor a metre away
        # through the wall and drove into it; office02, noisy)
        no_wall = union.cells != OCCUPIED
        detour = self.detour(start, target) if detour_m is None else detour_m
        reach: NDArray[np.bool_] | None = None
        planned = short = None  # short: the way ending nearest a target the robot does not fit at, so far
        for level, (kind, radius, medial) in enumerate(self.levels):
            if known_only and kind != "known":
                break
            passable = self._passable(union, kind, radius, medial, blocked_xy)
            own_parts = kind == "known" and not (probe and blocked_xy is not None and len(blocked_xy))
            parts = union.parts(kind, radius, medial) if own_parts else None
            if kind == "unknown":
                # only a way no longer than the detour is taken: the search bounded there (a shut door
                # seen ahead had the ways round through unknown space searched to the grid's edge,
                # 10-35 ms, then refused); the ends may snap by ``snap`` cells
                if reach is None:
                    reach = within_length(
                        union.frame, passable.shape, ends[0], ends[1], detour + 2 * snap * union.frame.resolution
                    )
                passable = passable & reach
            start_cell = grid_search.nearest_free(passable, end_cells[0], snap, no_wall)
            goal_cell = grid_search.nearest_free(passable, end_cells[1], snap, no_wall)
            if start_cell is None or goal_cell is None:
                continue
            parts = _parts(passable) if parts is None else parts
            if parts[start_cell] != parts[goal_cell]:
                continue
            found = plan_path(
                [passable],
                union.frame,
                ends[0],
                ends[1],
                snap,
                exact_goal=fits,
                clearance=union.clearance("known"),
                # a narrow passage's path is fitted to the scan as found (``narrow_part``)
                prefer_m=self._prefer(radius, medial),
                hold_m=self.tight,
                search=self.search,
                snap_through=no_wall,
            )
            if found is None:
                continue
            planned = PlannedPath(found.points, level)
            if kind == "unknown" and planned.length > detour:
                # far round through cells no location saw: a guess; a tighter level may pass the
                # door beside the robot (a wide level went round through the walls between rooms,
                # drawn unknown, and the goal beyond a door 1.9 m away was given up)
                planned = None
                continue
            gap = 0.0 if fits else _short_by(planned, ends[1])
            if gap > self.wide + union.frame.resolution:
                # ending far short of a target the robot does not fit at: a level through unknown
                # cells may come nearer (the known free space ended 0.9 m before a goal beside a
                # wall the location saw only from afar, the unknown cells up to the wall free)
                if short is None or gap < _short_by(short, ends[1]) - union.frame.resolution:
                    short = planned
                planned = None
                continue
            break
        planned = short if planned is None else planned
        if planned is None:
            return None
        points = union.from_grid_axes(planned.points)
        points[0] = start[:2]  # exact, not turned there and back
        if fits:
            points[-1] = target
        return PlannedPath(self._straight_from_start(union, points, blocked_xy), planned.level)

    def _straight_from_start(
        self, union: UnionGrid, points: NDArray[np.float64], blocked_xy: NDArray | None
    ) -> NDArray[np.float64]:
        """The path without the cell its start snapped to, where that cell lies behind the robot
        (away from the point after it), the robot stands in cells no location saw and the straight
        way from it to the point after keeps the tight clearance from every mapped wall and new
        obstacle. A robot in a room no location saw into, entered for a goal in it, had its start
        snapped back to the known free space behind it at every plan: it turned round, drove back,
        turned again, and ran out of time 0.8 m from the goal (an aliased wing, held out)."""
        resolution = union.frame.resolution
        if len(points) < 3 or float(np.hypot(*(points[1] - points[0]))) <= 1.5 * resolution:
            return points  # not snapped: the first cell is the robot's own
        if float(np.dot(points[1] - points[0], points[2] - points[0])) >= 0.0:
            return points  # the snapped cell lies on the way on: through it (a door met square)
        if union.values_at(points[:1], union.cells, UNKNOWN)[0] != UNKNOWN:
            # snapped in the known space (off a wall, out of a new obstacle's margin): the way out
            # stays (dropped, robots before a shut door drove on into it and turned back later)
            return points
        steps = max(int(np.ceil(float(np.hypot(*(points[2] - points[0]))) / (resolution / 2))), 1)
        line = points[0] + np.linspace(0.0, 1.0, steps + 1)[:, None] * (points[2] - points[0])
        if not union.clear_of_walls(line, self.tight, True).all():
            return points
        if blocked_xy is not None and len(blocked_xy) and float(cKDTree(blocked_xy[:, :2]).query(line)[0].min()) < self.tight:
            return points
        return np.vstack([points[:1], points[2:]])

    def blocked_leg(self, union: UnionGrid, start: NDArray, route: NDArray[np.float64], blocked_xy: NDArray) -> int | None:
        """The leg of the polyline robot -> ``route`` (K, 2, as ``target``'s) that new obstacles
        (``blocked_xy``) shut, seen before the robot gets there: None, or k (the leg from route point
        k - 1, the robot for k = 0, to route point k).

        Where the polyline first crosses cells the map leaves free for the robot and the obstacles
        do not, the union grid is asked for a way from the robot to the polyline's first free point
        past them: the leg is shut when there is one on the map and none with the obstacles (a door
        shut across a corridor; an obstacle the robot can pass round leaves a way, and one on the
        far side of the grid's known space, none on the map either: neither is a verdict)."""
        if not len(blocked_xy) or not len(route):
            return None
        samples, legs = densify_legs(np.vstack([start[None, :2], route]), self.config.target_step)
        # only obstacles within the robot's reach of the samples' box can be near one (most of a
        # scan's new obstacles lie off the route: the tree is built on the rest, or on none)
        blocked = np.asarray(blocked_xy, dtype=np.float64)[:, :2]
        box = (blocked >= samples.min(axis=0) - self.tight) & (blocked <= samples.max(axis=0) + self.tight)
        blocked = blocked[box.all(axis=1)]
        if not len(blocked):
            return None
        mapped = union.values_at(samples, self._passable(union, "known", self.tight), False)
        near = cKDTree(blocked).query(samples, distance_upper_bound=self.tight)[0]
        now = mapped & ~np.isfinite(near)  # no obstacle within the robot's reach of the point
        away = np.hypot(*(samples - start[:2]).T) >= 1.0  # at the robot: the path's own check (``path_ahead_blocked``)
        shut = np.flatnonzero(mapped & ~now & away)
        if not len(shut):
            return None
        past = np.flatnonzero(now[shut[0] :])
        if not len(past):
            return None
        beyond = samples[shut[0] + int(past[0])]
        if self.plan(union, start, beyond, blocked_xy, probe=True) is not None or self.plan(union, start, beyond) is None:
            return None
        return int(legs[shut[0]])

    def new_obstacles(self, union: UnionGrid, pose: NDArray, points: NDArray) -> NDArray[np.float64]:
        """Obstacle returns (N, 2+, robot frame) near the robot that no mapped wall explains, in v_cur's frame."""
        near = points[np.hypot(points[:, 0], points[:, 1]) <= self.config.new_obstacle_range]
        if not len(near):
            return np.zeros((0, 2))
        xy = transform_points(pose, np.asarray(near[:, :2], dtype=np.float64))
        far = union.clear_of_walls(xy, self.config.new_obstacle_distance, outside=True)
        return xy[far]


def _parts(passable: NDArray[np.bool_]) -> NDArray[np.integer]:
    """Labels of the 4-connected parts of a passable mask: the cells one search can reach from
    another (``navkit.grid_search`` moves diagonally only between two free cells); in the smallest
    unsigned type that holds them (a byte a cell for up to 255 parts, not OpenCV's four)."""
    count, labels = cv2.connectedComponents(passable.view(np.uint8), connectivity=4)
    return np.asarray(labels, dtype=np.uint8 if count <= 256 else np.uint16 if count <= 65536 else np.int32)


def _turned(xy: NDArray, yaw: float) -> NDArray[np.float64]:
    """Points (..., 2) turned by ``yaw`` about the origin."""
    if yaw == 0.0:
        return np.asarray(xy, dtype=np.float64).copy()
    c, s = math.cos(yaw), math.sin(yaw)
    x, y = xy[..., 0], xy[..., 1]
    turned = np.empty(np.shape(xy), np.float64)
    turned[..., 0] = c * x - s * y
    turned[..., 1] = s * x + c * y
    return turned
