"""SLAM-like maps of generated buildings: a shape world drawn as a robot's lidar SLAM map shows it.

``slam_map(spec, seed)`` takes a generated building (a scenario dict of ``generators.ring_building``,
``generators.corridor_tree`` or ``lattice.lattice_building``), gives its open side rooms a front
wall with a door and narrows every door (``slam_doors``), rasterizes it with ``scenarios.world``
and draws the result as a map_server map would show it, with the artefacts a real robot's map has
(issue 28: the importer must turn them into a world a robot can perceive and pass):

* walls ``wall_px`` pixels thick, the thickness varying along the wall (smooth noise, about 1 m
  correlation, plus a pixel of per-pixel jitter), and a ragged inner face: ``wall_bump_share`` of
  the free pixels along walls and furniture turned occupied (never in or before a door);
* furniture (the world's obstacles) as an occupied outline of the same thickness, unknown inside;
* doors 0.75-0.9 m wide on whole pixels (``door_width_m``), clear of every artefact;
* broken walls (``breaks_per_100m`` of exterior wall): gaps of ``break_px`` (1-2) pixels through a
  wall between free space and the unknown outside;
* laser fans (``fans_per_100m`` of exterior wall): ``fan_rays`` one-pixel free rays from a point
  in a room or corridor through a window in an exterior wall, each reaching ``fan_reach_m`` into
  the unknown beyond it;
* unknown corners (``unknown_corner_share`` of the rooms): a patch of a room's corner never seen;
* speckle (``speckle_per_100m2`` of free space): isolated 1-3 pixel occupied blobs (noise,
  people), and chairs (``chairs_per_100m2``): four one-pixel legs on a 0.4-0.5 m square.

An exterior wall is one whose far side is unknown (the outside of the building, or a block's
inside the mapping never entered): a straight walk from a free pixel across it meets unknown
before free, and at least ``OUTSIDE_M`` of it (not the unknown core of a thick wall).
Counts are the densities times the building's exterior wall length or free area, rounded; the
record (``SlamRecord``) says where each artefact is. The map's ground truth is the map itself, as
for any real map. Same building, seed and amounts, same map, byte for byte.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from numpy.typing import NDArray
from scipy import ndimage
from skimage.draw import line as raster_line

from navkit import raster
from navkit.files import atomic_write
from navkit.raster import FREE, OCCUPIED, UNKNOWN, GridFrame, largest_component
from scenarios.schema import parse_spec
from scenarios.slam_doors import DOOR_CLEAR_M, Door, slam_doors
from scenarios.world import shape_world

RESOLUTION = 0.05  # the map's pixel (the generated buildings' raster)
EIGHT = np.ones((3, 3), bool)
DIRECTIONS = ((1, 0), (-1, 0), (0, 1), (0, -1))  # (d_row, d_col): outward across a wall
OUTSIDE_M = 1.0  # beyond an exterior wall, at least this much unknown straight ahead


@dataclass(frozen=True)
class Artefacts:
    """How much of each artefact a SLAM-like map gets (defaults: about what the real office map of
    issue 28 shows). Densities: per 100 m of exterior wall, per 100 m² of free space."""

    wall_px: tuple[int, int] = (2, 4)  # wall thickness in pixels, smallest and largest
    wall_bump_share: float = 0.04  # share of the free pixels along walls turned occupied
    door_width_m: tuple[float, float] = (0.75, 0.9)  # every door, on whole pixels
    breaks_per_100m: float = 4.0  # gaps through exterior walls
    break_px: tuple[int, int] = (1, 2)  # a gap's width in pixels
    fans_per_100m: float = 3.0  # laser fans through exterior walls
    fan_rays: tuple[int, int] = (4, 9)  # rays a fan (at most one per 2 pixels of its window)
    fan_reach_m: tuple[float, float] = (1.0, 5.0)  # how far a ray reaches beyond the wall
    speckle_per_100m2: float = 2.0  # isolated 1-3 pixel occupied blobs
    chairs_per_100m2: float = 0.4  # four one-pixel legs each
    unknown_corner_share: float = 0.4  # rooms with an unknown corner patch
    unknown_corner_m: tuple[float, float] = (0.3, 0.8)  # the patch's sides

    def __post_init__(self) -> None:
        checks = {
            "wall_px": 1 <= self.wall_px[0] <= self.wall_px[1] <= 10,
            "wall_bump_share": 0.0 <= self.wall_bump_share <= 0.5,
            "door_width_m": 0.6 < self.door_width_m[0] <= self.door_width_m[1] <= 2.0,
            "break_px": 1 <= self.break_px[0] <= self.break_px[1] <= 3,
            "fan_rays": 1 <= self.fan_rays[0] <= self.fan_rays[1] <= 50,
            "fan_reach_m": 0.2 <= self.fan_reach_m[0] <= self.fan_reach_m[1] <= 20.0,
            "unknown_corner_share": 0.0 <= self.unknown_corner_share <= 1.0,
            "unknown_corner_m": 0.1 <= self.unknown_corner_m[0] <= self.unknown_corner_m[1] <= 2.0,
        }
        for density in ("breaks_per_100m", "fans_per_100m", "speckle_per_100m2", "chairs_per_100m2"):
            checks[density] = 0.0 <= getattr(self, density) <= 1000.0
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"SLAM artefacts: {name} {getattr(self, name)} is out of range")

    @classmethod
    def none(cls) -> Artefacts:
        """Walls as thick as the defaults' and no other artefact (a reference map)."""
        return cls(
            wall_bump_share=0.0, breaks_per_100m=0.0, fans_per_100m=0.0, speckle_per_100m2=0.0,
            chairs_per_100m2=0.0, unknown_corner_share=0.0,
        )  # fmt: skip


