"""The fair-comparison protocol (runners/protocol.py, DESIGN.md "The NavigationSystem protocol"):
no ground truth reaches a non-privileged system, initial poses carry the seeded error, every
trial starts from a clean state, the two settings change only the noise, and the stop tolerance
is one for all."""

from __future__ import annotations

import gc
import json
import types
from dataclasses import fields, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import BaseModel
from typer.testing import CliRunner

from navkit import geometry as se2
from navkit.types import Command, MemoryBreakdown, NavStatus, Observation, Status
from reports.records import TrialRecord
from runners.cli import app
from runners.mapping import MappingSystem, context_for, run_mapping
from runners.navigation import TrialJob, run_trial_job
from runners.protocol import SETTINGS, TrialProtocol, apply_setting, setting_of
from runners.results import RunDir
from runners.sim import Simulator
from runners.systems import _REGISTRY, GroundTruth, SystemContext, get_system, register_system
from scenarios import Scenario, load_scenario
from scenarios.trials import Trial
from scenarios.world import World

TIMING = {"compute_s", "planning_ms", "planning_ms_samples", "first_plan_ms"}


class SpyConfig(BaseModel):
    steps: int = 3


class Spy:
    """Records what the runner hands it; declares reached after a few ticks."""

    seen: list[Any] = []  # (kind, value) for the whole test process

    def __init__(self, config: SpyConfig, context: SystemContext) -> None:
        self.config = config
        Spy.seen.append(("context", context))
        self.status = NavStatus()
        self.ticks = 0

    @classmethod
    def create(cls, config, context):
        return cls(config, context)

    @classmethod
    def load(cls, directory, config, context):
        assert (Path(directory) / "spy.json").is_file()
        return cls(config, context)

    def observe(self, obs: Observation) -> None:
        Spy.seen.append(("mapping_obs", obs))

    def finish_mapping(self) -> None:
        pass

    def save(self, directory: Path) -> None:
        Path(directory).mkdir(parents=True, exist_ok=True)
        (Path(directory) / "spy.json").write_text("{}")

    def mapping_stats(self) -> dict:
        return {"map_bytes": 0}

    def memory(self) -> MemoryBreakdown:
        return MemoryBreakdown()

    def reset(self) -> None:
        Spy.seen.append(("reset", None))
        self.ticks = 0
        self.status = NavStatus()

    def set_initial_pose(self, pose) -> None:
        Spy.seen.append(("initial_pose", np.asarray(pose, float).copy()))

    def set_goal(self, goal) -> None:
        Spy.seen.append(("goal", np.asarray(goal, float).copy()))

    def step(self, obs: Observation) -> Command:
        Spy.seen.append(("obs", obs))
        self.ticks += 1
        if self.ticks >= self.config.steps:
            self.status = NavStatus(Status.REACHED)
        return Command(0.2, 0.0)

    def stats(self) -> dict:
        return {"planning_ms": [0.1]}


@pytest.fixture(scope="module")
def spies():
    register_system("spy", config=SpyConfig)(Spy)
    register_system("spy_posed", config=SpyConfig, wants_initial_pose=True)(type("SpyPosed", (Spy,), {}))
    yield
    _REGISTRY.pop("spy", None)
    _REGISTRY.pop("spy_posed", None)


@pytest.fixture(scope="module")
def tiny() -> Scenario:
    scenario = load_scenario("tiny")
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(scenario.route, axis=0).T))])
    scenario.route = scenario.route[arc <= arc[-1] / 2]  # one tour of the branches maps them all
    return scenario


@pytest.fixture(scope="module")
def mapped(tiny, spies, tmp_path_factory):
    """One short mapping drive with the spies and the metric baseline; its run folder."""
    run = RunDir(tmp_path_factory.mktemp("run"))
    Spy.seen.clear()
    entries = [get_system(name) for name in ("spy", "spy_posed", "metric_grid")]
    run_mapping(tiny, [MappingSystem(e, e.config_model()) for e in entries], run, seed=tiny.spec.seed)
    run.mapping_seen = list(Spy.seen)  # what the spies got while mapping
    return run


FORBIDDEN = (World, Scenario, Trial, GroundTruth, Simulator)


def _reachable(root: Any, limit: int = 20000) -> list[Any]:
    """Everything reachable from ``root`` through attributes, containers and closures."""
    found, stack, seen = [], [root], set()
    while stack and len(found) < limit:
        obj = stack.pop()
        if id(obj) in seen or isinstance(obj, (type, types.ModuleType, str, bytes, int, float, bool)) or obj is None:
            continue
        seen.add(id(obj))
        found.append(obj)
        stack.extend(gc.get_referents(obj))
    return found


