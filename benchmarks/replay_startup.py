r"""Replay NavTopo's start-up of one trial of a run, on the run's saved map, and say tick by tick
what it did: how it moved (exploring, driving by a hypothesis), the hypotheses against the truth,
the scan's nearest return and the true clearance. For tracing start-up failures (collisions,
wrong commitments) on generated scenes.

    .venv/bin/python benchmarks/replay_startup.py RUN TRIAL [--until-commit] [--every N]

RUN is a results folder of a run with NavTopo (its scenario, setting and seed are the manifest's;
the map is ``maps/navtopo``). The truth (anchors, true poses) is used here to judge, never given to
NavTopo.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from navkit import geometry as se2
from navkit.scan import obstacle_points
from navtopo.system import NavTopo
from runners.anchors import Anchors
from runners.navigation import TRIAL_STREAM, TrialOutcome, start_trial
from runners.protocol import TrialProtocol, apply_setting, context_for
from runners.sim import Simulator
from runners.systems import get_system
from scenarios import load_scenario


def arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("trial", type=int)
    parser.add_argument("--until-commit", action="store_true", help="stop at the commitment")
    parser.add_argument("--every", type=int, default=1, help="print every N-th tick (and every event)")
    parser.add_argument("--max-s", type=float, default=None, help="stop after this many simulated seconds")
    return parser


def true_clearance(world, pose, radius: float) -> float:
    """Metres from the robot's body to the nearest obstacle of the ground-truth raster (any height)."""
    return world.clearance_at(pose[:2]) - radius


def main() -> int:
    args = arguments().parse_args()
    manifest = json.loads((args.run / "manifest.json").read_text())
    mapping = json.loads((args.run / "mapping" / "navtopo.json").read_text())
    scenario = apply_setting(load_scenario(manifest["scenario"]["file"]), manifest["setting"])
    seed = int(manifest["seed"])
    entry = get_system("navtopo")
    config = entry.config_model.model_validate(manifest["config"]["navtopo"])
    protocol = TrialProtocol.from_json(manifest["protocol"])
    anchors = Anchors.from_rows(mapping["anchors"])
    assert anchors is not None
    with Simulator(scenario, seed=seed, with_changes=True) as sim:
        system = entry.load(args.run / "maps" / "navtopo", config, context_for(entry, scenario, sim, protocol))
        assert isinstance(system, NavTopo)
        nav = system.navigator
        trial = scenario.trials[args.trial]
        sim.reset(trial.start, stream=(TRIAL_STREAM, args.trial))
        start_trial(scenario, entry, system, trial, args.trial, seed, protocol, anchors, TrialOutcome())
        world, radius = scenario.navigation_world, scenario.spec.robot.radius
        tick = 0
        while True:
            obs = sim.observe()
            counters = dict(nav.counters)
            command = system.step(obs)
            truth = sim.true_pose
            mode = "committed" if nav.localized else ("explore" if nav.explorer.move is not None else "tentative")
            events = {k: v - counters.get(k, 0) for k, v in nav.counters.items() if v != counters.get(k, 0)}
            near = obstacle_points(obs.points, nav.maintainer.grid_config)
            nearest = float(np.hypot(near[:, 0], near[:, 1]).min()) if len(near) else np.inf
            clearance = true_clearance(world, truth, radius)
            hyps = []
            for h in nav.startup.hypotheses:
                anchor = anchors.poses.get(round(float(nav.graph.vertices[h.vertex].stamp), 6))
                where = se2.compose(anchor, h.pose) if anchor is not None else None
                off = float(np.hypot(*(where[:2] - truth[:2]))) if where is not None else np.nan
                hyps.append(f"v{h.vertex}:s{h.support}:p{len(h.places)}:{off:.1f}m")
            if tick % args.every == 0 or events or clearance < 0.05:
                path_end = nav.follower.path[-1] if nav.follower.has_path else None
                print(
                    f"t={obs.stamp:6.1f} true=({truth[0]:7.2f},{truth[1]:7.2f},{np.degrees(truth[2]):6.1f}) "
                    f"cmd=({command.linear:4.2f},{command.angular:5.2f}) {mode:9s} clear={clearance:5.2f} "
                    f"scan_min={nearest:5.2f} odo={nav.startup.odometer:5.1f} looks={nav.startup.looks} "
                    f"hyps=[{' '.join(hyps)}] {events if events else ''} "
                    f"end={None if path_end is None else np.round(path_end, 2)}"
                )
            result = sim.step(command)
            if result.collided:
                print(f"COLLISION at true {np.round(sim.true_pose, 3)}; status {nav.status}")
                break
            status = nav.status
            if status.state.value != "active" or (args.until_commit and nav.localized):
                print("END", status)
                break
            if args.max_s is not None and obs.stamp > args.max_s:
                break
            tick += 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