@dataclass
class Fan:
    source: tuple[float, float]  # where the robot stood (metres)
    window: tuple[float, float]  # the wall pixel the fan's middle ray crosses
    ray_ends: list[tuple[float, float]]  # each ray's last free pixel outside


@dataclass
class SlamRecord:
    """Where each artefact of a SLAM-like map is (metres, the map frame)."""

    doors: list[Door] = field(default_factory=list)
    breaks: list[tuple[float, float, int]] = field(default_factory=list)  # x, y (wall pixel by the free side), width px
    fans: list[Fan] = field(default_factory=list)
    speckle: list[tuple[float, float]] = field(default_factory=list)  # a blob's first pixel
    chair_legs: list[tuple[float, float]] = field(default_factory=list)
    unknown_corners: list[tuple[float, float, float, float]] = field(default_factory=list)  # x0, y0, x1, y1
    bumps: int = 0
    exterior_wall_m: float = 0.0
    free_area_m2: float = 0.0

    def counts(self) -> dict[str, float]:
        return {
            "doors": len(self.doors),
            "breaks": len(self.breaks),
            "fans": len(self.fans),
            "fan_rays": sum(len(f.ray_ends) for f in self.fans),
            "speckle": len(self.speckle),
            "chair_legs": len(self.chair_legs),
            "unknown_corners": len(self.unknown_corners),
            "bumps": self.bumps,
            "exterior_wall_m": round(self.exterior_wall_m, 1),
            "free_area_m2": round(self.free_area_m2, 1),
        }

    def summary(self) -> str:
        return ", ".join(f"{value} {key.replace('_', ' ')}" for key, value in self.counts().items())


@dataclass
class SlamMap:
    cells: NDArray[np.uint8]  # (H, W) UNKNOWN / FREE / OCCUPIED, row 0 the lowest y
    frame: GridFrame
    record: SlamRecord
    source: dict  # the building drawn (doors narrowed, open rooms behind doors)


# ---------------------------------------------------------------------------------------------
# the map


