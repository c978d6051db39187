"""A resolved scenario: the validated file, its ground-truth worlds (mapping stage, and navigation
stage with ``world.changes`` in place), mapping route and trials."""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from scenarios.gaps import GapGauge
from scenarios.route_space import RouteSpace, polyline_length, route_space, waypoint_route
from scenarios.routes import auto_route
from scenarios.schema import GOAL_TOLERANCE_M, TRIAL_MARGIN_M, ScenarioError, ScenarioSpec, TrialsGenerate, read_spec
from scenarios.trials import Trial, below_margin, generate_trials, make_trial
from scenarios.world import World, build_world, corridor_polygon, rectangle, with_changes

BUNDLED_DIR = Path(__file__).resolve().parent / "bundled"


@dataclass
class Scenario:
    """``world`` is the mapping stage's ground truth; ``navigation_world`` the navigation stage's:
    the same object unless the file has ``world.changes`` (boxes that appear only when navigating),
    then a world with those boxes in its free space. Trials (their ``shortest_m``) are resolved on
    the navigation world: efficiency is measured against the path that is really available."""

    spec: ScenarioSpec
    path: Path
    world: World
    route: NDArray[np.float64]  # (K, 2) mapping route polyline, scenario frame
    trials: list[Trial] = field(default_factory=list)
    navigation_world: World = None  # type: ignore[assignment]  # default: ``world`` itself
    notes: list[str] = field(default_factory=list)  # things a user should know (one line each), not errors

    def __post_init__(self) -> None:
        if self.navigation_world is None:
            self.navigation_world = with_changes(self.world)

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def route_length_m(self) -> float:
        return polyline_length(self.route)

    @cached_property
    def passable(self) -> NDArray[np.bool_]:
        """Cells where the robot's centre may be: free space eroded by the robot radius."""
        return self.world.eroded(self.spec.robot.radius)

    @cached_property
    def navigation_passable(self) -> NDArray[np.bool_]:
        """``passable`` of the navigation world (changes in place); ``passable`` if there are none."""
        if self.navigation_world is self.world:
            return self.passable
        return self.navigation_world.eroded(self.spec.robot.radius)

    @property
    def trial_margin_m(self) -> float:
        """The room (m) beyond the robot radius a trial's narrowest gap must leave on each side:
        ``trials.generate.margin``, or ``TRIAL_MARGIN_M`` for listed trials."""
        trials = self.spec.trials
        return trials.generate.margin if isinstance(trials, TrialsGenerate) else TRIAL_MARGIN_M

    @property
    def route_start(self) -> NDArray[np.float64]:
        """(3,) the pose the mapping run starts at: the first route point, facing along the route."""
        d = self.route[1] - self.route[0]
        return np.array([self.route[0, 0], self.route[0, 1], np.arctan2(d[1], d[0])])

    def summary(self) -> dict:
        distances = [t.shortest_m for t in self.trials]
        gaps = [t.narrowest_gap_m for t in self.trials if t.narrowest_gap_m is not None]
        corridor_length = sum(
            float(np.linalg.norm(np.diff(np.asarray(c.points, float), axis=0), axis=1).sum()) for c in self.spec.world.corridors
        )
        xmin, ymin, xmax, ymax = self.world.bounds
        return {
            "name": self.name,
            "description": self.spec.description,
            "file": str(self.path),
            "corridor_length_m": round(corridor_length, 3),
            "free_area_m2": round(self.world.free_area_m2, 3),
            "route_length_m": round(self.route_length_m, 3),
            "trial_count": len(self.trials),
            "trial_distance_mean_m": round(float(np.mean(distances)), 3) if distances else None,
            "trial_distance_min_m": round(float(np.min(distances)), 3) if distances else None,
            "trial_distance_max_m": round(float(np.max(distances)), 3) if distances else None,
            "trial_margin_m": self.trial_margin_m,
            "trial_narrowest_gap_m": round(float(np.min(gaps)), 3) if gaps else None,
            "trials_narrow": sum(t.narrow for t in self.trials),
            "bounds_m": [round(v, 3) for v in (xmin, ymin, xmax, ymax)],
            "obstacles": len(self.spec.world.obstacles),
            "changes": len(self.spec.world.changes),
            "raster": {"resolution": self.world.resolution, "shape": list(self.world.shape)},
            "sensor_rays": self.spec.sensor.rays,
            **({"map_import": self.world.map_import.as_dict()} if self.world.map_import is not None else {}),
        }