def test_a_non_privileged_system_is_told_nothing_derived_from_ground_truth(tiny, mapped):
    job = TrialJob.packed(
        scenario=str(tiny.path), system="spy", config={}, map_dir=str(mapped.map_dir("spy")), trials=[0, 1], seed=1
    )
    Spy.seen.clear()
    result = run_trial_job(job)
    assert [r.success for r in result["records"]] == [False, False]  # declared reached far from the goals
    contexts = [v for kind, v in Spy.seen if kind == "context"]
    assert contexts and all(c.ground_truth is None for c in contexts)
    for context in contexts:
        leaked = [type(o).__name__ for o in _reachable(context) if isinstance(o, FORBIDDEN)]
        assert not leaked, leaked
        assert {f.name for f in fields(context)} == {"robot", "sensor", "stop_tolerance", "ground_truth"}
    assert not [v for kind, v in Spy.seen if kind == "initial_pose"]  # it did not ask for one
    observations = [v for kind, v in Spy.seen if kind == "obs"]
    for obs in observations:
        assert type(obs) is Observation and is_dataclass(obs)
        assert {f.name for f in fields(obs)} == {"stamp", "points", "odom"}
        assert obs.points.dtype == np.float32 and obs.points.shape[1] == 3
        assert np.hypot(obs.points[:, 0], obs.points[:, 1]).max() <= tiny.spec.sensor.max_range + 1e-3  # robot frame
    # odometry restarts at each trial's start: it carries no pose in the map or the scenario frame
    resets = [i for i, (kind, _) in enumerate(Spy.seen) if kind == "reset"]
    assert len(resets) == 2
    for i in resets:
        first_obs = next(v for kind, v in Spy.seen[i:] if kind == "obs")
        assert np.array_equal(first_obs.odom, np.zeros(3))


def test_the_mapping_stage_gives_systems_scans_and_odometry_only(tiny, mapped):
    contexts = [v for kind, v in mapped.mapping_seen if kind == "context"]
    observations = [v for kind, v in mapped.mapping_seen if kind == "mapping_obs"]
    assert len(contexts) == 2 and all(c.ground_truth is None for c in contexts)
    assert all(not [o for o in _reachable(c) if isinstance(o, FORBIDDEN)] for c in contexts)
    assert len(observations) > 10
    assert np.array_equal(observations[0].odom, np.zeros(3))  # the map frame is the run's first pose
    assert all({f.name for f in fields(o)} == {"stamp", "points", "odom"} for o in observations)
    with Simulator(tiny, seed=0) as sim:
        assert context_for(get_system("oracle"), tiny, sim).ground_truth is not None  # the one privileged system


def test_a_system_that_takes_an_initial_pose_gets_the_start_with_the_seeded_error(tiny, mapped):
    protocol = TrialProtocol()
    job = TrialJob.packed(
        scenario=str(tiny.path),
        system="spy_posed",
        config={},
        map_dir=str(mapped.map_dir("spy_posed")),
        trials=[0, 1, 2],
        seed=5,
        protocol=protocol.as_json(),
    )
    Spy.seen.clear()
    records = run_trial_job(job)["records"]
    given = [v for kind, v in Spy.seen if kind == "initial_pose"]
    assert len(given) == 3
    for trial, pose, record in zip(tiny.trials, given, records, strict=True):
        true_in_map = se2.between(tiny.route_start, trial.start)
        error = pose - true_in_map
        error[2] = se2.wrap_angle(error[2])
        assert 0.0 < np.hypot(error[0], error[1]) and np.all(np.abs(error[:2]) <= 0.5)
        assert abs(error[2]) <= np.radians(10.0)
        assert np.allclose(error, protocol.initial_pose_error(5, trial.index))
        assert record.initial_pose_error == pytest.approx([error[0], error[1], np.degrees(error[2])], abs=1e-3)
    # the same (seed, trial) gives the same error, whatever ran before; another seed, another error
    assert np.allclose(protocol.initial_pose_error(5, 2), TrialProtocol().initial_pose_error(5, 2))
    assert not np.allclose(protocol.initial_pose_error(5, 2), protocol.initial_pose_error(6, 2))
    exact = TrialProtocol(initial_pose_error_xy=0.0, initial_pose_error_yaw_deg=0.0)
    assert np.array_equal(exact.initial_pose_error(5, 2), np.zeros(3))


def _without_timing(record: TrialRecord) -> dict:
    return {k: v for k, v in record.as_json().items() if k not in TIMING}


