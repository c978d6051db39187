"""Shared by the ``tune_*.py`` scripts: generated scenes in the benchmark's two settings, and
mapping drives recorded once and replayed offline.

The tuning rule (BENCHMARKS.md, "Design choices: the tuning rule"): parameters are chosen on scenes from ``scenarios.generators``
with seeds disjoint from the benchmark's, never on a bundled benchmark scene (corridor_150m,
tiny, ...). ``generated_scenario`` refuses the benchmark's seeds.

Settings, as the benchmark defines them:

* ``precise``: exact wheel odometry, no lidar range noise (the scenario defaults);
* ``noisy``: wheel odometry with 2 % / 0.5°-per-metre random walks and 0.01 m lidar range noise.

A recorded drive is what ``runners.mapping.run_mapping`` feeds every system: the robot follows
the scenario's mapping route on its true pose (``runners.route.RouteDrive``), the simulator's
noise comes from the scenario seed's mapping stream, and each tick's ``Observation`` (stamp,
float32 points, odometry) is stored with the true pose, in an ``.npz`` under a cache folder
(``data/`` is gitignored).
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from navkit import geometry as se2
from navkit.files import atomic_write
from navkit.types import Observation
from runners.route import RouteDrive
from runners.sim import Simulator
from scenarios import Scenario, generators, hall
from scenarios.scenario import build_scenario
from scenarios.schema import parse_spec

#: seeds of the benchmark's own scenes and runs (the bundled scenarios' ``seed:`` values, and
#: 150): never used for tuning
BENCHMARK_SEEDS = frozenset({1, 7, 11, 12, 21, 150})

SETTINGS: dict[str, dict[str, Any]] = {
    "precise": {"odometry": {"noise": None}, "sensor": {"range_noise": 0.0}},
    "noisy": {
        "odometry": {"noise": {"translation": 0.02, "rotation_deg_per_m": 0.5}},
        "sensor": {"range_noise": 0.01},
    },
}

DEFAULT_CACHE = Path("data/tuning")


def generated_spec(kind: str, length: float, seed: int, setting: str, route_factor: float = 6.0) -> dict[str, Any]:
    """A scenario dict of a generated scene in one setting.

    kind: ``tree`` (``generators.corridor_tree``), ``ring`` (``generators.ring_building``, if
    that generator exists in this revision) or ``hall`` (``hall.hall_building``: ``length`` its long
    side, ``route_factor`` times its aisles' length).
    """
    if seed in BENCHMARK_SEEDS:
        raise SystemExit(f"seed {seed} is one of the benchmark's ({sorted(BENCHMARK_SEEDS)}): tune on other seeds")
    if setting not in SETTINGS:
        raise SystemExit(f"unknown setting {setting!r}: one of {sorted(SETTINGS)}")
    if kind == "tree":
        spec = generators.corridor_tree(length, seed, route_factor=route_factor, trials=1)
    elif kind == "ring":
        ring = getattr(generators, "ring_building", None)
        if ring is None:
            raise SystemExit("scenarios.generators has no ring_building in this revision")
        spec = ring(length, seed, route_factor=route_factor, trials=1)
    elif kind == "hall":
        spec = hall.hall_building(length, seed, route_factor=route_factor, trials=1)
    else:
        raise SystemExit(f"unknown scene kind {kind!r}: tree, ring or hall")
    return in_setting(spec, setting)


def in_setting(spec: dict[str, Any], setting: str) -> dict[str, Any]:
    """The scenario dict with the odometry and lidar noise of ``setting``."""
    if setting not in SETTINGS:
        raise SystemExit(f"unknown setting {setting!r}: one of {sorted(SETTINGS)}")
    spec = dict(spec)
    spec["name"] = f"{spec['name']}_{setting}"
    spec["description"] = f"{spec.get('description', '')}; tuning setting {setting}"
    spec["odometry"] = dict(SETTINGS[setting]["odometry"])
    spec["sensor"] = {**spec.get("sensor", {}), **SETTINGS[setting]["sensor"]}
    return spec


def file_scenario(path: Path, setting: str) -> tuple[Scenario, str]:
    """A scene written by ``generate_scene.py`` (any kind: aliased, SLAM-like, ...) in one setting,
    and its cache key; a bundled scenario or one with a benchmark seed is refused (the tuning rule)."""
    path = Path(path)
    bundled = Path(__file__).resolve().parents[1] / "scenarios" / "bundled"
    if bundled in path.resolve().parents:
        raise SystemExit(f"{path}: a bundled benchmark scene; tune on generated scenes (benchmarks/generate_scene.py)")
    text = path.read_text()
    spec = yaml.safe_load(text)
    if not isinstance(spec, dict) or spec.get("seed") in BENCHMARK_SEEDS:
        raise SystemExit(f"{path}: seed: {spec.get('seed') if isinstance(spec, dict) else None} is not a tuning seed")
    spec = in_setting(spec, setting)
    digest = hashlib.sha1(text.encode()).hexdigest()[:8]
    return build_scenario(parse_spec(spec, path), path, with_trials=False), f"{path.stem}_{digest}_{setting}"


def generated_scenario(kind: str, length: float, seed: int, setting: str, route_factor: float = 6.0) -> Scenario:
    """The resolved scenario (mapping route, no trials) of ``generated_spec``."""
    spec = generated_spec(kind, length, seed, setting, route_factor)
    origin = Path(f"<generated {spec['name']}>")
    return build_scenario(parse_spec(spec, origin), origin, with_trials=False)


def scene_key(kind: str, length: float, seed: int, setting: str, route_factor: float) -> str:
    return f"{kind}{int(round(length))}m_s{seed}_r{route_factor:g}_{setting}"


@dataclass
class Recording:
    """One mapping drive: per tick the observation and the true pose (scenario frame)."""

    stamps: NDArray[np.float64]  # (T,)
    odom: NDArray[np.float64]  # (T, 3) odometry frame
    true: NDArray[np.float64]  # (T, 3) scenario frame
    offsets: NDArray[np.int64]  # (T + 1,) into points
    points: NDArray[np.float32]  # (sum N, 3) robot frame
    meta: dict[str, Any]

    def __len__(self) -> int:
        return len(self.stamps)

    def observation(self, k: int) -> Observation:
        return Observation(
            stamp=float(self.stamps[k]), points=self.points[self.offsets[k] : self.offsets[k + 1]], odom=self.odom[k].copy()
        )

    def true_in_map(self, start: NDArray) -> NDArray[np.float64]:
        """(T, 3) true poses in the map frame (the frame of the drive's first pose, ``start``)."""
        return se2.between(np.asarray(start, dtype=np.float64)[None, :], self.true)

    def save(self, path: Path) -> None:
        buffer = io.BytesIO()
        np.savez(
            buffer,
            stamps=self.stamps,
            odom=self.odom,
            true=self.true,
            offsets=self.offsets,
            points=self.points,
            meta=np.array(json.dumps(self.meta)),
        )
        atomic_write(path, buffer.getvalue())

    @classmethod
    def load(cls, path: Path) -> Recording:
        with np.load(path) as data:
            return cls(data["stamps"], data["odom"], data["true"], data["offsets"], data["points"], json.loads(str(data["meta"])))


def record_drive(scenario: Scenario, seed: int, progress: bool = True) -> Recording:
    """Drive the scenario's mapping route as the mapping stage does (``runners.route.RouteDrive``),
    recording every tick; a ``RouteError`` if the route cannot be driven."""
    started = time.perf_counter()
    with Simulator(scenario, seed=seed) as sim:
        drive = RouteDrive(scenario, sim)
        stamps, odom, true, clouds = [], [], [], []
        next_report = 100.0
        for _ in drive.ticks():
            if progress and sim.travelled_m >= next_report:
                print(f"  {scenario.name}: {sim.travelled_m:.0f} / {scenario.route_length_m:.0f} m", flush=True)
                next_report += 100.0
            obs = sim.observe()
            stamps.append(obs.stamp)
            odom.append(obs.odom)
            true.append(sim.true_pose)
            clouds.append(obs.points)
        drive.check()
        collisions, travelled = sim.collisions, sim.travelled_m
    counts = np.array([len(c) for c in clouds], dtype=np.int64)
    meta = {
        "scenario": scenario.name,
        "sim_seed": seed,
        "route_length_m": round(scenario.route_length_m, 3),
        "travelled_m": round(travelled, 3),
        "scans": len(stamps),
        "collisions": collisions,
        "record_s": round(time.perf_counter() - started, 1),
        "route_start": [float(v) for v in scenario.route_start],
        **git_state(),
    }
    return Recording(
        np.asarray(stamps, dtype=np.float64),
        np.asarray(odom, dtype=np.float64).reshape(-1, 3),
        np.asarray(true, dtype=np.float64).reshape(-1, 3),
        np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        np.concatenate(clouds).astype(np.float32) if clouds else np.zeros((0, 3), np.float32),
        meta,
    )


def recording(
    cache: Path, kind: str, length: float, seed: int, setting: str, route_factor: float
) -> tuple[Scenario, Recording, str]:
    """The scene and its recorded mapping drive, from the cache or recorded now (and cached)."""
    scenario = generated_scenario(kind, length, seed, setting, route_factor)
    key = scene_key(kind, length, seed, setting, route_factor)
    return scenario, cached_drive(cache, scenario, key), key


def cached_drive(cache: Path, scenario: Scenario, key: str) -> Recording:
    """The scenario's recorded mapping drive, from the cache or recorded now (and cached)."""
    path = Path(cache) / "drives" / f"{key}.npz"
    if path.is_file():
        rec = Recording.load(path)
        revision = git_state()["git_revision"]
        if rec.meta.get("git_revision") != revision:
            print(f"note: {path.name} was recorded at {rec.meta.get('git_revision')}, the code is at {revision}", flush=True)
        return rec
    print(f"recording {key} ({scenario.route_length_m:.0f} m route) ...", flush=True)
    rec = record_drive(scenario, seed=int(scenario.spec.seed))
    rec.save(path)
    print(f"  {rec.meta['scans']} scans in {rec.meta['record_s']} s, {rec.meta['collisions']} collisions", flush=True)
    return rec


def scenes(args: argparse.Namespace) -> Iterator[tuple[str, Scenario, Recording, str]]:
    """(setting, scenario, recorded drive, key) of each scene ``replay_parser``'s arguments name:
    the ``--scene`` files if any, else ``--kind`` at each of ``--seeds``; each in every setting."""
    for setting in parse_list(args.settings):
        if args.scene:
            for file in args.scene:
                scenario, key = file_scenario(file, setting)
                yield setting, scenario, cached_drive(args.cache, scenario, key), key
        else:
            for seed in parse_list(args.seeds, int):
                yield setting, *recording(args.cache, args.kind, args.length, seed, setting, args.route_factor)


def git_state() -> dict[str, Any]:
    """The revision of the code that ran, and whether its tracked files differed from it."""
    try:
        revision = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True).stdout
        return {"git_revision": revision, "git_dirty": bool(dirty.strip())}
    except (OSError, subprocess.CalledProcessError):
        return {"git_revision": None, "git_dirty": None}


def parse_list(text: str, kind: type = str) -> list:
    return [kind(item) for item in text.split(",") if item.strip()]


def scene_arguments(parser: argparse.ArgumentParser, kind: str, length: float, seeds: str, settings: str) -> None:
    """The arguments naming the scenes a tuning script drives (read by ``scenes``): a generated
    kind at seeds, or scene files; the settings; the drives' cache."""
    parser.add_argument("--kind", default=kind, help="tree (corridor_tree), ring (ring_building) or hall (hall_building)")
    parser.add_argument("--length", type=float, default=length, help="m of corridor (hall: its long side)")
    parser.add_argument("--seeds", default=seeds, help="comma list; never the benchmark's")
    parser.add_argument("--settings", default=settings)
    parser.add_argument("--route-factor", type=float, default=6.0, help="mapping route length / corridor length")
    parser.add_argument(
        "--scene",
        type=Path,
        action="append",
        default=[],
        help="a scene file from benchmarks/generate_scene.py (any kind, its own route), instead of --kind/--seeds; repeatable",
    )
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE, help="recorded drives (and what scripts cache beside them)")


def replay_parser(description: str, kind: str, length: float, seeds: str, settings: str) -> argparse.ArgumentParser:
    """The arguments every replay over recorded drives takes: the scenes (``scene_arguments``),
    candidate configs (``NAME=YAML`` overrides, read by ``candidates``) and a JSON copy."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    scene_arguments(parser, kind, length, seeds, settings)
    parser.add_argument("--candidate", action="append", default=[], help="NAME=YAML overrides; 'default' always runs first")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    return parser


def candidates(items: list[str]) -> dict[str, dict[str, Any]]:
    """``--candidate NAME=YAML`` arguments as {name: overrides}, the defaults ("default") first."""
    out: dict[str, dict[str, Any]] = {"default": {}}
    for item in items:
        name, _, text = item.partition("=")
        out[name] = yaml.safe_load(text) or {}
    return out
