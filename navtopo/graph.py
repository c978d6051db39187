"""The topological graph of NavTopo: locations and the relative poses between them.

Muravyev & Yakovlev, Sec. "Graph Structure": a vertex is a location ``v = (grid_v, desc_v)`` —
here with its creation stamp and the odometry pose at creation (a hint for drift-gated
localization, never a global position); an edge ``e = (u, v, T_uv)`` stores the pose of v's
observation point in u's frame (``navkit.geometry.between``), and its inverse for the way back.
Dijkstra weighs an edge by its length: the way between the two observation points measured on
their grids when mapping ends (``set_edge_length``: round a wall corner, through a door), else the
length of its translation.

On disk a graph is a folder: ``graph.json`` (format, vertices, edges), ``grids/<id>.png`` (one
lossless PNG per vertex grid) and ``descriptors.npy`` ((V, D) float32). An edge is ``[u, v, x, y, yaw]``, and its measured length
after them when it has one (readers of the five numbers alone still read it). ``load`` refuses a
corrupt or partial folder with one ``GraphFormatError`` line naming the file, key and reason.
"""

from __future__ import annotations

import heapq
import io
import json
import math
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from navkit.errors import BenchError
from navkit.files import atomic_write
from navkit.geometry import chain, inverse
from navtopo.local_grid import CroppedGrid, decode_png, encode_png

FORMAT = "navtopo-graph/1"
EDGE_BYTES = 2 * 8 + 3 * 8  # neighbour id + owner id (int64) and the relative pose (3 float64)
LENGTH_BYTES = 8  # an edge's measured length (float64), kept once for both directions


class GraphFormatError(BenchError, ValueError):
    """A saved graph that cannot be loaded; ``str(error)`` is the one line for a user. An input
    refused (``BenchError``, exit code 2), and a ``ValueError`` for callers that catch those."""


@dataclass
class Vertex:
    grid: CroppedGrid
    pose_hint: NDArray[np.float64]  # (3,) odometry pose at creation, odometry frame
    stamp: float
    odometer: float | None = None  # metres of odometry travelled before it was made (None: not recorded)
    # (3,) lidar-odometry pose at creation, odometry frame (None: not recorded; navtopo.graph_poses)
    lidar_hint: NDArray[np.float64] | None = None


