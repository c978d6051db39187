"""Place-recognition scans from procedurally generated worlds, and descriptor training on them.

Worlds are ``scenarios.generators.corridor_tree`` corridor trees (dressed with niches, side
rooms, furniture and pillars), never the bundled benchmark scenarios. In each world the robot
is placed at poses along the scenario's mapping route (a skeleton tour that runs every
corridor out and back), and the PyBullet lidar scans from there; the scan depends on the pose
only, so placing is equivalent to driving and ~100x faster than stepping the kinematics.

* pass 0: every ``spacing_m`` along the route, on the route, facing along it;
* later passes: shifted by half a spacing along the route, up to ``lateral_jitter_m`` sideways
  (kept in the free space eroded by the robot radius), heading along the route turned by a
  uniform angle within ``yaw_jitter_deg`` (180: any heading).

Training uses every scan; evaluation on a held-out world uses pass 0 as the database and the
later passes as queries (``PlaceRecognitionDataset.database_and_queries``).

    python -m runners.place_recognition_data --descriptor minkloc3d --minutes 15
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from navtopo.place_recognition import (
    PlaceRecognitionDataset,
    TrainingConfig,
    TrainingProgress,
    evaluate_revisits,
    make_descriptor,
    train,
)
from runners.sim import Simulator
from scenarios import Scenario, bundled_names, load_scenario
from scenarios.generators import corridor_tree
from scenarios.scenario import build_scenario
from scenarios.schema import parse_spec


@dataclass
class ScanDataConfig:
    """Which worlds and which poses. World ``i`` is ``corridor_tree(length_i, seed + i)``."""

    worlds: int = 9
    seed: int = 1000
    corridor_length_m: tuple[float, float] = (80.0, 160.0)  # uniform per world
    passes: int = 2
    spacing_m: float = 0.5
    lateral_jitter_m: float = 0.3
    yaw_jitter_deg: float = 20.0


def generated_scenario(corridor_length_m: float, seed: int) -> Scenario:
    """A generated corridor tree as a resolved scenario (no trials); refuses bundled names."""
    data = corridor_tree(corridor_length_m, seed=seed, route_factor=1.0, name=f"pr_tree_s{seed}")
    if data["name"] in bundled_names():
        raise ValueError(f"{data['name']} is a bundled benchmark scenario: never train on it")
    spec = parse_spec(data, f"<generated {data['name']}>")
    return build_scenario(spec, Path(f"{data['name']}.yaml"), with_trials=False)


def route_poses(
    scenario: Scenario,
    spacing_m: float,
    offset_m: float = 0.0,
    lateral_jitter_m: float = 0.0,
    yaw_jitter_rad: float = 0.0,
    rng: np.random.Generator | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(P, 3) poses [x, y, yaw] every ``spacing_m`` of arc length along the mapping route, and
    (P,) their arc lengths (the distance driven to reach them)."""
    rng = rng or np.random.default_rng(0)
    route = scenario.route
    steps = np.diff(route, axis=0)
    lengths = np.linalg.norm(steps, axis=1)
    keep = lengths > 1e-9
    steps, lengths, starts = steps[keep], lengths[keep], route[:-1][keep]
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    stations = np.arange(offset_m, cumulative[-1], spacing_m)
    segment = np.clip(np.searchsorted(cumulative, stations, side="right") - 1, 0, len(steps) - 1)
    along = (stations - cumulative[segment]) / lengths[segment]
    xy = starts[segment] + steps[segment] * along[:, None]
    heading = np.arctan2(steps[segment, 1], steps[segment, 0])
    if lateral_jitter_m > 0:
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        shifted = xy + normal * rng.uniform(-lateral_jitter_m, lateral_jitter_m, (len(xy), 1))
        cells = scenario.world.to_cell(shifted)
        inside = scenario.world.inside(cells)
        ok = np.zeros(len(xy), dtype=bool)
        ok[inside] = scenario.passable[cells[inside, 0], cells[inside, 1]]
        xy = np.where(ok[:, None], shifted, xy)
    yaw = heading + rng.uniform(-yaw_jitter_rad, yaw_jitter_rad, len(xy))
    yaw = (yaw + np.pi) % (2.0 * np.pi) - np.pi
    return np.column_stack([xy, yaw]), stations


