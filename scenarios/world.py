"""Ground-truth worlds: a free-space raster, the walls around it and the obstacles in it.

Raster convention (shared with ``navkit.grid_search``): ``free[row, col]``, row ↔ y, col ↔ x, the
centre of cell (r, c) at ``origin + ((c + 0.5) * res, (r + 0.5) * res)``; ``origin`` is the
lower-left corner of cell (0, 0).

Shapes: a corridor is its polyline buffered by width/2 with flat end caps and round joins (a
polyline whose last point equals its first is a ring, with no caps); a room is a rotated
rectangle; free space = (corridors ∪ rooms) − obstacles. Walls are the boundary of
corridors ∪ rooms, extruded to ``wall_height``; obstacles are boxes of their own height.

ROS maps (map_server YAML + image): pixel p = value/255, inverted unless ``negate``;
p ≥ occupied_thresh is occupied, p ≤ free_thresh is free, anything else unknown (a wall here);
``origin`` is the pose of the lower-left pixel and image row 0 is the largest y. The map's cells
pass the import rules of ``scenarios.map_import`` (stated in the scenario's lidar and robot:
blobs it cannot resolve, wall gaps, laser fans; ``world.map.clean``), and the largest connected
free component is the world's free space.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy import ndimage
from shapely import affinity
from shapely.geometry import LinearRing, LineString, MultiPolygon, Polygon, box
from shapely.ops import unary_union

from navkit import raster
from navkit.raster import GridFrame
from scenarios.map_import import ImportRules, MapImport, import_map, resolvable_size
from scenarios.schema import (
    MAX_RASTER_CELLS,
    ObstacleSpec,
    RobotSpec,
    ScenarioError,
    SensorSpec,
    WorldSpec,
    read_yaml,
)

PADDING_M = 1.0  # wall margin around the free space in a shape world's raster
# what a scenario takes per raster cell at its peak: the rasters, clearance and labels of the
# scenario itself, route spaces and skeletons, the oracle's and the simulator's copies (measured:
# about 80 B per cell loading the bundled scenes; the rest is margin)
BYTES_PER_CELL = 160
MEMORY_SHARE = 0.5  # a scenario may take at most this share of the machine's memory


def check_raster_size(shape: tuple[int, int], resolution: float, what: str = "a raster") -> None:
    """Refuse a raster that would not fit: ``ValueError`` with the reason."""
    cells = int(shape[0]) * int(shape[1])
    if cells > MAX_RASTER_CELLS:
        raise ValueError(
            f"{what} of {shape[0]} x {shape[1]} cells at {resolution} m is too large (at most {MAX_RASTER_CELLS:,} cells): "
            "use a coarser resolution or a smaller world"
        )
    import psutil

    total = psutil.virtual_memory().total
    need = cells * BYTES_PER_CELL
    if need > MEMORY_SHARE * total:
        raise ValueError(
            f"{what} of {shape[0]} x {shape[1]} cells at {resolution} m needs about {need / 1e9:.1f} GB, more than "
            f"{MEMORY_SHARE:.0%} of this machine's {total / 1e9:.1f} GB: use a coarser resolution or a smaller world"
        )


@dataclass
class World:
    resolution: float
    origin: NDArray[np.float64]  # (2,) lower-left corner of cell (0, 0)
    free: NDArray[np.bool_]  # (H, W) ground-truth free space (obstacles removed)
    structure_free: NDArray[np.bool_]  # (H, W) free space before obstacles: walls bound it
    wall_segments: NDArray[np.float64]  # (S, 2, 2) 2D wall segments, extruded to wall_height
    wall_height: float
    ceiling: bool
    obstacles: list[ObstacleSpec] = field(default_factory=list)
    geometry: Polygon | MultiPolygon | None = None  # exact free space of a shape world
    changes: list[ObstacleSpec] = field(default_factory=list)  # navigation-time boxes (in ``obstacles`` once applied)
    map_import: MapImport | None = None  # what the import rules changed (a map world's)

    @property
    def shape(self) -> tuple[int, int]:
        return self.free.shape  # type: ignore[return-value]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the raster, metres."""
        h, w = self.free.shape
        x0, y0 = self.origin
        return (float(x0), float(y0), float(x0 + w * self.resolution), float(y0 + h * self.resolution))

    @property
    def free_area_m2(self) -> float:
        if self.geometry is not None:
            return float(self.geometry.area)
        return float(self.free.sum()) * self.resolution**2

    @cached_property
    def clearance(self) -> NDArray[np.float32]:
        """Distance (m) from each cell centre to the nearest non-free cell (0 outside free space)."""
        padded = np.pad(self.free, 1, constant_values=False)
        dist = ndimage.distance_transform_edt(padded)[1:-1, 1:-1]
        # the EDT counts cell centres; half a cell more reaches the obstacle cell's border
        return np.where(self.free, (dist - 0.5) * self.resolution, 0.0).astype(np.float32)

    def eroded(self, radius: float) -> NDArray[np.bool_]:
        """Cells where a disc of ``radius`` centred on the cell centre stays in free space."""
        return self.clearance >= radius

    @property
    def frame(self) -> GridFrame:
        """The raster's placement (``navkit.raster``: the one cell <-> metre conversion)."""
        return GridFrame(self.origin, self.resolution)

    def to_cell(self, xy: NDArray | tuple[float, float]) -> NDArray[np.int64]:
        """Points (..., 2) [x, y] -> cells (..., 2) [row, col] (``GridFrame.to_cell``)."""
        return self.frame.to_cell(xy)

    def to_world(self, cells: NDArray) -> NDArray[np.float64]:
        """Cells (..., 2) [row, col] -> their centres (..., 2) [x, y] (``GridFrame.to_world``)."""
        return self.frame.to_world(cells)

    def inside(self, cells: NDArray) -> NDArray[np.bool_]:
        return raster.inside(cells, self.free.shape)

    def clearance_at(self, xy: NDArray | tuple[float, float]) -> float:
        """Clearance at a point (bilinear in the clearance raster; 0 outside the raster)."""
        return float(self.clearances_at(np.asarray(xy, dtype=np.float64)[None, :2])[0])

    def clearances_at(self, xy: NDArray) -> NDArray[np.float64]:
        """(N,) clearance at points (N, 2), bilinear in the clearance raster; 0 outside it."""
        rc = (np.asarray(xy, dtype=np.float64).reshape(-1, 2)[:, ::-1] - self.origin[::-1]) / self.resolution - 0.5
        return ndimage.map_coordinates(self.clearance, rc.T, order=1, cval=0.0).astype(np.float64)

    @property
    def wall_mask(self) -> NDArray[np.bool_]:
        """Non-free cells that touch free space (8-neighbourhood): the GT walls of map checks."""
        grown = ndimage.binary_dilation(self.free, structure=np.ones((3, 3), bool))
        return grown & ~self.free


