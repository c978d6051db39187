"""The command line's parts without a run: `run`'s flags as one typed request (``RunRequest``),
the manifest a resume reads (``ResumableManifest``), and the one place where expected failures
become their `error:` line (``BenchGroup``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from navkit.errors import BenchError
from runners.cli import BenchGroup
from runners.commands.errors import Refused, RunsFailed
from runners.commands.request import RunRequest
from runners.commands.resume import read_resumable
from runners.executors import ExecutorUnavailable
from runners.protocol import TrialProtocol

SYSTEMS = ["navtopo", "metric_grid", "oracle"]


def refused(**flags) -> str:
    with pytest.raises(BenchError) as info:
        RunRequest(**flags)
    assert info.value.exit_code == 2
    return str(info.value)


# ---------------------------------------------------------------------------------------------
# the run request


def test_a_request_of_one_scenario_derives_the_defaults_of_a_run():
    request = RunRequest(scenarios=["tiny"])
    assert request.system_list == SYSTEMS
    assert request.setting_list == [None] and request.seed_list == [None]  # the scenario file's own noise and seed
    assert request.protocol == TrialProtocol()
    assert request.shared_options()["trial_wall_s"] == 3600.0 and request.shared_options()["trial_memory_mb"] is None


def test_comma_lists_make_one_run_each_and_the_protocol_takes_the_flags():
    request = RunRequest(
        scenarios=["tiny"], systems=" oracle , navtopo", seeds="3,1", setting="noisy,precise", initial_pose_error="0,2.5"
    )
    assert request.system_list == ["oracle", "navtopo"]
    assert request.seed_list == [3, 1] and request.setting_list == ["noisy", "precise"]
    assert (request.protocol.initial_pose_error_xy, request.protocol.initial_pose_error_yaw_deg) == (0.0, 2.5)


@pytest.mark.parametrize(
    ("flags", "reason"),
    [
        ({"setting": "noisy,noisy"}, "--setting 'noisy,noisy': a setting is named twice"),
        ({"initial_pose_error": "1,inf"}, "--initial-pose-error: expected two non-negative numbers XY_M,YAW_DEG"),
        ({"stop_tolerance": 0.6}, "--stop-tolerance 0.6: expected a finite number of metres, 0.01 to 0.5"),
        ({"trial_timeout_s": float("nan")}, "--trial-timeout-s nan: expected a number of seconds, at least 1"),
        ({"goals": "x"}, "--goals: 'x' is not map or native"),
        ({"seed": -1}, "--seed -1: a seed is a non-negative integer"),
        ({"seeds": "1,x"}, "--seeds: not a list of integers: '1,x'"),
        ({"scenarios": []}, "give at least one SCENARIO"),
        ({"scenarios": ["tiny", "loop_office"], "out": Path("o")}, "--out takes one scenario, one seed and one setting"),
        ({"maps_from": Path("m"), "seeds": "1,2"}, "--maps-from serves one scenario, one seed and one setting"),
        ({"maps_from": Path("m"), "trials": 0}, "--trials 0 with --maps-from would run nothing"),
    ],
)
def test_a_broken_flag_rule_is_its_one_line_never_a_validation_error(flags, reason):
    assert reason in refused(**{"scenarios": ["tiny"], **flags})


def test_the_first_broken_rule_is_the_one_reported_in_the_commands_order():
    # executor, systems, settings, initial pose error, tolerances, goals, seeds: as `run` has always checked them
    with pytest.raises(ExecutorUnavailable):
        RunRequest(scenarios=["tiny"], executor="x", systems="nope", seed=-1)
    assert refused(scenarios=["tiny"], systems="nope", setting="x").startswith("--systems: unknown system(s) nope")
    assert refused(scenarios=["tiny"], setting="x", goals="x").startswith("--setting: unknown setting x")
    assert refused(scenarios=["tiny"], goals="x", seed=-1).startswith("--goals")


def test_what_a_suite_lists_is_refused_beside_it_and_what_a_manifest_decides_is_ignored_beside_a_resume(tmp_path):
    reason = refused(suite=Path("s.yaml"), scenarios=["tiny"], trials=2, seeds="1,2", maps_from=Path("m"))
    assert reason.startswith("--suite s.yaml: SCENARIO, --trials, --seeds, --maps-from: the suite file lists the runs")
    assert refused(resume=tmp_path) == f"{tmp_path}: not a run folder (manifest.json missing)"
    (tmp_path / "manifest.json").write_text("{}")
    assert refused(resume=tmp_path, seeds="1,2").startswith("--resume finishes one run folder")
    request = RunRequest(resume=tmp_path, systems="nope", initial_pose_error="0.50,10", goals="native")
    assert request.system_list == []  # a resume runs the manifest's systems: --systems is not even parsed
    assert request.ignored_by_resume == ["--systems", "--initial-pose-error", "--goals"]


def test_an_out_folder_that_holds_a_run_is_refused_before_the_out_rule(tmp_path):
    (tmp_path / "manifest.json").write_text("{}")
    reason = refused(scenarios=["tiny", "loop_office"], out=tmp_path)
    assert reason == f"{tmp_path}: already holds a run; use --resume {tmp_path} to finish it, or another --out"


# ---------------------------------------------------------------------------------------------
# the manifest of a resume


def manifest_in(folder: Path, **keys) -> Path:
    data = {"scenario": {"file": "tiny"}, "systems": ["oracle"], "seed": 1, "config": {"oracle": {}}, **keys}
    (folder / "manifest.json").write_text(json.dumps({k: v for k, v in data.items() if v is not None}))
    return folder


def test_a_resume_reads_the_manifest_with_the_results_folders_model(tmp_path):
    from reports.results import Manifest

    manifest = read_resumable(manifest_in(tmp_path, trial_count=2), ["oracle"])
    assert isinstance(manifest, Manifest)
    assert (manifest.scenario.name, manifest.scenario.file) == ("tiny", "tiny")  # named by its file when it has no name
    assert (manifest.systems, manifest.seed, manifest.trial_count, manifest.scenario_sha256) == (["oracle"], 1, 2, None)


@pytest.mark.parametrize(
    ("keys", "reason"),
    [
        ({"scenario": {"name": "tiny"}, "seed": "1"}, "scenario.file missing"),  # the first key a resume reads
        ({"systems": [], "seed": "1"}, "systems missing"),
        ({"systems": ["nope", "oracle"], "seed": True}, "systems: unknown system(s) nope"),
        ({"seed": True, "config": {}}, "seed missing or not an integer"),
        ({"config": {"oracle": 3}, "trial_count": "2"}, "config of a system missing"),
        ({"trial_count": "2"}, "trial_count not an integer"),
        ({"protocol": {"stop_tolerance": "far"}}, "protocol.stop_tolerance: Input should be a valid number"),
    ],
)
def test_a_manifest_a_resume_cannot_use_names_its_first_problem(tmp_path, keys, reason):
    with pytest.raises(Refused) as info:
        read_resumable(manifest_in(tmp_path, **keys), ["oracle"])
    assert str(info.value) == f"--resume {tmp_path / 'manifest.json'}: {reason}; this folder cannot be resumed"


# ---------------------------------------------------------------------------------------------
# the one handler


class Odd(BenchError):
    exit_code = 3


def test_every_expected_failure_is_its_error_line_and_exit_code_and_anything_else_a_traceback():
    app = typer.Typer(cls=BenchGroup)

    @app.command()
    def refuse() -> None:
        raise Refused("--flag x: [not] markup\nnor two lines")

    @app.command()
    def odd() -> None:
        raise Odd("odd")

    @app.command()
    def fail() -> None:
        raise RunsFailed(["run of a failed", "run of b failed"])

    @app.command()
    def bug() -> None:
        raise KeyError("bug")

    runner = CliRunner()
    result = runner.invoke(app, ["refuse"])
    assert (result.exit_code, result.output) == (2, "error: --flag x: [not] markup nor two lines\n")
    assert (runner.invoke(app, ["odd"]).exit_code, runner.invoke(app, ["odd"]).output) == (3, "error: odd\n")
    result = runner.invoke(app, ["fail"])
    assert (result.exit_code, result.output) == (1, "error: run of a failed\nerror: run of b failed\n")
    assert isinstance(runner.invoke(app, ["bug"]).exception, KeyError)
