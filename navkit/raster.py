"""Rasters: the cell values every grid uses, the one grid frame, and ROS map_server files.

Cell values (``uint8``): ``UNKNOWN`` 0, ``FREE`` 1, ``OCCUPIED`` 2 — NavTopo's location grids, the
metric baseline's global grid and the maps they save and load.

**The grid frame** (``GridFrame``): ``cells[row, col]``, row ↔ y, col ↔ x, both growing with the
index. ``origin`` is the metric position of the outer (lower-left) corner of cell ``origin_cell``
(``(0, 0)`` for a map; the central cell for a location grid centred on its observation point), so

* the cell containing a point ``(x, y)`` is
  ``(floor((y - origin_y) / res) + origin_row, floor((x - origin_x) / res) + origin_col)``;
* the centre of cell ``(r, c)`` is ``origin + ((c - origin_col + 0.5) * res, (r - origin_row + 0.5) * res)``.

Every cell <-> metre conversion of the benchmark is one of these two, so a point lands in the same
cell whichever system, planner or report asks.

**ROS map_server files** (``read_map_server`` / ``write_map_server``): a YAML file (``image``,
``resolution``, ``origin: [x, y, yaw]``, ``negate``, ``occupied_thresh``, ``free_thresh``, ``mode``)
beside an image (PGM or PNG; 8 or 16 bit; colour is averaged to grey) whose top row is the largest
y. A pixel's occupancy is ``p = (max - value) / max`` (``value / max`` if ``negate``); as map_server
classifies it, ``p > occupied_thresh`` is ``OCCUPIED``, ``p < free_thresh`` is ``FREE``, anything
else ``UNKNOWN``; in ``raw`` mode a value of 0 is ``FREE``, values up to 100 are occupancy
percentages and above 100 ``UNKNOWN``. A rotated origin (yaw ≠ 0) is refused. Every problem is one
``MapFileError`` naming the file, the key and the reason.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from navkit.errors import FileProblem
from navkit.files import atomic_write

UNKNOWN = 0
FREE = 1
OCCUPIED = 2

# map_server's trinary pixel values and default thresholds
PIXEL_OCCUPIED, PIXEL_FREE, PIXEL_UNKNOWN = 0, 254, 205
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.196


@dataclass(frozen=True)
class GridFrame:
    """Where a raster lies: ``origin`` (2,) [x, y] is the outer corner of cell ``origin_cell``
    ``(row, col)``; ``resolution`` metres per cell. See the module docstring for the formulas."""

    origin: NDArray[np.float64]
    resolution: float
    origin_cell: tuple[int, int] = (0, 0)

    @classmethod
    def centred(cls, size: int, resolution: float) -> GridFrame:
        """A square grid of ``size`` cells a side centred on its own origin (a location grid): the
        point (0, 0) is the corner shared by its four central cells."""
        half = size // 2
        return cls(np.zeros(2), resolution, (half, half))

    def shifted(self, rows: int, cols: int) -> GridFrame:
        """The frame of the window of this raster that starts at cell ``(rows, cols)``."""
        return GridFrame(self.origin, self.resolution, (self.origin_cell[0] - rows, self.origin_cell[1] - cols))

    def to_cell(self, xy: ArrayLike) -> NDArray[np.int64]:
        """Points (2,) or (..., 2) [x, y] -> the cells [row, col] containing them (no bounds check)."""
        xy = np.asarray(xy, dtype=np.float64)
        cells = np.empty(xy.shape, np.int64)  # filled in place: np.stack costs more than the sums here
        cells[..., 0] = np.floor((xy[..., 1] - self.origin[1]) / self.resolution) + self.origin_cell[0]
        cells[..., 1] = np.floor((xy[..., 0] - self.origin[0]) / self.resolution) + self.origin_cell[1]
        return cells

    def to_world(self, cells: ArrayLike) -> NDArray[np.float64]:
        """Cells (2,) or (..., 2) [row, col] -> their centres [x, y]."""
        cells = np.asarray(cells, dtype=np.float64)
        xy = np.empty(cells.shape, np.float64)
        xy[..., 0] = self.origin[0] + (cells[..., 1] - self.origin_cell[1] + 0.5) * self.resolution
        xy[..., 1] = self.origin[1] + (cells[..., 0] - self.origin_cell[0] + 0.5) * self.resolution
        return xy

    def centres(self, mask: NDArray[np.bool_]) -> NDArray[np.float64]:
        """(N, 2) [x, y] centres of the set cells of a ``[row, col]`` mask, in row-major order."""
        rows, cols = np.nonzero(mask)
        return self.to_world(np.stack([rows, cols], axis=-1))

    def extent(self, shape: tuple[int, ...]) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of a raster of ``shape`` (H, W) in this frame, metres."""
        x0, y0 = self.to_world(np.zeros(2)) - 0.5 * self.resolution
        return (float(x0), float(y0), float(x0 + shape[1] * self.resolution), float(y0 + shape[0] * self.resolution))