def record_world(scenario: Scenario, world_id: int, config: ScanDataConfig, rng: np.random.Generator) -> PlaceRecognitionDataset:
    """Scans of every pass through one world."""
    clouds, positions, sequences = [], [], []
    with Simulator(scenario, seed=int(rng.integers(2**31))) as sim:
        for sequence in range(config.passes):
            first = sequence == 0
            poses, _ = route_poses(
                scenario,
                config.spacing_m,
                offset_m=0.0 if first else config.spacing_m / 2.0,
                lateral_jitter_m=0.0 if first else config.lateral_jitter_m,
                yaw_jitter_rad=0.0 if first else np.radians(config.yaw_jitter_deg),
                rng=rng,
            )
            for pose in poses:
                clouds.append(sim.scan(pose))
                positions.append(pose[:2])
                sequences.append(sequence)
    count = len(clouds)
    return PlaceRecognitionDataset(clouds, np.array(positions), np.full(count, world_id), np.array(sequences))


def generate_scans(config: ScanDataConfig, progress: Callable[[str], None] | None = None) -> PlaceRecognitionDataset:
    """Scans of ``config.worlds`` generated worlds, world ids 0..worlds-1."""
    rng = np.random.default_rng(config.seed)
    parts = []
    for index in range(config.worlds):
        length = float(rng.uniform(*config.corridor_length_m))
        started = time.perf_counter()
        scenario = generated_scenario(length, config.seed + index)
        part = record_world(scenario, index, config, rng)
        parts.append(part)
        if progress is not None:
            progress(
                f"world {index + 1}/{config.worlds} ({scenario.name}, {length:.0f} m of corridor, "
                f"route {scenario.route_length_m:.0f} m): {len(part)} scans in "
                f"{time.perf_counter() - started:.0f} s"
            )
    return PlaceRecognitionDataset(
        [c for p in parts for c in p.clouds],
        np.concatenate([p.positions for p in parts]),
        np.concatenate([p.world_ids for p in parts]),
        np.concatenate([p.sequence_ids for p in parts]),
    )


def cached_scans(path: Path, config: ScanDataConfig, progress: Callable[[str], None] | None = None) -> PlaceRecognitionDataset:
    """``generate_scans`` once, then read from ``path`` (keyed by the config)."""
    key = path.with_suffix(".json")
    wanted = json.dumps(asdict(config), sort_keys=True)
    if path.exists() and key.exists() and key.read_text() == wanted:
        return PlaceRecognitionDataset.load(path)
    scans = generate_scans(config, progress)
    scans.save(path)
    key.write_text(wanted)
    return scans


def evaluate_scenario(
    scenario: Scenario, descriptors: list[str], spacing_m: float = 1.0, min_gap_m: float = 30.0
) -> dict[str, dict]:
    """Recall@1/@5 of each descriptor along a scenario's mapping route (3 m threshold).

    The robot is placed every ``spacing_m`` along the route facing along it; each scan queries
    the scans taken at least ``min_gap_m`` of driving earlier (``evaluate_revisits``). Evaluation
    only: bundled scenarios are fine here, never for training.
    """
    poses, travelled = route_poses(scenario, spacing_m)
    with Simulator(scenario) as sim:
        clouds = [sim.scan(pose) for pose in poses]
    results: dict[str, dict] = {}
    for name in descriptors:
        try:
            descriptor = make_descriptor(name)
        except FileNotFoundError as error:  # a learned descriptor without shipped weights
            results[name] = {"error": str(error)}
            continue
        results[name] = evaluate_revisits(descriptor, clouds, poses[:, :2], travelled, min_gap_m=min_gap_m)
    return results


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--descriptor", default="minkloc3d")
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--worlds", type=int, default=9)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--data-dir", type=Path, default=Path("data/place_recognition"))
    parser.add_argument("--out", type=Path, default=None, help="default: a new folder weights/<descriptor>-<time>")
    parser.add_argument("--eval", metavar="SCENARIO", help="only evaluate the shipped descriptors on SCENARIO")
    args = parser.parse_args(argv)
    if args.eval:
        if args.threads:
            torch.set_num_threads(args.threads)
        names = ["scan_context", "minkloc3d", "polar_bev"]
        print(json.dumps(evaluate_scenario(load_scenario(args.eval, with_trials=False), names), indent=2))
        return

    print(
        json.dumps(
            train_descriptor(
                args.descriptor,
                args.minutes,
                args.worlds,
                args.threads,
                args.data_dir,
                args.out or default_training_out(args.descriptor),
            ),
            indent=2,
            default=str,
        )
    )