def bundled_names() -> list[str]:
    return sorted(p.stem for p in BUNDLED_DIR.glob("*.yaml"))


def resolve_path(name_or_path: str | Path) -> Path:
    """A bundled scenario name, or a path to a YAML file. A bare name (no folder, no .yaml) is the
    bundled scenario's even where a local folder has that name (``--out tiny`` made one); a local
    file of that name is a clash, refused in one line (``./tiny`` names the file)."""
    text = str(name_or_path)
    candidate = Path(name_or_path)
    bundled = BUNDLED_DIR / f"{text}.yaml"
    bare = "/" not in text and os.sep not in text and candidate.suffix not in (".yaml", ".yml")
    if bare and bundled.is_file():
        if candidate.is_file():
            raise ScenarioError(text, "", f"names both a bundled scenario and the file here; write ./{text} for the file")
        return bundled
    if candidate.suffix in (".yaml", ".yml") or candidate.exists():
        return candidate
    raise ScenarioError(
        str(name_or_path), "", f"no such scenario file, nor a bundled scenario (bundled: {', '.join(bundled_names())})"
    )


def _check_point(
    scenario_file: Path, key: str, xy, world: World, passable: NDArray[np.bool_], radius: float, note: str = ""
) -> None:
    cell = world.to_cell(np.asarray(xy, float))
    if not world.inside(cell):
        xmin, ymin, xmax, ymax = world.bounds
        raise ScenarioError(
            scenario_file,
            key,
            f"{list(xy)} is outside the map (x {xmin:.2f} .. {xmax:.2f}, y {ymin:.2f} .. {ymax:.2f})",
        )
    if not passable[tuple(cell)]:
        clearance = world.clearance_at(np.asarray(xy, float))
        where = ("inside a wall or obstacle" if clearance <= 0 else f"only {clearance:.2f} m from a wall") + note
        raise ScenarioError(scenario_file, key, f"{list(xy)} is {where}; the robot (radius {radius} m) needs more room")


MIN_ROUTE_M = 1.0  # a mapping route shorter than this maps nothing
REROUTE_NOTE_FACTOR, REROUTE_NOTE_M = 1.2, 1.0  # a waypoint leg this much longer than straight is reported


def reroute_notes(world: World, waypoints: NDArray, route: NDArray, file: Path) -> list[str]:
    """One note per waypoint leg the planner had to take round walls (longer than the straight
    line by a factor and a margin): a user who drew a leg through a wall learns it was re-routed."""
    waypoints = np.asarray(waypoints, float)
    notes = []
    # the route passes every waypoint in order: split it there
    cursor = 0
    for i in range(1, len(waypoints)):
        hits = np.flatnonzero(np.all(np.isclose(route[cursor:], waypoints[i], atol=1e-9), axis=1))
        end = cursor + int(hits[0]) if len(hits) else len(route) - 1
        driven = polyline_length(route[cursor : end + 1])
        straight = float(np.linalg.norm(waypoints[i] - waypoints[i - 1]))
        if driven > REROUTE_NOTE_FACTOR * straight + REROUTE_NOTE_M:
            notes.append(
                f"{file}: mapping_route.waypoints.{i}: the leg from waypoint {i - 1} is {straight:.1f} m straight but "
                f"{driven:.1f} m through free space: it was re-routed round walls"
            )
        cursor = end
    return notes


MIN_PIECE_M2 = 0.25  # smaller free pieces (raster slivers around obstacles) are ignored