def slam_map(spec: dict, seed: int, artefacts: Artefacts | None = None) -> SlamMap:
    """The SLAM-like map of a generated building (a scenario dict of a shape world)."""
    artefacts = artefacts or Artefacts()
    rng = np.random.default_rng([seed, 28])
    building, doors = slam_doors(spec, rng, artefacts.door_width_m, RESOLUTION)
    world = shape_world(parse_spec(building, f"<generated {spec['name']}>").world)
    if abs(world.resolution - RESOLUTION) > 1e-12:
        raise ValueError(f"a SLAM-like map is drawn at {RESOLUTION} m a pixel (the building has {world.resolution})")
    pad = int(np.ceil((artefacts.fan_reach_m[1] + 1.0) / RESOLUTION))
    free = largest_component(np.pad(world.free, pad, constant_values=False))  # slivers behind furniture go
    frame = GridFrame(world.origin - pad * RESOLUTION, RESOLUTION)
    canvas = _Canvas(frame, rng, [d.centre for d in doors])
    canvas.walls(free, artefacts.wall_px)
    record = SlamRecord(doors=doors, free_area_m2=float(free.sum()) * RESOLUTION**2)
    faces = canvas.exterior_faces(artefacts.wall_px[1] + 1)
    record.exterior_wall_m = sum(len(f) for f in faces) * RESOLUTION
    per_wall = record.exterior_wall_m / 100.0
    record.fans = canvas.fans(faces, _count(artefacts.fans_per_100m * per_wall), artefacts)
    record.breaks = canvas.breaks(faces, _count(artefacts.breaks_per_100m * per_wall), artefacts.break_px)
    record.bumps = canvas.bumps(artefacts.wall_bump_share)
    record.unknown_corners = canvas.unknown_corners(building, artefacts)
    per_area = record.free_area_m2 / 100.0
    record.speckle, record.chair_legs = canvas.speckle(
        _count(artefacts.speckle_per_100m2 * per_area), _count(artefacts.chairs_per_100m2 * per_area)
    )
    _, pieces = ndimage.label(canvas.cells == FREE, structure=EIGHT)
    if pieces != 1:
        raise RuntimeError(f"the SLAM-like map of {spec['name']} has {pieces} free pieces")  # a bug of this module
    return SlamMap(canvas.cells, frame, record, building)


def _count(value: float) -> int:
    return int(np.floor(value + 0.5))