def default_training_out(descriptor: str) -> Path:
    """A new folder for trained weights: never the package's shipped weights (tracked in git, and
    what every run loads); ship new weights by copying them there by hand."""
    return Path("weights") / f"{descriptor}-{time.strftime('%Y%m%d-%H%M%S')}"


def existing_weights(out: Path, descriptor: str) -> list[Path]:
    """Files a training into ``out`` would overwrite."""
    return [p for p in (out / f"{descriptor}.pt", out / f"{descriptor}.json") if p.exists()]


def train_descriptor(
    descriptor: str,
    minutes: float,
    worlds: int,
    threads: int | None,
    data_dir: Path,
    out: Path,
    say: Callable[[str], None] = print,
) -> dict:
    """Generate (or reuse cached) scans of generated worlds, train, write the weights into ``out``
    (refused where weights of ``descriptor`` already are); the summary."""
    if existing_weights(out, descriptor):
        raise FileExistsError(f"{out} already holds weights of {descriptor}; train into another folder")
    train_config = ScanDataConfig(worlds=worlds)
    held_out = ScanDataConfig(worlds=1, seed=9000, yaw_jitter_deg=180.0, spacing_m=1.0)
    data_dir.mkdir(parents=True, exist_ok=True)
    scans = cached_scans(data_dir / f"train_{worlds}.npz", train_config, say)
    validation = cached_scans(data_dir / "held_out.npz", held_out, say)
    say(f"training scans: {len(scans)} from {worlds} worlds; held out: {len(validation)}")

    last = [0.0]

    def report(p: TrainingProgress) -> None:
        if p.elapsed_s - last[0] >= 30.0:
            last[0] = p.elapsed_s
            say(f"step {p.step}  {p.elapsed_s / 60:.1f} min  loss {p.loss:.3f}  active {p.active_fraction:.2f}  lr {p.lr:.1e}")

    config = TrainingConfig(
        descriptor=descriptor,
        max_seconds=minutes * 60.0,
        threads=threads,
        output_dir=str(out),
    )
    metrics = train(scans, config, progress=report, validation=validation)
    metrics["data"] = {"train": asdict(train_config), "held_out": asdict(held_out)}
    # the statistics ship with the weights: file names only, no machine paths
    metrics["weights_file"] = Path(metrics.pop("weights_path")).name
    weights_path = str(Path(metrics["stats_path"]).with_name(metrics["weights_file"]))
    metrics["stats_file"] = Path(metrics.pop("stats_path")).name
    metrics.get("config", {}).pop("output_dir", None)
    Path(weights_path).with_name(metrics["stats_file"]).write_text(json.dumps(metrics, indent=2, default=str) + "\n")
    summary = {k: metrics[k] for k in ("steps", "epochs", "seconds", "ms_per_step", "loss_last")}
    make_descriptor(descriptor, weights=weights_path)  # loads back
    return {**summary, "validation": metrics.get("validation"), "weights": weights_path}


if __name__ == "__main__":
    main()