class TopologicalGraph:
    """Vertices with grids and descriptors, edges with relative poses (both directions)."""

    def __init__(self, descriptor_dim: int) -> None:
        self.descriptor_dim = int(descriptor_dim)
        self.vertices: list[Vertex] = []
        self._descriptors = np.zeros((0, self.descriptor_dim), dtype=np.float32)
        self._adjacency: list[dict[int, NDArray[np.float64]]] = []
        self._lengths: dict[tuple[int, int], float] = {}  # (u, v), u < v: measured ways (``set_edge_length``)
        self._changes = 0  # edges added or removed so far: ``path_poses``' last answer holds until it moves
        self._last_path: tuple[tuple[int, ...], int, NDArray[np.float64]] | None = None

    # -- structure -------------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.vertices)

    @property
    def descriptors(self) -> NDArray[np.float32]:
        return self._descriptors[: len(self.vertices)]

    def add_vertex(
        self, grid: CroppedGrid, descriptor: ArrayLike, pose_hint: ArrayLike, stamp: float, odometer: float | None = None
    ) -> int:
        descriptor = np.asarray(descriptor, dtype=np.float32).reshape(-1)
        if descriptor.shape != (self.descriptor_dim,):
            raise ValueError(f"descriptor of shape {descriptor.shape}, expected ({self.descriptor_dim},)")
        index = len(self.vertices)
        if index == len(self._descriptors):  # grow the descriptor matrix geometrically
            grown = np.zeros((max(16, 2 * index), self.descriptor_dim), dtype=np.float32)
            grown[:index] = self._descriptors[:index]
            self._descriptors = grown
        self._descriptors[index] = descriptor
        self.vertices.append(
            Vertex(
                grid, np.asarray(pose_hint, dtype=np.float64).copy(), float(stamp), None if odometer is None else float(odometer)
            )
        )
        self._adjacency.append({})
        return index

    def add_edge(self, u: int, v: int, pose_uv: ArrayLike) -> None:
        """Connect u and v; ``pose_uv`` is v's observation point in u's frame."""
        if u == v:
            raise ValueError("no self-loops")
        pose_uv = np.asarray(pose_uv, dtype=np.float64).copy()
        self._adjacency[u][v] = pose_uv
        self._adjacency[v][u] = inverse(pose_uv)
        self._lengths.pop((min(u, v), max(u, v)), None)  # a new pose: the old measure no longer holds
        self._changes += 1

    def remove_edge(self, u: int, v: int) -> None:
        self._adjacency[u].pop(v, None)
        self._adjacency[v].pop(u, None)
        self._lengths.pop((min(u, v), max(u, v)), None)
        self._changes += 1

    def set_edge_length(self, u: int, v: int, metres: float) -> None:
        """The edge's length as the robot drives it (the way measured on the grids; never below the
        straight line): Dijkstra's weight from now on."""
        if not self.has_edge(u, v):
            raise KeyError(f"no edge ({u}, {v})")
        pose = self._adjacency[u][v]
        self._lengths[(min(u, v), max(u, v))] = max(float(metres), math.hypot(pose[0], pose[1]))

    def clear_edge_lengths(self) -> None:
        """Every edge weighed by its translation again, as before mapping's end measured them."""
        self._lengths.clear()

    def edge_length(self, u: int, v: int) -> float:
        """Dijkstra's weight of the edge: its measured length, else its translation's."""
        measured = self._lengths.get((min(u, v), max(u, v)))
        if measured is not None:
            return measured
        pose = self._adjacency[u][v]
        return math.hypot(pose[0], pose[1])

    def measured_edge(self, u: int, v: int) -> bool:
        return (min(u, v), max(u, v)) in self._lengths

    def has_edge(self, u: int, v: int) -> bool:
        return v in self._adjacency[u]

    def edge(self, u: int, v: int) -> NDArray[np.float64]:
        """T_uv: the pose of v's observation point in u's frame."""
        return self._adjacency[u][v].copy()

    def neighbours(self, u: int) -> list[tuple[int, NDArray[np.float64]]]:
        return [(v, pose.copy()) for v, pose in self._adjacency[u].items()]

    def edges(self) -> list[tuple[int, int, NDArray[np.float64]]]:
        """Each undirected edge once, as (u, v, T_uv) with u < v."""
        return [(u, v, pose.copy()) for u, adj in enumerate(self._adjacency) for v, pose in adj.items() if u < v]

    @property
    def edge_count(self) -> int:
        return sum(len(adj) for adj in self._adjacency) // 2

    # -- search ----------------------------------------------------------------------------------

    def dijkstra(self, source: int, removed: Collection[frozenset[int]] = ()) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Distances (edge lengths: ``edge_length``) from ``source`` to every vertex and the predecessors (each
        vertex's next one on the way back to ``source``), over the edges but those in ``removed``
        (``frozenset((u, v))``: edges found impassable during a trial)."""
        n = len(self.vertices)
        dist = [math.inf] * n  # plain floats: a search of a few hundred vertices, no numpy per edge
        prev = [-1] * n
        dist[source] = 0.0
        heap = [(0.0, source)]
        lengths = self._lengths
        while heap:
            d, u = heapq.heappop(heap)
            if d > dist[u]:
                continue
            for v, pose in self._adjacency[u].items():
                if removed and frozenset((u, v)) in removed:
                    continue
                measured = lengths.get((u, v) if u < v else (v, u)) if lengths else None
                nd = d + (measured if measured is not None else math.hypot(pose[0], pose[1]))
                if nd < dist[v]:
                    dist[v] = nd
                    prev[v] = u
                    heapq.heappush(heap, (nd, v))
        return np.array(dist, dtype=np.float64), np.array(prev, dtype=np.int64)

    def shortest_path(self, source: int, target: int) -> tuple[list[int] | None, float]:
        dist, prev = self.dijkstra(source)
        if not np.isfinite(dist[target]):
            return None, float("inf")
        path = [target]
        while path[-1] != source:
            path.append(int(prev[path[-1]]))
        return path[::-1], float(dist[target])

    def path_poses(self, path: list[int]) -> NDArray[np.float64]:
        """(len(path), 3) each vertex of ``path``'s observation point in the first one's frame,
        composed along the edges. The last path's answer is kept until an edge changes: navigation
        asks for its route's at every replan and every step toward the goal."""
        key = tuple(int(v) for v in path)
        last = self._last_path
        if last is not None and last[:2] == (key, self._changes):
            poses = last[2]
        else:
            # composed afresh, never from the last path's rest: the same poses to the last bit (a
            # noisy trial whose pose hung on a match at the margin ended elsewhere on a difference
            # of 1e-16 m)
            poses = chain([self._adjacency[u][v] for u, v in zip(key[:-1], key[1:], strict=True)])
        self._last_path = (key, self._changes, poses)
        return poses.copy()

    def path_pose(self, path: list[int]) -> NDArray[np.float64]:
        """The last vertex of ``path`` in the first one's frame (``path_poses``' last row)."""
        return self.path_poses(path)[-1]

    def nearest(self, descriptor: ArrayLike, k: int) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        """The k vertices whose descriptors are nearest (Euclidean) to ``descriptor``."""
        n = len(self.vertices)
        if n == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.float32)
        query = np.asarray(descriptor, dtype=np.float32).reshape(1, -1)
        distances = np.linalg.norm(self.descriptors - query, axis=1)
        k = min(k, n)
        order = np.argpartition(distances, k - 1)[:k]
        order = order[np.argsort(distances[order])]
        return order.astype(np.int64), distances[order].astype(np.float32)

    # -- memory ----------------------------------------------------------------------------------

    @property
    def nbytes(self) -> int:
        """Exact bytes of the map's data: grids, descriptors, pose hints (odometry and lidar), stamps,
        odometers, edges and their measured lengths."""
        n = len(self.vertices)
        grids = sum(v.grid.nbytes for v in self.vertices)
        odometers = 8 * sum(1 for v in self.vertices if v.odometer is not None)
        lidar_hints = 3 * 8 * sum(1 for v in self.vertices if v.lidar_hint is not None)
        return int(
            grids
            + self.descriptors.nbytes
            + n * 3 * 8
            + n * 8
            + odometers
            + lidar_hints
            + 2 * self.edge_count * EDGE_BYTES
            + len(self._lengths) * LENGTH_BYTES
        )

    # -- files -----------------------------------------------------------------------------------

    def save(self, directory: Path, extra: dict[str, Any] | None = None) -> None:
        """Write the folder (atomically per file; graph.json last, so a partial folder is refused)."""
        directory = Path(directory)
        (directory / "grids").mkdir(parents=True, exist_ok=True)
        for i, vertex in enumerate(self.vertices):
            atomic_write(directory / "grids" / f"{i:06d}.png", encode_png(vertex.grid.cells) if vertex.grid.cells.size else b"")
        buffer = io.BytesIO()
        np.save(buffer, self.descriptors)
        atomic_write(directory / "descriptors.npy", buffer.getvalue())
        data = {
            "format": FORMAT,
            "descriptor_dim": self.descriptor_dim,
            "vertices": [
                {
                    "id": i,
                    "stamp": v.stamp,
                    "pose_hint": [float(x) for x in v.pose_hint],
                    **({"odometer": v.odometer} if v.odometer is not None else {}),
                    **({"lidar_hint": [float(x) for x in v.lidar_hint]} if v.lidar_hint is not None else {}),
                    "grid": {
                        "file": f"grids/{i:06d}.png",
                        "row0": v.grid.row0,
                        "col0": v.grid.col0,
                        "size": v.grid.size,
                        "shape": list(v.grid.cells.shape),
                    },
                }
                for i, v in enumerate(self.vertices)
            ],
            "edges": [
                [u, v, *[float(x) for x in pose], *([self._lengths[(u, v)]] if (u, v) in self._lengths else [])]
                for u, v, pose in self.edges()
            ],
            **(extra or {}),
        }
        atomic_write(directory / "graph.json", (json.dumps(data, indent=1) + "\n").encode())

    @classmethod
    def load(cls, directory: Path) -> tuple[TopologicalGraph, dict[str, Any]]:
        """The graph and the extra keys saved with it; ``GraphFormatError`` on a bad folder."""
        directory = Path(directory)
        index = directory / "graph.json"
        data, dim, vertices, edges = _read_index(index)
        descriptors = _read_descriptors(directory / "descriptors.npy", len(vertices), dim)
        graph = cls(dim)
        for i, entry in enumerate(vertices):
            try:
                _add_vertex(graph, directory, index, i, entry, descriptors[i])
            except GraphFormatError:
                raise
            except (KeyError, TypeError, ValueError) as exc:
                raise GraphFormatError(f"{index}: vertices.{i}: bad entry ({exc})") from None
        for j, edge in enumerate(edges):
            try:
                u, v = int(edge[0]), int(edge[1])
                if not (0 <= u < len(graph) and 0 <= v < len(graph)):
                    raise ValueError(f"vertex id out of range ({u}, {v})")
                graph.add_edge(u, v, np.asarray(edge[2:5], float))
                if len(edge) > 5:
                    length = float(edge[5])
                    if not (math.isfinite(length) and length >= 0):
                        raise ValueError(f"length {edge[5]!r} is not a finite length")
                    graph.set_edge_length(u, v, length)
            except (TypeError, ValueError, IndexError) as exc:
                raise GraphFormatError(f"{index}: edges.{j}: bad edge ({exc})") from None
        extra = {k: v for k, v in data.items() if k not in ("format", "descriptor_dim", "vertices", "edges")}
        return graph, extra