class _Canvas:
    """The map's cells and the bookkeeping of where artefacts may go."""

    def __init__(self, frame: GridFrame, rng: np.random.Generator, door_centres: list[tuple[float, float]]) -> None:
        self.frame = frame
        self.rng = rng
        self.door_centres = np.asarray(door_centres, float).reshape(-1, 2)
        self.used: list[tuple[float, float]] = []  # fans and breaks: kept apart
        self.cells: NDArray[np.uint8] = np.zeros((0, 0), np.uint8)
        self.opened: NDArray[np.bool_] = np.zeros((0, 0), bool)  # pixels fans and breaks freed

    def xy(self, rc: NDArray | tuple) -> tuple[float, float]:
        x, y = self.frame.to_world(np.asarray(rc, dtype=np.float64))
        return (round(float(x), 3), round(float(y), 3))

    def near_door(self, xy: tuple[float, float], distance: float) -> bool:
        return bool(len(self.door_centres)) and bool(np.hypot(*(self.door_centres - xy).T).min() < distance)

    def near_used(self, xy: tuple[float, float], distance: float) -> bool:
        return any(np.hypot(xy[0] - u[0], xy[1] - u[1]) < distance for u in self.used)

    # walls -------------------------------------------------------------------------------------

    def walls(self, free: NDArray[np.bool_], wall_px: tuple[int, int]) -> None:
        """Free space, walls (and furniture outlines) ``wall_px`` thick, unknown elsewhere."""
        low, high = wall_px
        noise = ndimage.gaussian_filter(self.rng.random(free.shape), sigma=1.0 / RESOLUTION / 2)
        noise = (noise - noise.min()) / max(float(np.ptp(noise)), 1e-12)
        thickness = low + noise * (high - low) + (self.rng.random(free.shape) < 0.3)  # ragged outer face
        thickness = np.minimum(thickness, high)
        distance = ndimage.distance_transform_edt(~free)
        self.cells = np.full(free.shape, UNKNOWN, np.uint8)
        self.cells[free] = FREE
        self.cells[~free & (distance <= np.maximum(thickness, low))] = OCCUPIED
        self.opened = np.zeros(free.shape, bool)

    def exterior_faces(self, max_px: int) -> list[NDArray[np.int64]]:
        """Per direction of ``DIRECTIONS``: the free pixels (K, 2) [row, col] whose neighbour that way
        is a wall that a walk of at most ``max_px`` pixels crosses into unknown that goes on for
        ``OUTSIDE_M`` straight ahead (an exterior wall; not the unknown core of a thick wall)."""
        cells = self.cells
        unknown = (cells == UNKNOWN).astype(np.uint8)
        deep_px = int(round(OUTSIDE_M / RESOLUTION))
        faces = []
        for d in DIRECTIONS:
            deep = unknown.copy()
            for j in range(1, deep_px):
                deep &= _shifted(unknown, d, j, 0)
            alive = (cells == FREE) & (_shifted(cells, d, 1, UNKNOWN) == OCCUPIED)
            exterior = np.zeros_like(alive)
            for k in range(2, max_px + 2):
                ahead = _shifted(cells, d, k, FREE)
                exterior |= alive & (_shifted(deep, d, k, 0) == 1)
                alive &= ahead == OCCUPIED
            faces.append(np.argwhere(exterior))
        return faces

    def _candidates(self, faces: list[NDArray[np.int64]]) -> list[tuple[int, int, int]]:
        """(row, col, direction index) of every exterior face pixel, in a seeded order."""
        every = [(int(r), int(c), k) for k, face in enumerate(faces) for r, c in face]
        return [every[i] for i in self.rng.permutation(len(every))]

    def _straight(self, faces_set: list[set], r: int, c: int, k: int, half_px: int) -> bool:
        """The exterior wall runs straight ``half_px`` pixels either side of (r, c)."""
        dr, dc = DIRECTIONS[k]
        return all((r + j * dc, c + j * dr) in faces_set[k] for j in range(-half_px, half_px + 1))

    def _walk(self, cells: NDArray[np.uint8], r: int, c: int, k: int) -> list[tuple[int, int]] | None:
        """The wall pixels from free (r, c) outward to the unknown, or None if it ends elsewhere."""
        dr, dc = DIRECTIONS[k]
        out = []
        r, c = r + dr, c + dc
        while 0 <= r < cells.shape[0] and 0 <= c < cells.shape[1] and cells[r, c] == OCCUPIED:
            out.append((r, c))
            r, c = r + dr, c + dc
        inside = 0 <= r < cells.shape[0] and 0 <= c < cells.shape[1]
        return out if out and inside and cells[r, c] == UNKNOWN else None

    # fans and breaks ---------------------------------------------------------------------------

    def breaks(self, faces: list[NDArray[np.int64]], count: int, width_px: tuple[int, int]) -> list[tuple[float, float, int]]:
        """``count`` gaps through exterior walls, each ``width_px`` pixels wide."""
        faces_set = [set(map(tuple, f.tolist())) for f in faces]
        made: list[tuple[float, float, int]] = []
        for r, c, k in self._candidates(faces):
            if len(made) >= count:
                break
            xy = self.xy((r, c))
            if self.near_door(xy, 1.5) or self.near_used(xy, 1.5) or not self._straight(faces_set, r, c, k, 6):
                continue
            width = int(self.rng.integers(width_px[0], width_px[1] + 1))
            dr, dc = DIRECTIONS[k]
            walks = [self._walk(self.cells, r + j * dc, c + j * dr, k) for j in range(width)]
            if any(w is None for w in walks):
                continue
            for walk in walks:
                for pixel in walk or []:
                    self.cells[pixel] = FREE
                    self.opened[pixel] = True
            self.used.append(xy)
            made.append((*xy, width))
        return made

    def fans(self, faces: list[NDArray[np.int64]], count: int, artefacts: Artefacts) -> list[Fan]:
        """``count`` laser fans through exterior walls (rays traced on the walls as they were)."""
        faces_set = [set(map(tuple, f.tolist())) for f in faces]
        before = self.cells.copy()
        clearance = ndimage.distance_transform_edt(before == FREE)
        made: list[Fan] = []
        for r, c, k in self._candidates(faces):
            if len(made) >= count:
                break
            xy = self.xy((r, c))
            half = int(self.rng.integers(4, 12))  # the window's half width, pixels
            if self.near_door(xy, 2.0) or self.near_used(xy, 2.5) or not self._straight(faces_set, r, c, k, half + 2):
                continue
            source = self._fan_source(before, clearance, r, c, k)
            if source is None:
                continue
            rays = self._fan_rays(before, source, (r, c), k, half, artefacts)
            if not rays:
                continue
            for pixels in rays:
                for pixel in pixels:
                    self.cells[pixel] = FREE
                    self.opened[pixel] = True
            self.used.append(xy)
            made.append(Fan(self.xy(source), xy, [self.xy(pixels[-1]) for pixels in rays]))
        return made

    def _fan_source(self, cells: NDArray, clearance: NDArray, r: int, c: int, k: int) -> tuple[int, int] | None:
        """Where the robot stood: 0.5-2.5 m in from the window, in the open, the window in sight."""
        dr, dc = DIRECTIONS[k]
        back = int(self.rng.integers(10, 51))
        while back >= 10:
            sr, sc = r - dr * back, c - dc * back
            if 0 <= sr < cells.shape[0] and 0 <= sc < cells.shape[1] and clearance[sr, sc] >= 6:
                rows, cols = raster_line(sr, sc, r, c)
                if np.all(cells[rows, cols] == FREE):
                    return (sr, sc)
            back //= 2
        return None

    def _fan_rays(
        self, cells: NDArray, source: tuple[int, int], window: tuple[int, int], k: int, half: int, artefacts: Artefacts
    ) -> list[list[tuple[int, int]]]:
        """The pixels each ray frees (the window in the wall, then the unknown beyond), ``[]`` if none
        gets out. A ray that meets free space beyond a wall (furniture, an inside wall) is dropped."""
        dr, dc = DIRECTIONS[k]
        n = int(self.rng.integers(artefacts.fan_rays[0], artefacts.fan_rays[1] + 1))
        n = min(n, half + 1)  # rays at least 2 pixels apart in the window: one-pixel rays, not a blob
        offsets = np.linspace(-half, half, n) if n > 1 else np.zeros(1)
        rays = []
        for offset in offsets:
            target = np.array([window[0] + offset * dc, window[1] + offset * dr], float)
            direction = target - source
            distance = float(np.linalg.norm(direction))
            reach = float(self.rng.uniform(*artefacts.fan_reach_m)) / RESOLUTION
            end = np.asarray(source, float) + direction / distance * (distance + 12 + reach)
            end = np.clip(np.round(end), 0, np.array(cells.shape) - 1).astype(int)
            rows, cols = raster_line(source[0], source[1], int(end[0]), int(end[1]))
            pixels = _ray_out(cells, rows, cols, int(reach))
            if pixels:
                rays.append(pixels)
        return rays

    # the rest ----------------------------------------------------------------------------------

    def bumps(self, share: float) -> int:
        """Turn ``share`` of the free pixels along walls and furniture occupied (not at doors, fans
        or breaks); a free pocket they cut off becomes wall too."""
        free = self.cells == FREE
        along = free & ndimage.binary_dilation(self.cells == OCCUPIED, structure=EIGHT)
        keep_off = self._protected(0.6, 0.5)
        chosen = along & ~keep_off & (self.rng.random(free.shape) < share)
        self.cells[chosen] = OCCUPIED
        self._fill_pockets(OCCUPIED)
        return int(chosen.sum())

    def _protected(self, door_m: float, used_m: float) -> NDArray[np.bool_]:
        """Pixels within ``door_m`` of a door's centre, ``used_m`` of a fan's window or a break, or
        3 pixels of what fans and breaks opened."""
        protected = ndimage.binary_dilation(self.opened, structure=EIGHT, iterations=3)
        for centres, radius in ((self.door_centres, door_m), (np.asarray(self.used, float).reshape(-1, 2), used_m)):
            marks = np.zeros(self.cells.shape, bool)
            for cell in self.frame.to_cell(centres):
                if raster.inside(cell, marks.shape):
                    marks[tuple(cell)] = True
            if marks.any():
                protected |= ndimage.distance_transform_edt(~marks) * RESOLUTION <= radius
        return protected

    def _fill_pockets(self, value: int) -> int:
        """Free pieces cut off from the main one take ``value``; returns their pixels."""
        pieces = largest_component(self.cells == FREE)
        cut = (self.cells == FREE) & ~pieces
        self.cells[cut] = value
        return int(cut.sum())

    def unknown_corners(self, building: dict, artefacts: Artefacts) -> list[tuple[float, float, float, float]]:
        """A corner patch of ``unknown_corner_share`` of the rooms left unknown (never seen)."""
        rooms = [r for r in building["world"]["rooms"] if min(r["size"]) >= 2.0 and r.get("yaw", 0.0) % 90 == 0]
        order = self.rng.permutation(len(rooms))
        wanted = _count(artefacts.unknown_corner_share * len(rooms))
        opened_near = ndimage.binary_dilation(self.opened, structure=EIGHT, iterations=3)
        made: list[tuple[float, float, float, float]] = []
        for i in order:
            if len(made) >= wanted:
                break
            (x0, y0, x1, y1) = _box(rooms[i])
            sx, sy = (float(self.rng.uniform(*artefacts.unknown_corner_m)) for _ in range(2))
            cx = x0 if self.rng.random() < 0.5 else x1 - sx
            cy = y0 if self.rng.random() < 0.5 else y1 - sy
            patch = (round(cx, 3), round(cy, 3), round(cx + sx, 3), round(cy + sy, 3))
            centre = (cx + sx / 2, cy + sy / 2)
            if self.near_door(centre, DOOR_CLEAR_M) or self.near_used(centre, 1.0):
                continue
            (r0, c0), (r1, c1) = self.frame.to_cell(np.array([[patch[0], patch[1]], [patch[2], patch[3]]]))
            if opened_near[r0 : r1 + 1, c0 : c1 + 1].any():
                continue
            window = self.cells[r0 : r1 + 1, c0 : c1 + 1]
            window[window == FREE] = UNKNOWN
            self._fill_pockets(UNKNOWN)
            made.append(patch)
        return made

    def speckle(self, count: int, chairs: int) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
        """``count`` isolated 1-3 pixel blobs and ``chairs`` chairs of four one-pixel legs in free
        space, each pixel at least two pixels from anything occupied or unknown and from each other."""
        clearance = ndimage.distance_transform_edt(self.cells == FREE)
        taken = np.zeros(self.cells.shape, bool)  # pixels no new blob may come within two pixels of
        keep_off = self._protected(DOOR_CLEAR_M / 2, 0.0)
        speckle: list[tuple[float, float]] = []
        legs: list[tuple[float, float]] = []
        shapes = [
            [(0, 0)],
            [(0, 0), (0, 1)],
            [(0, 0), (1, 0)],
            [(0, 0), (1, 1)],
            [(0, 0), (0, 1), (1, 1)],
            [(0, 0), (1, 0), (1, 1)],
        ]
        candidates = np.argwhere((clearance >= 4.5) & ~keep_off)
        for i in self.rng.permutation(len(candidates)):
            if len(speckle) >= count:
                break
            r, c = (int(v) for v in candidates[i])
            pixels = [(r + a, c + b) for a, b in shapes[int(self.rng.integers(len(shapes)))]]
            if self._place(pixels, clearance, taken, 4.5):
                speckle.append(self.xy((r, c)))
        candidates = np.argwhere((clearance >= 14.0) & ~keep_off)
        placed = 0
        for i in self.rng.permutation(len(candidates)):
            if placed >= chairs:
                break
            r, c = (int(v) for v in candidates[i])
            half, turn = float(self.rng.uniform(0.2, 0.25)) / RESOLUTION, float(self.rng.uniform(0, np.pi / 2))
            corners = [(half * np.cos(turn + a), half * np.sin(turn + a)) for a in np.arange(4) * np.pi / 2 + np.pi / 4]
            pixels = [(int(round(r + dy)), int(round(c + dx))) for dx, dy in corners]
            if self._place(pixels, clearance, taken, 3.0):
                placed += 1
                legs += [self.xy(p) for p in pixels]
        return speckle, legs

    def _place(self, pixels: list[tuple[int, int]], clearance: NDArray, taken: NDArray, least: float) -> bool:
        """Occupy ``pixels`` if each has ``least`` clearance and no blob within two pixels."""
        if any(clearance[p] < least or taken[max(p[0] - 2, 0) : p[0] + 3, max(p[1] - 2, 0) : p[1] + 3].any() for p in pixels):
            return False
        for p in pixels:
            self.cells[p] = OCCUPIED
            taken[p] = True
        return True