def check_connected(spec: ScenarioSpec, path: Path, world: World) -> None:
    """Free space must be one connected piece: name the shape of any piece cut off from the rest."""
    labels, count = ndimage.label(world.free, structure=np.ones((3, 3), bool))
    if count <= 1:
        return
    sizes = np.bincount(labels.ravel()) * world.resolution**2
    sizes[0] = 0.0
    main = int(np.argmax(sizes))  # the rest of the world: where the route starts, else the largest piece
    if spec.mapping_route.waypoints:
        cell = world.to_cell(np.asarray(spec.mapping_route.waypoints[0], float))
        if world.inside(cell) and labels[tuple(cell)] > 0:
            main = int(labels[tuple(cell)])
    for piece in np.nonzero(sizes >= MIN_PIECE_M2)[0]:
        if piece == main:
            continue
        cell = np.argwhere(labels == piece)[0]
        x, y = world.to_world(cell)
        key = "world"
        if spec.world.map is None:
            from shapely.geometry import Point

            point = Point(x, y)
            for kind, shapes, make in (
                ("corridors", spec.world.corridors, lambda c: corridor_polygon(c.points, c.width)),
                ("rooms", spec.world.rooms, lambda r: rectangle(r.center, r.size, r.yaw)),
            ):
                for i, shape in enumerate(shapes):
                    if make(shape).buffer(world.resolution).contains(point):
                        key = f"world.{kind}.{i}"
                        break
                if key != "world":
                    break
        raise ScenarioError(
            path, key, f"free space near ({x:.2f}, {y:.2f}) ({sizes[piece]:.1f} m²) is not connected to the rest of the world"
        )


def build_scenario(spec: ScenarioSpec, path: Path, with_trials: bool = True) -> Scenario:
    """The scenario of a validated file: its world, mapping route and (``with_trials``) trials;
    ``ScenarioError`` naming the key of anything that cannot be resolved."""
    rng = np.random.default_rng(spec.seed)
    try:
        world = build_world(spec.world, path, spec.robot, spec.sensor)
    except ValueError as exc:
        raise ScenarioError(path, "world", str(exc)) from None
    check_connected(spec, path, world)
    space = route_space(world, spec.robot.radius)
    route, notes = _mapping_route(spec, path, world, space, rng)
    if polyline_length(route) < MIN_ROUTE_M:
        raise ScenarioError(
            path, "mapping_route", f"the route is {polyline_length(route):.2f} m long: at least {MIN_ROUTE_M} m is needed to map"
        )
    scenario = Scenario(spec=spec, path=path, world=world, route=route, notes=notes)
    scenario.__dict__["passable"] = space.passable
    if with_trials:
        _resolve_trials(scenario, space, rng)
    return scenario


def _mapping_route(
    spec: ScenarioSpec, path: Path, world: World, space: RouteSpace, rng: np.random.Generator
) -> tuple[NDArray[np.float64], list[str]]:
    """The mapping route (its waypoints joined, or generated with a seed drawn from ``rng``) and
    the notes on it."""
    radius = spec.robot.radius
    route_spec = spec.mapping_route
    if route_spec.waypoints is not None:
        for i, point in enumerate(route_spec.waypoints):
            _check_point(path, f"mapping_route.waypoints.{i}", point, world, space.passable, radius)
        route, bad = waypoint_route(world, space.passable, np.asarray(route_spec.waypoints, float), space.roomy, space.fit)
        if route is None:
            raise ScenarioError(
                path,
                f"mapping_route.waypoints.{bad}",
                f"not connected to waypoint {bad - 1} through free space wide enough for the robot",
            )
        return route, reroute_notes(world, np.asarray(route_spec.waypoints, float), route, path)
    assert route_spec.auto is not None
    try:
        return auto_route(world, space, route_spec.auto.min_length, np.random.default_rng(rng.integers(2**32))), []
    except ValueError as exc:
        raise ScenarioError(path, "mapping_route.auto", str(exc)) from None