# -- loading, one part of the folder at a time ------------------------------------------------------


def _read_index(index: Path) -> tuple[dict[str, Any], int, list, list]:
    """``graph.json``: (its data, the descriptor dimension, the vertex entries, the edge entries)."""
    if not index.is_file():
        raise GraphFormatError(f"{index}: missing (not a NavTopo graph folder, or a partial save)")
    try:
        data = json.loads(index.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise GraphFormatError(f"{index}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise GraphFormatError(
            f"{index}: format: expected {FORMAT!r}, got {data.get('format') if isinstance(data, dict) else None!r}"
        )
    try:
        dim = int(data["descriptor_dim"])
        vertices, edges = list(data["vertices"]), list(data["edges"])
    except (KeyError, TypeError, ValueError) as exc:
        raise GraphFormatError(f"{index}: {exc}: required key missing or of the wrong type") from None
    return data, dim, vertices, edges


def _read_descriptors(path: Path, count: int, dim: int) -> NDArray:
    """``descriptors.npy``: (count, dim) as ``graph.json`` says."""
    try:
        descriptors = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise GraphFormatError(f"{path}: cannot read ({exc})") from None
    if descriptors.shape != (count, dim):
        raise GraphFormatError(f"{path}: shape {descriptors.shape}, expected ({count}, {dim}) from graph.json")
    return descriptors


def _read_grid(directory: Path, index: Path, key: str, grid_entry: dict[str, Any]) -> CroppedGrid:
    """A vertex's grid from its PNG (none is written for a grid with no known cell)."""
    png = directory / grid_entry["file"]
    shape = tuple(grid_entry["shape"])
    if shape == (0, 0):
        cells = np.zeros((0, 0), np.uint8)
    else:
        try:
            cells = decode_png(png.read_bytes())
        except FileNotFoundError:
            raise GraphFormatError(f"{png}: missing ({key} of {index})") from None
        except ValueError as exc:
            raise GraphFormatError(f"{png}: corrupt grid image ({exc})") from None
        if cells.shape != shape:
            raise GraphFormatError(f"{png}: grid of shape {cells.shape}, expected {shape} from {index}")
    return CroppedGrid(cells, int(grid_entry["row0"]), int(grid_entry["col0"]), int(grid_entry["size"]))


def _add_vertex(
    graph: TopologicalGraph, directory: Path, index: Path, i: int, entry: dict[str, Any], descriptor: NDArray
) -> None:
    """Vertex ``i`` of ``graph.json`` into ``graph``; a bad entry raises KeyError, TypeError or ValueError
    (the caller names it), a bad grid file ``GraphFormatError``."""
    grid = _read_grid(directory, index, f"vertices.{i}", entry["grid"])
    odometer = entry.get("odometer")
    graph.add_vertex(
        grid,
        descriptor,
        np.asarray(entry["pose_hint"], float),
        float(entry["stamp"]),
        None if odometer is None else float(odometer),
    )
    if entry.get("lidar_hint") is not None:
        try:
            lidar_hint = np.asarray(entry["lidar_hint"], float)
        except (TypeError, ValueError):
            lidar_hint = np.zeros(0)
        if lidar_hint.shape != (3,) or not np.isfinite(lidar_hint).all():
            raise ValueError(f"lidar_hint: expected 3 finite numbers, got {entry['lidar_hint']!r}")
        graph.vertices[-1].lidar_hint = lidar_hint
