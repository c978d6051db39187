"""The shortcut pass at mapping's end (``GraphMaintainer.add_shortcuts``) replayed on saved maps of
generated scenes, under mapping-config variants: the edges each adds, each checked against the truth
(the anchors: where each location was made), and the pairs of nearby locations still joined only the
long way round (``runners.metrics.unjoined_neighbours``). For tuning the pass on generated scenes
(never a bundled benchmark scene); no run is needed beyond the mapping.

    .venv/bin/python benchmarks/tune_shortcuts.py RUN [RUN ...] [--variant '{"shortcut_wall_agreement": 0.85}' ...]

Each RUN is a results folder with ``maps/navtopo`` (its scenario, setting and config are the
manifest's). An edge is wrong when its pose is more than 0.3 m or 3° off the truth.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from navkit import geometry as se2
from navtopo.system import NavTopo, NavTopoConfig
from runners.metrics import unjoined_neighbours
from scenarios import load_scenario


def evaluate(run: Path, variant: dict) -> dict:
    manifest = json.loads((run / "manifest.json").read_text())
    base = manifest["config"]["navtopo"]
    config = NavTopoConfig.model_validate({**base, "mapping": {**base.get("mapping", {}), **variant}})
    system = NavTopo.load(run / "maps" / "navtopo", config)
    anchors = {round(r[0], 6): np.asarray(r[1:4]) for r in json.loads((run / "mapping" / "navtopo.json").read_text())["anchors"]}
    graph = system.graph
    truth = [anchors[round(v.stamp, 6)] for v in graph.vertices]
    before = {(u, v) for u, v, _ in graph.edges()}
    added = system.maintainer.add_shortcuts(system.navigator.local.way_between)
    wrong = []
    for u, v, pose in graph.edges():
        if (u, v) in before:
            continue
        error = se2.between(se2.between(truth[u], truth[v]), pose)
        if np.hypot(error[0], error[1]) > 0.3 or abs(np.degrees(error[2])) > 3.0:
            wrong.append((u, v, round(float(np.hypot(error[0], error[1])), 2)))
    scenario = load_scenario(manifest["scenario"]["file"])
    pairs = [(u, v) for u, v, _ in graph.edges()]
    positions = np.array([t[:2] for t in truth])
    unjoined = unjoined_neighbours(positions, pairs, scenario.world.clearances_at, scenario.spec.robot.radius, radius=8.0)
    return {"run": run.name, "added": added, "wrong": wrong, "unjoined": len(unjoined)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--variant", action="append", default=[], help="mapping config overrides (JSON); repeatable")
    args = parser.parse_args()
    variants = [{}] + [json.loads(v) for v in args.variant]
    for variant in variants:
        results = [evaluate(run, variant) for run in args.runs]
        print(json.dumps({"variant": variant, "runs": results}))


if __name__ == "__main__":
    main()