TILE_SHIFT = 4
TILE = 1 << TILE_SHIFT  # cells a side of a ``TiledRaster``'s tile


class TiledRaster(NamedTuple):
    """A raster kept as those of its ``TILE`` x ``TILE`` tiles that hold a value other than ``fill``:
    most of a building's map lies far from every wall or out of reach, where a distance saturates or
    a field is unreached. ``tile_of[r >> TILE_SHIFT, c >> TILE_SHIFT]`` names a cell's tile (0: the one
    shared tile of ``fill``), ``tiles[k, r % TILE, c % TILE]`` holds its value. Lossless:
    ``dense()`` gives the raster back, ``at`` reads it where the raster would be read."""

    tile_of: NDArray[np.int32]
    tiles: NDArray[Any]  # (K + 1, TILE, TILE); tiles[0] is all ``fill``
    shape: tuple[int, int]

    @classmethod
    def of(cls, dense: NDArray[Any], fill: Any) -> TiledRaster:
        height, width = dense.shape
        rows, cols = -(-height // TILE), -(-width // TILE)
        padded = np.full((rows * TILE, cols * TILE), fill, dtype=dense.dtype)
        padded[:height, :width] = dense
        blocks = padded.reshape(rows, TILE, cols, TILE).swapaxes(1, 2)
        live = (blocks != padded.dtype.type(fill)).any(axis=(2, 3))
        index = np.zeros((rows, cols), np.int32)
        index[live] = np.arange(1, int(live.sum()) + 1, dtype=np.int32)
        tiles = np.empty((int(live.sum()) + 1, TILE, TILE), dtype=dense.dtype)
        tiles[0] = fill
        tiles[1:] = blocks[live]
        return cls(index, tiles, (height, width))

    @property
    def fill(self) -> Any:
        return self.tiles[0, 0, 0]

    @property
    def dtype(self) -> np.dtype[Any]:
        return self.tiles.dtype

    def at(self, rows: NDArray[np.integer], cols: NDArray[np.integer]) -> NDArray[Any]:
        """The values at cells (rows, cols), integer arrays of one shape, every cell on the raster."""
        return self.tiles[self.tile_of[rows >> TILE_SHIFT, cols >> TILE_SHIFT], rows & (TILE - 1), cols & (TILE - 1)]

    def dense(self) -> NDArray[Any]:
        rows, cols = self.tile_of.shape
        whole = self.tiles[self.tile_of].swapaxes(1, 2).reshape(rows * TILE, cols * TILE)
        return np.ascontiguousarray(whole[: self.shape[0], : self.shape[1]])

    @property
    def nbytes(self) -> int:
        return int(self.tile_of.nbytes + self.tiles.nbytes)


def largest_component(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The largest 8-connected piece of ``mask`` (all of it if it has one piece or none)."""
    from scipy import ndimage

    labels, count = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if count <= 1:
        return mask
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels == int(np.argmax(sizes))


def inside(cells: ArrayLike, shape: tuple[int, ...]) -> NDArray[np.bool_]:
    """Which cells (..., 2) [row, col] lie in a raster of ``shape`` (H, W)."""
    cells = np.asarray(cells)
    return (cells[..., 0] >= 0) & (cells[..., 0] < shape[0]) & (cells[..., 1] >= 0) & (cells[..., 1] < shape[1])


# ---------------------------------------------------------------------------------------------
# ROS map_server files


class MapFileError(FileProblem, ValueError):
    """A map_server map that cannot be read: ``file: key: reason``."""


@dataclass
class MapServerMap:
    """A map_server map as read: ``cells`` (H, W) uint8 UNKNOWN / FREE / OCCUPIED with row 0 the
    lowest y, placed by ``frame``; ``meta`` is the YAML as written (extra keys included)."""

    cells: NDArray[np.uint8]
    frame: GridFrame
    meta: dict[str, Any] = field(default_factory=dict)
    image_path: Path | None = None


def _number(path: Path, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MapFileError(path, key, f"must be a finite number (got {value!r})")
    return float(value)


def _header(path: Path, meta: Any) -> tuple[GridFrame, str, bool, float, float]:
    """The YAML's placement and classification: (frame, mode, negate, occupied_thresh, free_thresh)."""
    if not isinstance(meta, dict):
        raise MapFileError(path, "", "not a map_server YAML mapping")
    for required in ("image", "resolution", "origin"):
        if required not in meta:
            raise MapFileError(path, required, "required key is missing")
    mode = meta.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise MapFileError(path, "mode", f"unknown mode {mode!r}")
    origin = meta["origin"]
    if not (isinstance(origin, list) and len(origin) == 3):
        raise MapFileError(path, "origin", "must be [x, y, yaw]")
    origin = [_number(path, f"origin.{i}", v) for i, v in enumerate(origin)]
    if abs(origin[2]) > 1e-9:
        raise MapFileError(path, "origin", "a rotated map origin (yaw != 0) is not supported")
    resolution = _number(path, "resolution", meta["resolution"])
    if resolution <= 0:
        raise MapFileError(path, "resolution", f"must be > 0 (got {resolution})")
    negate = meta.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise MapFileError(path, "negate", f"must be 0 or 1 (got {negate!r})")
    defaults = {"free_thresh": FREE_THRESH, "occupied_thresh": OCCUPIED_THRESH}  # map_server's
    thresholds = {key: _number(path, key, meta.get(key, default)) for key, default in defaults.items()}
    for key, value in thresholds.items():
        if not 0.0 <= value <= 1.0:
            raise MapFileError(path, key, f"must be between 0 and 1, a share of full intensity (got {value})")
    if thresholds["free_thresh"] >= thresholds["occupied_thresh"]:
        raise MapFileError(
            path, "free_thresh", f"{thresholds['free_thresh']} is not below occupied_thresh {thresholds['occupied_thresh']}"
        )
    frame = GridFrame(np.array(origin[:2]), resolution)
    return frame, mode, bool(negate), thresholds["occupied_thresh"], thresholds["free_thresh"]


def image_size(path: Path) -> tuple[int, int] | None:
    """(width, height) of an image from its header, without decoding it; None if unreadable."""
    from PIL import Image

    limit = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = None  # the caller checks the size, with a reason
    try:
        with Image.open(path) as image:
            return image.size
    except Exception:  # noqa: BLE001 - any file Pillow cannot identify
        return None
    finally:
        Image.MAX_IMAGE_PIXELS = limit


def read_image(path: Path) -> NDArray | None:
    """The image as stored (depth and channels), None for a file OpenCV cannot decode, without
    OpenCV's own lines on stderr (a truncated PGM prints three): the caller says why. Decoded from
    its bytes: ``cv2.imread`` of a path that is not UTF-8 crashes the process."""
    logging = cv2.utils.logging
    level = logging.getLogLevel()
    logging.setLogLevel(logging.LOG_LEVEL_SILENT)
    try:
        data = np.fromfile(path, np.uint8)
        return cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    finally:
        logging.setLogLevel(level)


def _pgm_maxval(data: bytes) -> int | None:
    """The maxval of a PGM (P2 or P5) header, None for anything else: its pixels are shares of it."""
    if data[:2] not in (b"P2", b"P5"):
        return None
    tokens: list[bytes] = []
    pos = 2
    while len(tokens) < 3 and pos < len(data):  # width, height, maxval; skipping comments
        if data[pos : pos + 1].isspace():
            pos += 1
        elif data[pos : pos + 1] == b"#":
            end = data.find(b"\n", pos)
            pos = len(data) if end < 0 else end + 1
        else:
            end = pos
            while end < len(data) and not data[end : end + 1].isspace():
                end += 1
            tokens.append(data[pos:end])
            pos = end
    return int(tokens[2]) if len(tokens) == 3 and tokens[2].isdigit() and int(tokens[2]) > 0 else None


def full_scale(path: Path, image: NDArray) -> float:
    """The pixel value of full intensity: a PGM's maxval, else 65535 for 16 bit and 255 for 8 bit."""
    with open(path, "rb") as f:
        maxval = _pgm_maxval(f.read(512))
    if maxval is not None:
        return float(maxval)
    return 65535.0 if image.dtype == np.uint16 else 255.0


def classify(
    image: NDArray, scale: float, mode: str, negate: bool, occupied_thresh: float, free_thresh: float
) -> NDArray[np.uint8]:
    """(H, W) UNKNOWN / FREE / OCCUPIED of map_server pixels (image order kept), by the module's
    rule; ``scale`` is the value of full intensity."""
    if image.ndim == 3:
        image = image[..., :3].mean(axis=2)
    values = image.astype(np.float64)
    cells = np.full(values.shape, UNKNOWN, np.uint8)
    if mode == "raw":
        cells[(values > occupied_thresh * 100.0) & (values <= 100.0)] = OCCUPIED
        cells[values == 0] = FREE
        return cells
    occupancy = values / scale if negate else (scale - values) / scale
    cells[occupancy > occupied_thresh] = OCCUPIED
    cells[occupancy < free_thresh] = FREE
    return cells


def _read_yaml(path: Path) -> Any:
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise MapFileError(path, "", f"not a readable YAML file ({' '.join(str(exc).split())})") from None


def read_map_server(
    yaml_path: str | Path,
    check_size: Callable[[tuple[int, int], float, Path], None] | None = None,
    read_yaml: Callable[[Path], Any] | None = None,
) -> MapServerMap:
    """Read a map_server map: ``MapFileError`` naming the file, the key and the reason on any problem.

    check_size: called with the image's (rows, cols), the resolution and the image's path before it
    is decoded (the size from its header) and after; a ``ValueError`` it raises becomes the error of
    the ``image`` key (a map too large to load).
    read_yaml: how to read the YAML file (default: ``yaml.safe_load``; a scenario reads it strictly).
    """
    path = Path(yaml_path)
    if path.is_dir():
        raise MapFileError(path, "", "is a folder, not a map_server YAML file")
    if not path.is_file():
        raise MapFileError(path, "", "map file not found")
    meta = (read_yaml or _read_yaml)(path)
    frame, mode, negate, occupied_thresh, free_thresh = _header(path, meta)
    image_path = (path.parent / str(meta["image"])).resolve()
    if image_path.is_dir():
        raise MapFileError(path, "image", f"{meta['image']} is a folder, not a map image")
    if not image_path.is_file():
        raise MapFileError(path, "image", f"map image {image_path.name} not found next to {path.name}")
    try:
        size = image_size(image_path)  # None: a format Pillow does not read
        if size is not None and check_size is not None:
            check_size((size[1], size[0]), frame.resolution, image_path)
        image = read_image(image_path)
        if image is None or image.size == 0:
            raise MapFileError(path, "image", f"cannot decode map image {image_path.name}")
        if check_size is not None:
            check_size(image.shape[:2], frame.resolution, image_path)
    except MapFileError:
        raise
    except ValueError as exc:
        raise MapFileError(path, "image", str(exc)) from None
    cells = classify(image, full_scale(image_path, image), mode, negate, occupied_thresh, free_thresh)
    return MapServerMap(np.ascontiguousarray(cells[::-1]), frame, meta, image_path)


def trinary_image(cells: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """map_server trinary pixels of UNKNOWN / FREE / OCCUPIED cells (same row order)."""
    image = np.full(cells.shape, PIXEL_UNKNOWN, np.uint8)
    image[cells == FREE] = PIXEL_FREE
    image[cells == OCCUPIED] = PIXEL_OCCUPIED
    return image


def write_map_server(
    yaml_path: str | Path,
    pixels: NDArray[np.uint8],
    frame: GridFrame,
    *,
    image_format: str = "png",
    mode: str | None = "trinary",
    thresholds: tuple[float, float] = (OCCUPIED_THRESH, FREE_THRESH),
    header: dict[str, Any] | None = None,
    extra: dict[str, Any] | None = None,
    comment: str = "",
    yaml_style: dict[str, Any] | None = None,
) -> Path:
    """Write a map_server map: the image ``<yaml stem>.<image_format>`` and the YAML; returns the
    YAML's path. Both atomically (``navkit.files``), so a reader sees the old map or the new one.

    pixels: (H, W) uint8 map_server pixel values with row 0 the lowest y (``trinary_image`` of a
    grid's cells, or values of the caller's own, named in ``extra``); written top row first.
    frame: the raster's placement (``origin_cell`` (0, 0)). PNG is lossless and what NavTopo's
    grids use too, so both systems' maps on disk compare like for like; ``pgm`` writes binary P5
    with ``comment`` in its header. YAML keys: ``header``'s first, then ``image``, ``mode`` (unless
    None), ``resolution``, ``origin``, ``negate``, ``occupied_thresh``, ``free_thresh``, then ``extra``'s.
    """
    yaml_path = Path(yaml_path)
    if image_format not in ("png", "pgm"):
        raise ValueError(f"image_format must be png or pgm, not {image_format!r}")
    if frame.origin_cell != (0, 0):
        raise ValueError("a map_server map's origin is the corner of its cell (0, 0)")
    image_path = yaml_path.with_suffix(f".{image_format}")
    rows_down = np.ascontiguousarray(np.flipud(np.asarray(pixels, dtype=np.uint8)))
    if image_format == "png":
        ok, data = cv2.imencode(".png", rows_down)
        if not ok:
            raise ValueError(f"could not encode {image_path.name} as PNG")
        atomic_write(image_path, data.tobytes())
    else:
        height, width = rows_down.shape
        note = f"# {comment}\n" if comment else ""
        atomic_write(image_path, f"P5\n{note}{width} {height}\n255\n".encode("ascii") + rows_down.tobytes())
    meta: dict[str, Any] = {**(header or {}), "image": image_path.name}
    if mode is not None:
        meta["mode"] = mode
    meta.update(
        {
            "resolution": float(frame.resolution),
            "origin": [float(frame.origin[0]), float(frame.origin[1]), 0.0],
            "negate": 0,
            "occupied_thresh": thresholds[0],
            "free_thresh": thresholds[1],
            **(extra or {}),
        }
    )
    atomic_write(yaml_path, yaml.safe_dump(meta, sort_keys=False, **(yaml_style or {})).encode())
    return yaml_path
