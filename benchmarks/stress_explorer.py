r"""Drive NavTopo's start-up ``Explorer`` alone (no map, no hypothesis) from many start poses of a
scenario and count collisions: the exploring moves a start-up makes when it has no hypothesis, or
when driving by one gets nowhere. Start poses are drawn at random in the ground-truth free space
(the robot's radius plus ``--margin`` from every obstacle), with the scenario's trial starts first.

    .venv/bin/python benchmarks/stress_explorer.py SCENE.yaml [--starts 20] [--seconds 40] [--seed 0]
    .venv/bin/python benchmarks/stress_explorer.py SCENE.yaml --run RESULTS [--starts 40] [--only 4 24] [--trace]

Prints one line a start (collisions, metres driven, exploring moves, moves given up) and a total;
``--trace`` prints the ticks before each collision. With ``--run`` (a results folder of this scene
with NavTopo's map) each start runs the whole start-up toward a random goal until it commits, and
the commitment is judged against the truth by the run's anchors (right within 0.5 m, else WRONG);
``--trace`` then prints every tick with the live hypotheses and their true errors. ``--only``
replays chosen starts of the same draw. For generated scenes (docs/NOTES.md, "Tuning rule"): never
a bundled benchmark scene.
"""

from __future__ import annotations

import argparse
import sys
from collections import deque
from pathlib import Path

import numpy as np

from navkit import geometry as se2
from navkit.scan import obstacle_points
from navtopo.system import NavTopo, NavTopoConfig
from runners.protocol import apply_setting, context_for
from runners.sim import Simulator
from runners.systems import get_system
from scenarios import load_scenario


def arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene", type=Path)
    parser.add_argument("--starts", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=40.0, help="simulated seconds of exploring per start")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--margin", type=float, default=0.05, help="m beyond the radius a start keeps from obstacles")
    parser.add_argument(
        "--near", type=float, default=None, help="random starts at most this far (m) beyond the margin: near walls"
    )
    parser.add_argument("--setting", default="precise")
    parser.add_argument("--config", type=Path, default=None, help="YAML of NavTopo config keys over the defaults")
    parser.add_argument("--trace", action="store_true")
    parser.add_argument("--only", type=int, nargs="*", default=None, help="run only these starts (their indices)")
    parser.add_argument(
        "--run",
        type=Path,
        default=None,
        help="a results folder of this scene with NavTopo's saved map: drive the whole start-up (hypotheses, "
        "tentative drives, exploring) toward a random goal until it commits, instead of the Explorer alone",
    )
    return parser


def start_poses(scenario, count: int, margin: float, rng: np.random.Generator, near: float | None = None) -> list[np.ndarray]:
    world = scenario.navigation_world
    radius = scenario.spec.robot.radius
    poses = [np.asarray(t.start, dtype=np.float64) for t in scenario.trials][:count] if near is None else []
    room = world.clearance >= radius + margin
    if near is not None:
        room &= world.clearance <= radius + margin + near
    cells = np.argwhere(room)
    while len(poses) < count:
        xy = world.to_world(cells[rng.integers(len(cells))][None])[0]
        poses.append(np.array([xy[0], xy[1], rng.uniform(-np.pi, np.pi)]))
    return poses


def hypotheses_seen(nav, anchors, truth: np.ndarray) -> str:
    """The live start-up hypotheses as vVERTEX:sSUPPORT:pPLACES:ERRORm, the error judged by the anchors."""
    seen = []
    for h in nav.startup.hypotheses:
        anchor = anchors.poses.get(round(float(nav.graph.vertices[h.vertex].stamp), 6))
        off = np.hypot(*(se2.compose(anchor, h.pose)[:2] - truth[:2])) if anchor is not None else np.nan
        seen.append(f"v{h.vertex}:s{h.support}:p{len(h.places)}:c{h.contradicted}:{off:.1f}m")
    startup = nav.startup
    return f"looks={startup.looks} far(dropped={startup.far_dropped},refused={startup.far_refused}) [{' '.join(seen)}]"


