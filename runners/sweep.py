"""``navtopo-bench sweep scaling``: the same study at growing environment sizes.

For each total corridor length a scenario is generated (``--building lattice``, the default:
``scenarios.lattice.lattice_building``, corridors round blocks, so with loops; ``tree``:
``scenarios.generators.corridor_tree``; both dressed with door niches, side rooms, furniture and
pillars; same seed, same building), written as a YAML file under ``<out>/scenarios/`` (so every
run can be resumed and repeated from its manifest), then run like ``navtopo-bench run`` into
``<out>/<length>m/``: the mapping route (an auto tour of ``route_factor`` x the corridor length at
least) and a fixed number of trials for each system. The sizes run on one executor, their jobs in
flight together (``runners.driver``). ``reports.sweep`` then reads those folders alone and plots
planning time and every memory part against the environment size, log-log, with fitted growth
exponents.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from runners.executors import open_executor
from runners.protocol import TrialProtocol
from runners.run import RunOptions, RunPlan, execute_runs, in_folder
from scenarios import Scenario, load_scenario
from scenarios.generators import corridor_tree
from scenarios.lattice import lattice_building

DEFAULT_LENGTHS = (150, 300, 600, 1200, 2400)
DEFAULT_SYSTEMS = ("navtopo", "metric_grid")
GENERATORS = {"lattice": lattice_building, "tree": corridor_tree}
# runs them all, on one executor: the (scenario, options) of each run to make or resume
RunAll = Callable[[list[tuple[Scenario, RunOptions]]], None]


@dataclass
class ScalingOptions:
    lengths: list[float] = field(default_factory=lambda: list(DEFAULT_LENGTHS))
    systems: list[str] = field(default_factory=lambda: list(DEFAULT_SYSTEMS))
    trials: int = 5
    seed: int = 31  # the buildings' seed: disjoint from the generated scenes parameters were tuned on
    building: str = "lattice"  # a GENERATORS name
    route_factor: float = 1.0  # the auto route drives at least this many times the corridor length
    # trial ends this far apart (GT path): a share of the corridor length for trees; for a lattice
    # its generator's default, 40 % of the way across it (a share of the length would not fit)
    min_distance_factor: float = 0.3
    setting: str | None = "precise"
    workers: int | None = None  # jobs at once; None: the cores (local), the cluster's CPUs (ray)
    executor: str = "local"  # runners.executors: local or ray
    ray_address: str | None = None
    out: Path = Path("results/sweep_scaling")
    protocol: TrialProtocol = field(default_factory=TrialProtocol)


def scaling_scenario_file(length: float, options: ScalingOptions) -> Path:
    """Write (once) and return the YAML file of the generated building of ``length`` m."""
    name = f"scaling_{options.building}_{int(round(length))}m"
    path = options.out / "scenarios" / f"{name}.yaml"
    if not path.is_file():
        spec = GENERATORS[options.building](
            length,
            seed=options.seed,
            route_factor=options.route_factor,
            trials=options.trials,
            min_distance=options.min_distance_factor * length if options.building == "tree" else None,
            name=name,
        )
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def run_scaling(options: ScalingOptions, run_all: RunAll | None = None) -> list[Path]:
    """Every size (a finished size is kept, an interrupted one resumed), all on one executor;
    returns the run folders."""
    return _run_each(
        [
            (
                options.out / f"{int(round(length))}m",
                options.setting,
                lambda length=length: load_scenario(scaling_scenario_file(length, options)),
            )
            for length in options.lengths
        ],
        options,
        run_all,
    )


# ---------------------------------------------------------------------------------------------
# drift: one scenario under odometry noise off, moderate and strong

DEFAULT_LEVELS = ("precise", "noisy", "strong")  # runners.protocol.SETTINGS: off, moderate, strong


@dataclass
class DriftOptions:
    scenario: str = "loop_office"
    levels: list[str] = field(default_factory=lambda: list(DEFAULT_LEVELS))
    systems: list[str] = field(default_factory=lambda: list(DEFAULT_SYSTEMS))
    trials: int = 5
    workers: int | None = None
    executor: str = "local"
    ray_address: str | None = None
    out: Path = Path("results/sweep_drift")
    protocol: TrialProtocol = field(default_factory=TrialProtocol)


def run_drift(options: DriftOptions, run_all: RunAll | None = None) -> list[Path]:
    """The scenario once per level into ``<out>/<level>/`` (a finished level kept, an interrupted one
    resumed), all on one executor; the same seed, route and trials, only the noise differs. Returns
    the run folders."""
    scenario = load_scenario(options.scenario)
    return _run_each([(options.out / level, level, lambda: scenario) for level in options.levels], options, run_all)


def _run_each(
    runs: list[tuple[Path, str | None, Callable[[], Scenario]]],
    options: ScalingOptions | DriftOptions,
    run_all: RunAll | None,
) -> list[Path]:
    """Run each (folder, setting, scenario loader) but those finished, together on the sweep's
    executor: an interrupted folder is resumed. Returns the run folders."""
    base = RunOptions(
        systems=list(options.systems),
        trials=options.trials,
        workers=options.workers,
        executor=options.executor,
        ray_address=options.ray_address,
        protocol=options.protocol,
    )
    todo = []
    for folder, setting, load in runs:
        run_options = in_folder(folder, dataclasses.replace(base, setting=setting))
        if run_options is not None:
            todo.append((load(), run_options))
    (run_all or _execute_all)(todo)
    return [folder for folder, _, _ in runs]


def _execute_all(todo: list[tuple[Scenario, RunOptions]]) -> None:
    if not todo:
        return
    first = todo[0][1]
    with open_executor(first.executor, first.workers, first.ray_address) as pool:
        for outcome in execute_runs([RunPlan(scenario, options) for scenario, options in todo], pool):
            if outcome.error is not None:
                raise outcome.error