def _resolve_trials(scenario: Scenario, space: RouteSpace, rng: np.random.Generator) -> None:
    """The scenario's trials, resolved in the navigation stage's world (changes in place),
    reachable from where the route runs (or, if a change stands there, from the largest piece
    left); generated ones with a seed drawn from ``rng``."""
    spec, path, world = scenario.spec, scenario.path, scenario.world
    nav = scenario.navigation_world
    nav_space = space if nav is world else route_space(nav, spec.robot.radius)
    nav_passable = nav_space.passable
    scenario.__dict__["navigation_passable"] = nav_passable
    start_cell = tuple(nav.to_cell(scenario.route[0]))
    labels, _ = ndimage.label(nav_passable, structure=np.ones((3, 3), bool))
    if nav_passable[start_cell]:
        reachable = labels == labels[start_cell]
    else:
        reachable = labels == int(np.argmax(np.bincount(labels.ravel())[1:])) + 1 if labels.max() else nav_passable
    trial_rng = np.random.default_rng(rng.integers(2**32))
    where = " (with world.changes in place)" if nav is not world else ""
    if isinstance(spec.trials, TrialsGenerate):
        gen = spec.trials.generate
        # generated ends are joined to the route through space the robot fits in with a margin
        # (no trial behind a gap it could only scrape through)
        fit_labels, _ = ndimage.label(nav_space.fit, structure=np.ones((3, 3), bool))
        fit_reachable = fit_labels == fit_labels[start_cell] if nav_space.fit[start_cell] else reachable
        try:
            scenario.trials = generate_trials(
                nav,
                reachable,
                gen.count,
                gen.min_distance,
                trial_rng,
                gen.max_distance,
                within=fit_reachable,
                margin=gen.margin,
                radius=spec.robot.radius,
            )
        except ValueError as exc:
            raise ScenarioError(path, "trials.generate", f"{exc}{where}") from None
    else:
        scenario.trials = _listed_trials(scenario, nav_passable, reachable, where)


def _listed_trials(scenario: Scenario, nav_passable: NDArray[np.bool_], reachable: NDArray[np.bool_], where: str) -> list[Trial]:
    """The trials the file lists, each end checked in the mapping and the navigation world, and
    its shortest path's narrowest gap against the margin (refused below it, unless ``allow_narrow``)."""
    spec, path, world, nav = scenario.spec, scenario.path, scenario.world, scenario.navigation_world
    assert not isinstance(spec.trials, TrialsGenerate)
    radius = spec.robot.radius
    passable = scenario.passable
    gauge = GapGauge(nav, radius)
    trials = []
    for i, t in enumerate(spec.trials):
        apart = float(np.hypot(t.goal[0] - t.start[0], t.goal[1] - t.start[1]))
        if apart <= GOAL_TOLERANCE_M:
            raise ScenarioError(
                path,
                f"trials.{i}.goal",
                f"{list(t.goal)} is {apart:.2f} m from the start: within the {GOAL_TOLERANCE_M} m goal tolerance, "
                "the trial would succeed without moving",
            )
        for end, xy in (("start", t.start[:2]), ("goal", t.goal)):
            _check_point(path, f"trials.{i}.{end}", xy, world, passable, radius)
            if nav is not world:
                _check_point(path, f"trials.{i}.{end}", xy, nav, nav_passable, radius, where)
        trial = make_trial(nav, reachable, i, t.start, t.goal, gauge)
        if trial is None:
            raise ScenarioError(
                path,
                f"trials.{i}",
                "start and goal are not connected to the mapping route through free space wide enough for the robot" + where,
            )
        if below_margin(trial, scenario.trial_margin_m):
            if not t.allow_narrow:
                raise ScenarioError(path, f"trials.{i}", narrow_reason(trial, scenario.trial_margin_m, radius) + where)
            trial = replace(trial, narrow=True)
        trials.append(trial)
    return trials


def narrow_reason(trial: Trial, margin: float, radius: float) -> str:
    """Why a listed trial is refused: its narrowest gap, where, and the two ways out."""
    gap = float(trial.narrowest_gap_m or 0.0)
    at = f" at ({trial.gap_at[0]:.2f}, {trial.gap_at[1]:.2f})" if trial.gap_at is not None else ""
    return (
        f"its shortest path's narrowest gap {gap:.3f} m{at} (a passage {2 * (radius + gap):.2f} m wide) is below the "
        f"margin {margin:g} m the robot (radius {radius:g} m) needs on each side; move the trial, or give it "
        "'allow_narrow: true' to run it marked narrow"
    )


def load_scenario(name_or_path: str | Path, with_trials: bool = True) -> Scenario:
    """Load, validate and resolve a scenario; raises ``ScenarioError`` with one clear line."""
    path = resolve_path(name_or_path)
    spec = read_spec(path)
    return build_scenario(spec, path, with_trials=with_trials)
