"""What a ROS map becomes as a world: the import rules, stated in the scenario's sensor and robot.

A robot's SLAM map holds what no simulated robot could perceive or pass if it were extruded as it
is: isolated blobs of a pixel or two (chair legs, people, noise) that become pillars thinner than
the gap between two lidar rays, one-pixel free rays fanning into unknown space that become slits
in the walls, and walls broken by gaps of a pixel or two. The world's free space is the map's free
cells after these rules, applied in this order on the map's cells (FREE / OCCUPIED / UNKNOWN;
whatever is not free is wall). The rules are morphology on the raster (``scipy.ndimage``), and
none of them narrows a passage the robot fits through (docs/DESIGN.md, "Map worlds"):

1. **Small obstacles.** An *island* is a piece of non-free cells (8-connected, occupied or
   unknown) with free space all round it. An island whose extent (the larger side of its bounding
   box) is below the *resolvable size* ``d`` is removed (``remove``, the default: it becomes
   free), grown to a square of side at least ``d`` (``grow``) or kept (``keep``). ``d`` is the
   width that two rays of the lidar's horizontal resolution ``Δθ`` hit in every scan at the range
   ``R`` (``resolve_range``, default 3 m, the distance within which a robot at 1 m/s must see what
   it will avoid): ``d = 2 · 2R·sin(Δθ/2)``, 10.5 cm at 1°, two pixels of a 0.05 m map. Two rays,
   not one: a single return is what range filters and voxel filters drop, and at ``d`` one ray
   always hits. Removal is the default because the map is the only evidence of such a blob and it
   is a weak one: a speck of one or two pixels is a SLAM map's noise floor, or a person who walked
   by; its true size is unknown, and growing it would invent obstacles that narrow corridors and
   doors and change which trials exist. Removing never narrows a passage.
2. **Wall gaps.** Free slits narrower than ``d`` (at most ``g = ⌈d / resolution⌉ - 1`` pixels
   across, axis-aligned; diagonal ones up to √2 times that) become wall: the free space is opened
   by a square of ``g + 1`` pixels. No robot passes such a slit, and the lidar sees through it only
   now and then; so broken walls become continuous where the map's are nearly so. A door (wider
   than the robot) is never touched.
3. **Laser fans.** Free cells that no robot body covers (no disc of the robot's radius centred
   where the robot's centre may be, ``World.eroded``), in an 8-connected piece that touches unknown
   space or the map's edge, become wall: rays fanning into unknown space, and the ragged free
   fringe of walls seen through gaps. Such cells are neither places a robot can reach nor space a
   robot could have seen from there; kept, they are slits a lidar looks into. Removing them never
   changes where the robot's centre may be (the cells lie farther than its radius from every such
   place), so no trial or route is lost.

Then, as without the rules, the largest connected free piece is the world's free space.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from navkit.raster import FREE, OCCUPIED, UNKNOWN, largest_component

EIGHT = np.ones((3, 3), bool)
SmallObstacles = Literal["remove", "grow", "keep"]
RESOLVE_RANGE_M = 3.0  # default R of rule 1
RAYS_TO_RESOLVE = 2  # rays that must hit an obstacle in every scan for it to count as seen


def resolvable_size(resolve_range_m: float, horizontal_resolution_deg: float) -> float:
    """The width (m) that ``RAYS_TO_RESOLVE`` rays hit in every scan at ``resolve_range_m``."""
    spacing = 2.0 * resolve_range_m * math.sin(math.radians(horizontal_resolution_deg) / 2.0)
    return RAYS_TO_RESOLVE * spacing


@dataclass(frozen=True)
class ImportRules:
    """The rules of one import: which apply, and their sizes (metres)."""

    small_obstacles: SmallObstacles = "remove"
    close_gaps: bool = True
    fans: bool = True
    resolve_range_m: float = RESOLVE_RANGE_M
    resolvable_m: float = 0.105  # d, from the sensor (``resolvable_size``)
    robot_radius_m: float = 0.3

    @property
    def raw(self) -> bool:
        return self.small_obstacles == "keep" and not self.close_gaps and not self.fans


@dataclass(frozen=True)
class MapImport:
    """What the import changed, in map pixels (``changed_px``: the cells in which the world's free
    space differs from the raw map's largest free piece, what ``clean: false`` gives)."""

    rules: ImportRules
    gap_px: int  # the widest slit closed (rule 2), pixels
    islands: int  # islands below the resolvable size (rule 1)
    removed_px: int  # their pixels made free (remove)
    grown_px: int  # free pixels made obstacle round them (grow)
    closed_px: int  # free pixels of slits made wall (rule 2)
    fan_px: int  # free pixels no robot covers, touching unknown, made wall (rule 3)
    detached_px: int  # free pixels left out of the world's free space: not connected to it
    free_px: int  # the world's free space
    raw_free_px: int  # the raw map's largest free piece
    changed_px: int

    def as_dict(self) -> dict[str, Any]:
        """The report of ``scenario show --json`` and of the manifest's ``scenario.map_import``."""
        data = asdict(self)
        rules = data.pop("rules")
        return {
            "rules": {
                "small_obstacles": rules["small_obstacles"],
                "close_gaps": rules["close_gaps"],
                "fans": rules["fans"],
                "resolve_range_m": rules["resolve_range_m"],
                "resolvable_m": round(rules["resolvable_m"], 4),
                "gap_px": self.gap_px,
                "robot_radius_m": rules["robot_radius_m"],
            },
            **{key: value for key, value in data.items() if key != "gap_px"},
        }


def gap_pixels(resolvable_m: float, resolution: float) -> int:
    """The widest slit, in whole pixels, narrower than ``resolvable_m``."""
    return max(0, math.ceil(resolvable_m / resolution - 1e-9) - 1)


def islands(cells: NDArray[np.uint8]) -> tuple[NDArray[np.int32], NDArray[np.bool_], NDArray[np.int64]]:
    """Pieces of non-free cells with free space all round: (labels (H, W), which labels are
    islands (count + 1,), their extents in pixels (count + 1,)). Label 0 is free space."""
    labels, count = ndimage.label(cells != FREE, structure=EIGHT)
    edge = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    is_island = np.ones(count + 1, bool)
    is_island[0] = False
    is_island[edge] = False
    extent = np.zeros(count + 1, np.int64)
    if count:
        rows, cols = np.nonzero(labels)
        which = labels[rows, cols]
        index = np.arange(1, count + 1)
        spans = [
            np.asarray(ndimage.maximum(axis, which, index)) - np.asarray(ndimage.minimum(axis, which, index)) + 1
            for axis in (rows, cols)
        ]
        extent[1:] = np.maximum(*spans)
    return labels, is_island, extent


def small_obstacles(cells: NDArray[np.uint8], rules: ImportRules, resolution: float) -> tuple[int, int, int]:
    """Rule 1 in place: (islands below the resolvable size, pixels removed, pixels grown)."""
    if rules.small_obstacles == "keep":
        return 0, 0, 0
    labels, is_island, extent = islands(cells)
    small = is_island & (extent * resolution < rules.resolvable_m - 1e-9)
    mask = small[labels]
    count = int(small.sum())
    if rules.small_obstacles == "remove":
        cells[mask] = FREE
        return count, int(mask.sum()), 0
    # grow: a one-pixel island becomes a square of side (2k + 1) pixels >= d
    k = max(0, math.ceil((rules.resolvable_m / resolution - 1.0) / 2.0 - 1e-9))
    grown = ndimage.binary_dilation(mask, structure=np.ones((2 * k + 1, 2 * k + 1), bool)) & (cells == FREE)
    cells[grown] = OCCUPIED
    return count, 0, int(grown.sum())


def close_gaps(cells: NDArray[np.uint8], gap_px: int) -> int:
    """Rule 2 in place: free cells in no all-free square of ``gap_px + 1`` become wall; how many."""
    if gap_px <= 0:
        return 0
    free = cells == FREE
    side = gap_px + 1
    opened = ndimage.binary_opening(np.pad(free, side), structure=np.ones((side, side), bool))[side:-side, side:-side]
    slits = free & ~opened
    cells[slits] = OCCUPIED
    return int(slits.sum())


def body_covered(free: NDArray[np.bool_], radius_px: float) -> NDArray[np.bool_]:
    """Cells under a robot body of ``radius_px`` centred where its centre may be: the centres of
    ``World.eroded`` (clearance = distance to the nearest non-free cell centre minus half a cell
    >= radius), each covering the cells nearer than ``radius_px + 0.5`` (all of them free)."""
    reach = radius_px + 0.5
    clearance = ndimage.distance_transform_edt(np.pad(free, 1))[1:-1, 1:-1]
    centres = free & (clearance >= reach - 1e-9)
    if not centres.any():
        return np.zeros_like(free)
    return ndimage.distance_transform_edt(~centres) < reach - 1e-9


def laser_fans(cells: NDArray[np.uint8], radius_px: float) -> int:
    """Rule 3 in place: free cells no robot body covers, in pieces touching unknown space or the
    map's edge, become unknown (wall); how many."""
    free = cells == FREE
    thin = free & ~body_covered(free, radius_px)
    if not thin.any():
        return 0
    unknown = np.pad(cells == UNKNOWN, 1, constant_values=True)
    near_unknown = ndimage.binary_dilation(unknown, structure=EIGHT)[1:-1, 1:-1]
    labels, count = ndimage.label(thin, structure=EIGHT)
    reaching = np.zeros(count + 1, bool)
    reaching[labels[thin & near_unknown]] = True
    reaching[0] = False
    fans = reaching[labels]
    cells[fans] = UNKNOWN
    return int(fans.sum())


def import_map(cells: NDArray[np.uint8], resolution: float, rules: ImportRules) -> tuple[NDArray[np.bool_], MapImport]:
    """The world's free space (H, W) of a map's cells (UNKNOWN / FREE / OCCUPIED, as
    ``navkit.raster.read_map_server`` gives them) under ``rules``, and what the rules changed."""
    raw_free = largest_component(cells == FREE)
    work = cells.copy()
    gap_px = gap_pixels(rules.resolvable_m, resolution) if rules.close_gaps else 0
    count, removed, grown = small_obstacles(work, rules, resolution)
    closed = close_gaps(work, gap_px)
    fans = laser_fans(work, rules.robot_radius_m / resolution) if rules.fans else 0
    cleaned = work == FREE
    free = largest_component(cleaned)
    report = MapImport(
        rules=rules,
        gap_px=gap_px,
        islands=count,
        removed_px=removed,
        grown_px=grown,
        closed_px=closed,
        fan_px=fans,
        detached_px=int(cleaned.sum() - free.sum()),
        free_px=int(free.sum()),
        raw_free_px=int(raw_free.sum()),
        changed_px=int(np.count_nonzero(free != raw_free)),
    )
    return free, report