def _ray_out(cells: NDArray, rows: NDArray, cols: NDArray, reach: int) -> list[tuple[int, int]]:
    """Along a ray's pixels (from inside): the wall pixels it crosses and up to ``reach`` unknown
    pixels beyond, or ``[]`` if it meets unknown before a wall or free space right after one."""
    out: list[tuple[int, int]] = []
    phase = "inside"
    outside = 0
    for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
        value = cells[r, c]
        if phase == "inside":
            if value == UNKNOWN:
                return []
            if value == OCCUPIED:
                phase = "wall"
                out.append((r, c))
        elif phase == "wall":
            if value == FREE:
                return []
            if value == UNKNOWN:
                phase = "outside"
            out.append((r, c))
            outside += value == UNKNOWN
        else:
            if value != UNKNOWN or outside >= reach:
                break
            out.append((r, c))
            outside += 1
    return out if outside >= 2 else []


def _shifted(cells: NDArray[np.uint8], d: tuple[int, int], k: int, fill: int) -> NDArray[np.uint8]:
    """``out[r, c] = cells[r + k d_row, c + k d_col]`` (``fill`` beyond the edge)."""
    out = np.full_like(cells, fill)
    h, w = cells.shape
    dr, dc = d[0] * k, d[1] * k
    out[max(-dr, 0) : h - max(dr, 0), max(-dc, 0) : w - max(dc, 0)] = cells[
        max(dr, 0) : h - max(-dr, 0), max(dc, 0) : w - max(-dc, 0)
    ]
    return out