# ---------------------------------------------------------------------------------------------
# shape worlds


def corridor_polygon(points: list[tuple[float, float]], width: float) -> Polygon:
    pts = [tuple(map(float, p)) for p in points]
    if len(pts) >= 4 and np.allclose(pts[0], pts[-1]):
        ring = LinearRing(pts[:-1])
        return ring.buffer(width / 2.0, join_style="round")
    return LineString(pts).buffer(width / 2.0, cap_style="flat", join_style="round")


def rectangle(center: tuple[float, float], size: tuple[float, float], yaw_deg: float) -> Polygon:
    cx, cy = center
    sx, sy = size
    rect = box(cx - sx / 2.0, cy - sy / 2.0, cx + sx / 2.0, cy + sy / 2.0)
    return affinity.rotate(rect, yaw_deg, origin=(cx, cy)) if yaw_deg else rect


def rasterize(geometry: Polygon | MultiPolygon, origin: NDArray, resolution: float, shape: tuple[int, int]) -> NDArray[np.bool_]:
    """Cells whose centre lies inside ``geometry`` (holes respected): exact centre sampling."""
    shapely.prepare(geometry)
    h, w = shape
    out = np.zeros(shape, dtype=bool)
    xmin, ymin, xmax, ymax = geometry.bounds
    c0 = max(int(np.floor((xmin - origin[0]) / resolution)), 0)
    c1 = min(int(np.ceil((xmax - origin[0]) / resolution)) + 1, w)
    r0 = max(int(np.floor((ymin - origin[1]) / resolution)), 0)
    r1 = min(int(np.ceil((ymax - origin[1]) / resolution)) + 1, h)
    if c1 <= c0 or r1 <= r0:
        return out
    xs = origin[0] + (np.arange(c0, c1) + 0.5) * resolution
    ys = origin[1] + (np.arange(r0, r1) + 0.5) * resolution
    grid_x, grid_y = np.meshgrid(xs, ys)
    inside = shapely.contains_xy(geometry, grid_x.ravel(), grid_y.ravel())
    out[r0:r1, c0:c1] = inside.reshape(grid_x.shape)
    return out