def test_two_trials_in_one_worker_give_what_each_gives_alone(tiny, mapped):
    """The metric baseline resets at each trial's start: trial 1 after trial 0 in one worker is
    trial 1 alone in a fresh one (everything but timing identical)."""
    common = {"scenario": str(tiny.path), "system": "metric_grid", "map_dir": str(mapped.map_dir("metric_grid")), "seed": 1}
    config = get_system("metric_grid").default_config().model_dump(mode="json")
    both = run_trial_job(TrialJob.packed(config=config, trials=[0, 1], **common))["records"]
    alone = run_trial_job(TrialJob.packed(config=config, trials=[1], **common))["records"]
    assert both[1].success and alone[0].success
    assert _without_timing(both[1]) == _without_timing(alone[0])


def test_settings_change_only_the_noise():
    scenario = load_scenario("tiny")
    assert setting_of(scenario) == "precise"
    noisy = apply_setting(scenario, "noisy")
    assert setting_of(noisy) == "noisy" and setting_of(scenario) == "precise"  # the original is untouched
    assert noisy.spec.odometry.noise == SETTINGS["noisy"].odometry_noise
    assert noisy.spec.odometry.noise.translation == 0.02 and noisy.spec.odometry.noise.rotation_deg_per_m == 0.5
    assert noisy.spec.sensor.range_noise == 0.01
    assert noisy.world is scenario.world and noisy.trials is scenario.trials and noisy.route is scenario.route
    assert apply_setting(noisy, "precise").spec.odometry.noise is None
    assert apply_setting(scenario, None) is scenario
    with pytest.raises(ValueError, match="unknown setting"):
        apply_setting(scenario, "foggy")
    assert setting_of(load_scenario("corridor_150m_noisy")) == "noisy"


def test_every_follower_stops_at_the_protocols_tolerance(tiny):
    context = SystemContext(robot=tiny.spec.robot, sensor=tiny.spec.sensor, stop_tolerance=0.2)
    from baselines.metric_grid.system import MetricGrid, MetricGridConfig

    assert MetricGrid(MetricGridConfig(), context).follower.config.goal_tolerance == 0.2
    with Simulator(tiny, seed=0) as sim:
        oracle_context = context_for(get_system("oracle"), tiny, sim, TrialProtocol(stop_tolerance=0.2))
        oracle = get_system("oracle").create(get_system("oracle").default_config(), oracle_context)
    assert oracle.follower.config.goal_tolerance == 0.2


@pytest.mark.long
def test_the_manifest_records_the_protocol_and_the_setting(tmp_path):
    from test_scaleout import short_tiny

    out = tmp_path / "run"
    result = CliRunner().invoke(
        app,
        [
            "run",
            str(short_tiny(tmp_path)),  # the oracle maps nothing: a 3 m route
            "--systems",
            "oracle",
            "--trials",
            "0",
            "--setting",
            "noisy",
            "--initial-pose-error",
            "0.3,5",
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["setting"] == "noisy" and manifest["setting_override"] == "noisy"
    assert manifest["odometry_noise"] == {"translation": 0.02, "rotation_deg_per_m": 0.5} and manifest["range_noise"] == 0.01
    assert manifest["protocol"] == {
        "initial_pose_error_xy": 0.3,
        "initial_pose_error_yaw_deg": 5.0,
        "stop_tolerance": 0.25,
        "goal_tolerance": 0.5,
        "goals": "map",
        "initial_pose": "perturbed",
    }
    bad = CliRunner().invoke(app, ["run", "tiny", "--systems", "oracle", "--setting", "foggy", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "--setting" in bad.output and not (tmp_path / "x").exists()


def test_a_system_is_configured_for_the_setting_as_a_user_configures_a_robot():
    from runners.run import resolved_configs

    precise = resolved_configs(["metric_grid", "navtopo"], None, "precise")
    noisy = resolved_configs(["metric_grid", "navtopo"], {"metric_grid": {"planning": {"replan_period": 3.0}}}, "noisy")
    assert precise["metric_grid"]["odometry"]["source"] == "wheel"
    assert noisy["metric_grid"]["odometry"]["source"] == "lidar"  # kiss-icp for noisy wheels
    assert noisy["metric_grid"]["planning"]["replan_period"] == 3.0  # the user's own overrides still win
    # odometry factors as tight as exact odometry, and the noisy recipe's own (not the precise ones)
    assert precise["metric_grid"]["pose_graph"]["odometry_sigma_yaw_deg_per_m"] == 0.02
    assert noisy["metric_grid"]["pose_graph"]["odometry_sigma_yaw_deg_per_m"] == 0.1
    assert noisy["metric_grid"]["pose_graph"]["odometry_sigma_xy_per_m"] == 0.02
    assert precise["navtopo"] == noisy["navtopo"]  # NavTopo has no setting-specific configuration
