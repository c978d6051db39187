"""`run --suite FILE`: a YAML file listing runs (scenarios, seeds, settings, systems, trials). A valid
suite makes a folder per run under --out and the same command again keeps or resumes them; a bad
one is refused in one line naming the file, the key and the reason, exit 2, with nothing created."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from test_scaleout import records_of, short_tiny
from typer.testing import CliRunner

from runners.cli import app


def write_suite(folder: Path, data) -> Path:
    path = folder / "suite.yaml"
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data, sort_keys=False))
    return path


def listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.mark.long
def test_a_suite_runs_each_listed_run_into_its_folder_and_the_same_command_finishes_it(tmp_path):
    short_tiny(tmp_path)  # `tiny` with a 3 m mapping route, beside the suite: found by its relative path
    suite = write_suite(
        tmp_path,
        {
            "format": "navtopo-suite/1",
            "systems": ["oracle"],
            "trials": 1,
            "runs": [
                {"scenarios": ["short_tiny.yaml"], "seeds": [1, 2]},
                {"scenarios": ["short_tiny.yaml"], "seeds": [1], "settings": ["noisy"], "trials": 2},
            ],
        },
    )
    out = tmp_path / "out"
    command = ["run", "--suite", str(suite), "--out", str(out), "--workers", "2"]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 0, result.output
    folders = {"s1": (1, None, 1), "s2": (2, None, 1), "s1-noisy": (1, "noisy", 2)}
    assert sorted(p.name for p in (out / "tiny").iterdir()) == sorted(folders)
    for name, (seed, setting, trials) in folders.items():
        run = out / "tiny" / name
        manifest = json.loads((run / "manifest.json").read_text())
        assert (manifest["seed"], manifest["setting_override"], manifest["systems"]) == (seed, setting, ["oracle"])
        assert manifest["scenario"]["file"] == str((tmp_path / "short_tiny.yaml").resolve())
        assert sorted(records_of(run)) == [("oracle", i) for i in range(trials)]
        assert json.loads((run / "summary.json").read_text())["oracle"]["trials"] == trials
        assert f"results: {run}" in " ".join(result.output.split())

    # an interrupted run (no summary yet) is resumed by the same command; finished ones are kept
    (out / "tiny" / "s2" / "summary.json").unlink()
    kept = (out / "tiny" / "s1" / "trials.jsonl").stat().st_mtime_ns
    mapped = (out / "tiny" / "s2" / "mapping" / "oracle.json").stat().st_mtime_ns
    again = CliRunner().invoke(app, command)
    assert again.exit_code == 0, again.output
    assert "s1: finished before; kept" in again.output and "s1-noisy: finished before; kept" in again.output
    assert (out / "tiny" / "s1" / "trials.jsonl").stat().st_mtime_ns == kept
    assert (out / "tiny" / "s2" / "mapping" / "oracle.json").stat().st_mtime_ns == mapped
    assert (out / "tiny" / "s2" / "summary.json").is_file() and sorted(records_of(out / "tiny" / "s2")) == [("oracle", 0)]


GOOD = {"format": "navtopo-suite/1", "runs": [{"scenarios": ["tiny"]}]}


def entry(**keys):
    return {**GOOD, "runs": [{"scenarios": ["tiny"], **keys}]}


BAD_SUITES = [
    pytest.param("- tiny\n", ": not a YAML mapping of keys", id="a list"),
    pytest.param("format: navtopo-suite/1\nruns: [\n", ": line ", id="YAML syntax"),
    pytest.param("format: navtopo-suite/1\nformat: navtopo-suite/1\nruns: []\n", "duplicate key 'format'", id="a key twice"),
    pytest.param({"runs": GOOD["runs"]}, ": format: required key is missing", id="no format"),
    pytest.param({**GOOD, "format": "navtopo-scenario/1"}, ": format: Input should be 'navtopo-suite/1'", id="a scenario file"),
    pytest.param({"format": "navtopo-suite/1"}, ": runs: required key is missing", id="no runs"),
    pytest.param({**GOOD, "runs": []}, ": runs: List should have at least 1 item", id="runs empty"),
    pytest.param({**GOOD, "seeds": [1]}, ": seeds: unknown key", id="seeds at the top"),
    pytest.param(entry(seed=1), ": runs.0.seed: unknown key", id="seed, not seeds"),
    pytest.param({**GOOD, "runs": [{"seeds": [1]}]}, ": runs.0.scenarios: required key is missing", id="no scenarios"),
    pytest.param(entry(seeds=[1, -2]), ": runs.0.seeds.1: Input should be greater than or equal to 0", id="negative seed"),
    pytest.param(entry(seeds=["1"]), ": runs.0.seeds.0: Input should be a valid integer", id="seed as text"),
    pytest.param(entry(trials=-1), ": runs.0.trials: Input should be greater than or equal to 0", id="negative trials"),
    pytest.param(entry(settings=["loud"]), ": runs.0.settings: unknown setting loud", id="unknown setting"),
    pytest.param(entry(systems=["nope"]), ": runs.0.systems: unknown system(s) nope", id="unknown system"),
    pytest.param({**GOOD, "systems": ["oracle", "oracle"]}, ": systems: a system is named twice", id="a system twice"),
    pytest.param(
        {**GOOD, "runs": [{"scenarios": ["tiny", "nope"]}]}, ": runs.0.scenarios.1: nope: no such scenario file", id="no scenario"
    ),
    pytest.param({**GOOD, "runs": [{"scenarios": ["missing.yaml"]}]}, "missing.yaml: no such file", id="no scenario file"),
    pytest.param(
        {**GOOD, "runs": [{"scenarios": ["tiny"], "seeds": [1]}, {"scenarios": ["tiny"], "systems": ["oracle"]}]},
        ": runs.1: tiny/s1 is run twice (by runs.0 too)",
        id="a run twice",
    ),
]


@pytest.mark.parametrize(("suite", "expected"), BAD_SUITES)
def test_a_bad_suite_file_is_one_line_naming_file_key_and_reason_and_creates_nothing(tmp_path, suite, expected):
    path = write_suite(tmp_path, suite)
    before = listing(tmp_path)
    result = CliRunner().invoke(app, ["run", "--suite", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}") and expected in lines[0], result.output
    assert "Traceback" not in result.output and listing(tmp_path) == before


@pytest.mark.parametrize(
    "flags", [["tiny"], ["--seeds", "1,2"], ["--systems", "oracle"], ["--trials", "1"], ["--resume", "somewhere"]]
)
def test_what_the_suite_lists_is_refused_beside_it(tmp_path, flags):
    path = write_suite(tmp_path, GOOD)
    result = CliRunner().invoke(app, ["run", "--suite", str(path), "--out", str(tmp_path / "out"), *flags])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: --suite {path}: ") and "the suite file lists the runs" in result.output
    assert not (tmp_path / "out").exists()


def test_a_missing_suite_file_is_one_line(tmp_path):
    result = CliRunner().invoke(app, ["run", "--suite", str(tmp_path / "none.yaml"), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and result.output.strip() == f"error: {tmp_path / 'none.yaml'}: no such file"


def test_the_readme_suite_example_is_a_valid_suite(tmp_path):
    """The suite file README.md shows reads as the runs it describes: 2 scenarios x 2 settings x 3
    seeds with the defaults, and the warehouse with its own trials."""
    from runners.suite import read_suite

    readme = (Path(__file__).resolve().parent.parent / "README.md").read_text()
    start = readme.index("```yaml\nformat: navtopo-suite/1") + len("```yaml\n")
    runs = read_suite(write_suite(tmp_path, readme[start : readme.index("```", start)]))
    assert len(runs) == 13 and len({run.folder for run in runs}) == 13
    assert {(run.scenario.name, run.trials) for run in runs} == {("corridor_150m", 5), ("loop_office", 5), ("warehouse", 10)}
    assert all(run.systems == ["navtopo", "metric_grid"] for run in runs)
    assert Path("loop_office/s3-noisy") in {run.folder for run in runs}