def polygon_segments(geometry: Polygon | MultiPolygon) -> NDArray[np.float64]:
    polygons = list(geometry.geoms) if isinstance(geometry, MultiPolygon) else [geometry]
    segments = []
    for polygon in polygons:
        for ring in [polygon.exterior, *polygon.interiors]:
            c = np.asarray(ring.coords)[:, :2]
            segments.append(np.stack([c[:-1], c[1:]], axis=1))
    return np.concatenate(segments, axis=0) if segments else np.zeros((0, 2, 2))


def _shapes(spec: WorldSpec) -> list[Polygon]:
    """The corridors and rooms of a shape world (their union is its free space before obstacles)."""
    corridors = [corridor_polygon(c.points, c.width) for c in spec.corridors]
    return corridors + [rectangle(r.center, r.size, r.yaw) for r in spec.rooms]


def _raster_frame(bounds: tuple[float, float, float, float], res: float) -> tuple[NDArray[np.float64], tuple[int, int]]:
    """Origin and shape of a shape world's raster over the shapes' ``bounds``, padded; refused
    (``ValueError``) if too large."""
    xmin, ymin, xmax, ymax = bounds
    origin = np.array([np.floor((xmin - PADDING_M) / res) * res, np.floor((ymin - PADDING_M) / res) * res])
    shape = (int(np.ceil((ymax + PADDING_M - origin[1]) / res)), int(np.ceil((xmax + PADDING_M - origin[0]) / res)))
    check_raster_size(shape, res)
    return origin, shape


def check_shape_world_size(spec: WorldSpec) -> None:
    """The size check of ``shape_world``, from the shapes' bounds alone (nothing is rasterized or
    merged): ``ValueError`` for a world too large, e.g. a generated building before it is written."""
    bounds = np.array([shape.bounds for shape in _shapes(spec)])
    _raster_frame((*bounds[:, :2].min(axis=0), *bounds[:, 2:].max(axis=0)), spec.resolution)


def shape_world(spec: WorldSpec) -> World:
    structure = unary_union(_shapes(spec))
    obstacle_polys = [rectangle(o.center, o.size, o.yaw) for o in spec.obstacles]
    free_geometry = structure.difference(unary_union(obstacle_polys)) if obstacle_polys else structure
    res = spec.resolution
    origin, shape = _raster_frame(structure.bounds, res)
    return World(
        resolution=res,
        origin=origin,
        free=rasterize(free_geometry, origin, res, shape),
        structure_free=rasterize(structure, origin, res, shape),
        wall_segments=polygon_segments(structure),
        wall_height=spec.wall_height,
        ceiling=spec.ceiling,
        obstacles=list(spec.obstacles),
        geometry=free_geometry,
    )


# ---------------------------------------------------------------------------------------------
# ROS map_server worlds


def read_map_cells(
    yaml_path: Path, scenario_file: str | Path, key: str = "world.map.yaml"
) -> tuple[NDArray[np.uint8], NDArray[np.float64], float]:
    """Cells (UNKNOWN / FREE / OCCUPIED, row 0 = lowest y), origin and resolution of a map_server
    map (``navkit.raster``, read as strictly as a scenario file; a map too large for this machine
    is refused before its image is decoded)."""
    if yaml_path.is_dir():
        raise ScenarioError(scenario_file, key, f"{yaml_path} is a folder, not a map_server YAML file")
    if not yaml_path.is_file():
        raise ScenarioError(scenario_file, key, f"map file {yaml_path} not found")

    def check_size(shape: tuple[int, int], resolution: float, image: Path) -> None:
        check_raster_size(shape, resolution, f"map image {image.name}")

    try:
        ros_map = raster.read_map_server(yaml_path, check_size=check_size, read_yaml=read_yaml)
    except raster.MapFileError as exc:
        raise ScenarioError(exc.file, exc.key, exc.reason) from None
    return ros_map.cells, ros_map.frame.origin, ros_map.frame.resolution


def read_ros_map(
    yaml_path: Path, scenario_file: str | Path, key: str = "world.map.yaml"
) -> tuple[NDArray[np.bool_], NDArray[np.float64], float]:
    """Free cells (row 0 = lowest y), origin and resolution of a map_server map (``read_map_cells``)."""
    cells, origin, resolution = read_map_cells(yaml_path, scenario_file, key)
    return cells == raster.FREE, origin, resolution


