"""Localization in the graph of locations (Muravyev & Yakovlev, Sec. "Localization").

Two stages: place recognition picks the ``top_k`` vertices whose descriptors are nearest to the
current scan's; scan matching of 2D grids verifies each and gives the robot's pose in it. An
odometry hint (the robot's pose predicted from a vertex's stored odometry pose, valid while one
odometry frame lasts) seeds the matcher and gates candidates that drift cannot explain; without
hints (a fresh start, as at the beginning of a navigation trial) every candidate is matched
globally. No ground truth is involved anywhere.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from navkit.geometry import between
from navkit.scan_grid import GridConfig
from navtopo.graph import TopologicalGraph
from navtopo.scan_matching import MatchingConfig, MatchResult, PreparedGrid, match, prepare


class LocalizationConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    top_k: int = Field(5, ge=1, description="place-recognition candidates verified by scan matching (the paper: 5)")
    near_k: int = Field(3, ge=0, description="with an odometry hint, the vertices nearest by hint verified too")
    drift_base: float = Field(3.0, ge=0, description="hint gate: candidates farther than this (m) ...")
    drift_per_metre: float = Field(
        0.05, ge=0, description="... plus this share of the odometry travelled between them are skipped"
    )
    cache_size: int = Field(
        6,
        ge=1,
        description="prepared vertex grids kept in memory (an LRU cache: the current location, its neighbours and the "
        "candidates being verified; bounded, so that it does not grow with the map)",
    )


@dataclass(frozen=True)
class Localized:
    vertex: int
    pose: NDArray[np.float64]  # (3,) robot pose in the vertex's frame
    result: MatchResult


class VertexGrids:
    """Prepared (matchable) full grids of vertices, made on demand and kept in an LRU cache."""

    def __init__(self, graph: TopologicalGraph, grid_config: GridConfig, matching: MatchingConfig, size: int) -> None:
        self.graph = graph
        self.grid_config = grid_config
        self.matching = matching
        self.size = size
        self._cache: OrderedDict[int, PreparedGrid] = OrderedDict()

    def get(self, vertex: int) -> PreparedGrid:
        prepared = self._cache.get(vertex)
        if prepared is None:
            prepared = prepare(self.graph.vertices[vertex].grid.to_grid(), self.grid_config, self.matching)
            self._cache[vertex] = prepared
            if len(self._cache) > self.size:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(vertex)
        return prepared

    def forget(self, vertex: int) -> None:
        self._cache.pop(vertex, None)

    def clear(self) -> None:
        self._cache.clear()

    @property
    def nbytes(self) -> int:
        return sum(prepared.nbytes for prepared in self._cache.values())


class Localizer:
    def __init__(
        self,
        graph: TopologicalGraph,
        grids: VertexGrids,
        config: LocalizationConfig,
        matching: MatchingConfig,
        grid_config: GridConfig,
    ) -> None:
        self.graph = graph
        self.grids = grids
        self.config = config
        self.matching = matching
        self.grid_config = grid_config
        # judge every match by the thresholds without a guess (a start-up hypothesis among rivals)
        self.strict = False

    def verify(
        self,
        query: PreparedGrid,
        vertex: int,
        guess: NDArray[np.float64] | None = None,
        max_jump: float | None = None,
        strict: bool = False,
        min_wall_agreement: float | None = None,
        guess_tolerance: float | None = None,
    ) -> Localized | None:
        """Match the current grid against one vertex; the robot's pose in it, or None. ``strict``:
        see ``scan_matching.match``; ``min_wall_agreement``: the verdict's with a guess, if not the
        matcher's own; ``guess_tolerance``: feature matches kept within this of the guess (m), if
        not the matcher's ``guess_translation_tolerance``.

        With a guess, a match that shares little known area (below ``min_overlap``, the threshold
        without a guess) still says the place is right, but its pose is less sure than the guess
        (few walls in common fix the rotation poorly): the guess is kept as the pose."""
        matching = self.matching
        overrides: dict[str, float] = {}
        if min_wall_agreement is not None:
            overrides["min_wall_agreement"] = min_wall_agreement
        if guess_tolerance is not None:
            overrides["guess_translation_tolerance"] = guess_tolerance
        if overrides:
            matching = matching.model_copy(update=overrides)
        result = match(
            self.grids.get(vertex),
            query,
            initial_guess=guess,
            config=matching,
            grid_config=self.grid_config,
            strict=strict or self.strict,
        )
        if not result.accepted:
            return None
        if guess is not None and max_jump is not None and float(np.hypot(*(result.pose[:2] - guess[:2]))) > max_jump:
            return None
        if guess is not None and result.overlap < self.matching.min_overlap:
            return Localized(vertex, np.asarray(guess, dtype=np.float64).copy(), result)
        return Localized(vertex, result.pose, result)

    def localize(
        self,
        query: PreparedGrid,
        descriptor: NDArray[np.float32],
        exclude: set[int] | None = None,
        robot_hint: NDArray[np.float64] | None = None,
        hint_gate: dict[int, float] | None = None,
        top_k: int | None = None,
    ) -> list[Localized]:
        """Verified candidates among the ``top_k`` descriptor neighbours, best score first.

        robot_hint: the robot's pose in the odometry frame of the vertices' hints, if that frame
        is still the current one; then each candidate's hint gives a guess for the matcher and
        candidates farther than ``hint_gate[v]`` (m) from the hint are skipped, and the
        ``near_k`` vertices nearest by hint within their gates are verified too (odometry finds a
        place that place recognition ranks low). Where a gate is wider than the matcher's window
        around a guess (``guess_translation_tolerance``: drift over a long drive, a loop coming
        round), a candidate the hinted match refuses is matched again without the guess and kept
        if it lies within the gate (on a generated ring with noisy odometry, places mapped twice
        fell from 20 to 4 of the route's late locations: BENCHMARKS.md, "Design choices: edge
        measurements").
        top_k: how many descriptor neighbours to verify (default: the config's).
        """
        ids, _ = self.graph.nearest(descriptor, top_k or self.config.top_k)
        candidates = [int(v) for v in ids]
        if robot_hint is not None and self.config.near_k > 0 and len(self.graph):
            hints = np.array([v.pose_hint[:2] for v in self.graph.vertices])
            distance = np.hypot(*(hints - robot_hint[:2]).T)
            gates = np.array([(hint_gate or {}).get(v, np.inf) for v in range(len(hints))])
            near = [int(v) for v in np.argsort(distance) if distance[v] <= gates[v]][: self.config.near_k]
            candidates += [v for v in near if v not in candidates]
        found: list[Localized] = []
        for vertex in candidates:
            if exclude and vertex in exclude:
                continue
            guess, gate = None, None
            if robot_hint is not None:
                guess = between(self.graph.vertices[vertex].pose_hint, robot_hint)
                gate = (hint_gate or {}).get(vertex, np.inf)
                if float(np.hypot(guess[0], guess[1])) > gate:
                    continue
            # a hinted match may move the robot away from its hint by what drift explains, no more
            # recognising a place (not tracking one): the verdict's thresholds without a guess
            located = self.verify(query, vertex, guess, gate, strict=True)
            if located is None and guess is not None and gate is not None and gate > self.matching.guess_translation_tolerance:
                # the hint may be off by more than the features' window around a guess (drift over
                # a long drive, a loop coming round): search every pose, and keep the gate
                unguided = self.verify(query, vertex, None, strict=True)
                if unguided is not None and float(np.hypot(*(unguided.pose[:2] - guess[:2]))) <= gate:
                    located = unguided
            if located is not None:
                found.append(located)
        found.sort(key=lambda loc: -loc.result.score)
        return found