def drive(args, sim, system, anchors) -> tuple[int, float]:
    """One start: the Explorer alone (no ``--run``), or the whole start-up until it commits or ends;
    (collisions, metres driven). ``--trace`` prints the ticks (before a collision; with ``--run``, all)."""
    nav, explorer = system.navigator, system.navigator.explorer
    world, radius, grid = sim.scenario.navigation_world, sim.scenario.spec.robot.radius, system.config.grid
    odometer, last = 0.0, None
    collisions, driven = 0, 0.0
    ticks: deque[str] = deque(maxlen=12)
    while sim.time < args.seconds:
        obs = sim.observe()
        if last is not None:
            odometer += float(np.hypot(*se2.between(last, obs.odom)[:2]))
        last = np.asarray(obs.odom, dtype=np.float64).copy()
        if args.run is None:
            explorer.record(obs.odom)
            if not explorer.under_way(odometer):
                explorer.begin(obs.stamp, odometer)
            command = explorer.step(obs, nav.counters)
        else:
            command = system.step(obs)
            if nav.localized or nav.status.state.value != "active":
                break
        mode = "explore" if explorer.move is not None else "drive"
        if anchors is not None and args.trace:
            mode += " " + hypotheses_seen(nav, anchors, sim.true_pose)
        truth = sim.true_pose
        near = obstacle_points(obs.points, grid)
        nearest = float(np.hypot(near[:, 0], near[:, 1]).min()) if len(near) else np.inf
        ticks.append(
            f"  t={obs.stamp:5.1f} true=({truth[0]:7.2f},{truth[1]:7.2f},{np.degrees(truth[2]):6.1f}) "
            f"clear={world.clearance_at(truth[:2]) - radius:5.2f} scan_min={nearest:4.2f} "
            f"cmd=({command.linear:4.2f},{command.angular:5.2f}) {mode} moves={nav.counters['explore_moves']} "
            f"blocked={nav.counters['explore_blocked']}"
        )
        if args.trace and args.run is not None:
            print(ticks[-1])  # the whole start-up, tick by tick
        result = sim.step(command)
        driven += result.travelled_m
        if result.collided:
            collisions += 1
            if args.trace:
                print("\n".join(ticks))
                print(f"  COLLISION at {np.round(sim.true_pose, 3)}")
            break
    return collisions, driven


def main() -> int:
    args = arguments().parse_args()
    scenario = apply_setting(load_scenario(args.scene), args.setting)
    entry = get_system("navtopo")
    overrides: dict = {}
    if args.config is not None:
        import yaml

        overrides = yaml.safe_load(args.config.read_text()) or {}
    config = NavTopoConfig.model_validate(overrides)
    rng = np.random.default_rng(args.seed)
    total_collisions = total_m = 0.0
    goals = start_poses(scenario, 2 * args.starts, args.margin, rng)[args.starts :]
    with Simulator(scenario, seed=scenario.spec.seed, with_changes=True) as sim:
        context = context_for(entry, scenario, sim)
        system = (
            NavTopo(config, None, mapping=False, context=context)
            if args.run is None
            else NavTopo.load(args.run / "maps" / "navtopo", config, context)
        )
        nav = system.navigator
        anchors = None
        if args.run is not None:
            import json

            from runners.anchors import Anchors

            anchors = Anchors.from_rows(json.loads((args.run / "mapping" / "navtopo.json").read_text())["anchors"])
        verdicts: list[str] = []
        starts = 0
        for k, start in enumerate(start_poses(scenario, args.starts, args.margin, rng, args.near)):
            if args.only is not None and k not in args.only:
                continue
            sim.reset(start, stream=(99, k))
            system.reset()
            if args.run is not None:
                goal = se2.transform_points(se2.inverse(scenario.route_start), goals[k][None, :2])[0]
                system.set_goal(goal)
            collisions, driven = drive(args, sim, system, anchors)
            total_collisions += collisions
            verdict = ""
            if anchors is not None and nav.localizations:
                first = nav.localizations[0]
                estimate = anchors.locate((first.vertex_stamp, first.pose))
                error = float(np.hypot(*(estimate[:2] - sim.true_pose[:2]))) if estimate is not None else np.inf
                verdict = f", {'right' if error <= 0.5 else 'WRONG'} ({error:.2f} m)"
                verdicts.append("right" if error <= 0.5 else "wrong")
            total_m += driven
            starts += 1
            ending = "localized" if nav.localized else nav.status.reason or "active"
            print(
                f"start {k} ({start[0]:.2f}, {start[1]:.2f}, {np.degrees(start[2]):.0f}): collisions {collisions}, "
                f"{driven:.1f} m, moves {nav.counters['explore_moves']}, blocked {nav.counters['explore_blocked']}, "
                f"tentative blocked {nav.counters['tentative_blocked']}, {ending} after {sim.time:.1f} s{verdict}",
                flush=True,
            )
    print(f"total: {int(total_collisions)} collisions in {starts} starts, {total_m:.1f} m driven", end="")
    undecided = starts - len(verdicts)
    print(f"; start-ups right {verdicts.count('right')}, wrong {verdicts.count('wrong')}, none {undecided}" if args.run else "")
    return 0


if __name__ == "__main__":
    sys.exit(main())