def raster_segments(free: NDArray[np.bool_], origin: NDArray, res: float) -> NDArray[np.float64]:
    """Boundary of a raster's free space as merged axis-aligned 2D segments."""
    padded = np.pad(free, 1, constant_values=False)
    segments: list[NDArray] = []
    # horizontal boundaries between padded rows r-1 and r
    rows_change = padded[1:, :] != padded[:-1, :]
    for r in np.nonzero(rows_change.any(axis=1))[0]:
        line = np.concatenate([[False], rows_change[r], [False]]).astype(np.int8)
        starts = np.nonzero(np.diff(line) == 1)[0]
        ends = np.nonzero(np.diff(line) == -1)[0]
        y = origin[1] + (r) * res  # padded row r boundary == raster row r-1/r boundary
        x0 = origin[0] + (starts - 1) * res
        x1 = origin[0] + (ends - 1) * res
        segments.append(np.stack([np.stack([x0, np.full_like(x0, y)], 1), np.stack([x1, np.full_like(x1, y)], 1)], 1))
    cols_change = padded[:, 1:] != padded[:, :-1]
    for c in np.nonzero(cols_change.any(axis=0))[0]:
        line = np.concatenate([[False], cols_change[:, c], [False]]).astype(np.int8)
        starts = np.nonzero(np.diff(line) == 1)[0]
        ends = np.nonzero(np.diff(line) == -1)[0]
        x = origin[0] + c * res
        y0 = origin[1] + (starts - 1) * res
        y1 = origin[1] + (ends - 1) * res
        segments.append(np.stack([np.stack([np.full_like(y0, x), y0], 1), np.stack([np.full_like(y1, x), y1], 1)], 1))
    return np.concatenate(segments, axis=0) if segments else np.zeros((0, 2, 2))


def import_rules(spec: WorldSpec, robot: RobotSpec, sensor: SensorSpec) -> ImportRules:
    """The import rules of a map world: ``world.map.clean`` in the scenario's lidar and robot."""
    assert spec.map is not None
    clean = spec.map.clean
    return ImportRules(
        small_obstacles=clean.small_obstacles,
        close_gaps=clean.close_gaps,
        fans=clean.fans,
        resolve_range_m=clean.resolve_range,
        resolvable_m=resolvable_size(clean.resolve_range, sensor.horizontal_resolution),
        robot_radius_m=robot.radius,
    )


def map_world(spec: WorldSpec, scenario_file: Path, robot: RobotSpec | None = None, sensor: SensorSpec | None = None) -> World:
    """The world of a ROS map, its cells cleaned by the import rules for ``robot`` and ``sensor``
    (the format's defaults if not given)."""
    assert spec.map is not None
    cells, origin, res = read_map_cells((scenario_file.parent / spec.map.yaml), scenario_file)
    structure, report = import_map(cells, res, import_rules(spec, robot or RobotSpec(), sensor or SensorSpec()))
    if not structure.any():
        reason = "the map has no free cells"
        if report.raw_free_px:
            reason = "no free space is left by the import rules (world.map.clean: false keeps the raw map)"
        raise ScenarioError(scenario_file, "world.map", reason)
    free = structure.copy()
    if spec.obstacles:
        h, w = free.shape
        blocked = rasterize(unary_union([rectangle(o.center, o.size, o.yaw) for o in spec.obstacles]), origin, res, (h, w))
        free &= ~blocked
    return World(
        resolution=res,
        origin=origin,
        free=free,
        structure_free=structure,
        wall_segments=raster_segments(structure, origin, res),
        wall_height=spec.wall_height,
        ceiling=spec.ceiling,
        obstacles=list(spec.obstacles),
        map_import=report,
    )


def build_world(spec: WorldSpec, scenario_file: Path, robot: RobotSpec | None = None, sensor: SensorSpec | None = None) -> World:
    """The mapping stage's world (``spec.changes`` listed in ``changes``, not applied); a map
    world's import rules use ``robot`` and ``sensor`` (the format's defaults if not given)."""
    world = map_world(spec, scenario_file, robot, sensor) if spec.map is not None else shape_world(spec)
    world.changes = list(spec.changes)
    return world


def with_changes(world: World) -> World:
    """The navigation stage's world: ``world`` with its ``changes`` standing in the free space.

    The same object if there are no changes. Walls (``structure_free``, ``wall_segments``) are
    the mapping world's: a change is an obstacle, as a closed door or a parked cart is.
    """
    if not world.changes:
        return world
    boxes = unary_union([rectangle(c.center, c.size, c.yaw) for c in world.changes])
    blocked = rasterize(boxes, world.origin, world.resolution, world.free.shape)
    return World(
        resolution=world.resolution,
        origin=world.origin.copy(),
        free=world.free & ~blocked,
        structure_free=world.structure_free,
        wall_segments=world.wall_segments,
        wall_height=world.wall_height,
        ceiling=world.ceiling,
        obstacles=[*world.obstacles, *world.changes],
        geometry=world.geometry.difference(boxes) if world.geometry is not None else None,
        changes=list(world.changes),
        map_import=world.map_import,
    )