def _box(room: dict) -> tuple[float, float, float, float]:
    (cx, cy), (sx, sy) = room["center"], room["size"]
    if room.get("yaw", 0.0) % 180 == 90:
        sx, sy = sy, sx
    return (cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2)


# ---------------------------------------------------------------------------------------------
# files


def slam_scenario_dict(spec: dict, map_yaml: str, name: str, record: SlamRecord) -> dict:
    """The scenario on a SLAM-like map: the building's mapping route and trials, its map."""
    return {
        "format": "navtopo-scenario/1",
        "name": name,
        "description": f"SLAM-like map of {spec['description']}: {record.summary()}",
        "seed": spec["seed"],
        "world": {"wall_height": spec["world"].get("wall_height", 2.6), "map": {"yaml": map_yaml}},
        "mapping_route": spec["mapping_route"],
        "trials": spec["trials"],
    }


def write_slam_scenario(spec: dict, scenario_path: Path, seed: int, artefacts: Artefacts | None = None) -> SlamMap:
    """Write ``<stem>_map.pgm``, ``<stem>_map.yaml`` and the scenario ``scenario_path`` on them.

    The scenario is validated before anything is written; each file is written atomically."""
    made = slam_map(spec, seed, artefacts)
    map_yaml = scenario_path.with_name(f"{scenario_path.stem}_map.yaml")
    scenario = slam_scenario_dict(spec, map_yaml.name, scenario_path.stem, made.record)
    parse_spec(scenario, scenario_path)
    scenario_path.parent.mkdir(parents=True, exist_ok=True)
    raster.write_map_server(
        map_yaml,
        raster.trinary_image(made.cells),
        made.frame,
        image_format="pgm",
        comment=f"SLAM-like map, seed {seed}: {made.record.summary()}",
    )
    text = yaml.safe_dump(scenario, sort_keys=False, default_flow_style=None, width=120)
    atomic_write(scenario_path, text.encode("utf-8"))
    return made
