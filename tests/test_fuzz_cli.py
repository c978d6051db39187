"""Property-based fuzz of the command line's inputs (issue 14): scenario files, `run` flags,
configs and folders, run folders for `report` and `--resume`. Whatever the input, the answer is
exit 0 or 2, never a traceback; a refusal is one `error:` line (or typer's usage panel for a flag
value of the wrong type) and creates nothing."""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path
from typing import Any

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from runners.cli import app

FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

BASE: dict[str, Any] = {
    "format": "navtopo-scenario/1",
    "name": "fuzz",
    "seed": 1,
    "world": {"corridors": [{"points": [[0, 0], [10, 0], [10, 6]], "width": 2.0}]},
    "robot": {"radius": 0.3},
    "sensor": {"channels": 16, "rate_hz": 5},
    "mapping_route": {"waypoints": [[1, 0], [10, 5]]},
    "trials": [{"start": [1, 0, 0], "goal": [10, 5]}],
}
KEYS = [
    "format", "name", "seed", "description", "bogus",
    "world", "world.resolution", "world.wall_height", "world.ceiling", "world.corridors", "world.corridors.0",
    "world.corridors.0.width", "world.corridors.0.points", "world.corridors.0.points.1", "world.rooms",
    "world.obstacles", "world.map", "world.map.yaml",
    "robot.radius", "robot.max_linear", "robot.max_angular",
    "sensor.channels", "sensor.vertical_fov", "sensor.horizontal_resolution", "sensor.max_range",
    "sensor.mount_height", "sensor.rate_hz", "sensor.range_noise",
    "odometry", "odometry.noise", "odometry.noise.translation",
    "mapping_route", "mapping_route.waypoints", "mapping_route.waypoints.1", "mapping_route.auto",
    "mapping_route.auto.min_length",
    "trials", "trials.0", "trials.0.start", "trials.0.goal", "trials.generate", "trials.generate.count",
]  # fmt: skip
VALUES = st.sampled_from(
    [-1, 0, 1, 3, 0.5, 2.5, 1e-300, 1e308, float("inf"), float("nan"), 2**64, -(2**70), "x", "", "1e-3",
     True, None, [], [1], [1, 2], [1, 2, 3], [[0, 0], [1, 1]], {}, {"a": 1}, {"count": 2}, {"min_length": 3}]
)  # fmt: skip


def set_path(spec: dict, path: str, value: Any) -> None:
    node: Any = spec
    parts = path.split(".")
    for part in parts[:-1]:
        key: Any = part
        if isinstance(node, list):
            if not (part.isdigit() and int(part) < len(node)):
                return
            key = int(part)
        elif not isinstance(node.get(key), dict | list):
            node[key] = {}
        node = node[key]
    last: Any = parts[-1]
    if isinstance(node, list):
        if last.isdigit() and int(last) < len(node):
            node[int(last)] = value
    elif isinstance(node, dict):
        node[last] = value


@st.composite
def scenario_texts(draw) -> bytes:
    """A scenario file: the valid base with keys set to odd values, then perhaps its text mangled."""
    spec = copy.deepcopy(BASE)
    for path, value in draw(st.lists(st.tuples(st.sampled_from(KEYS), VALUES), max_size=3)):
        set_path(spec, path, value)
    text = yaml.safe_dump(spec, sort_keys=False)
    how = draw(st.sampled_from(["as is", "as is", "truncated", "line twice", "tab", "bytes", "exponent"]))
    if how == "truncated":
        text = text[: draw(st.integers(0, len(text)))]
    elif how == "line twice":
        lines = text.splitlines(keepends=True)
        i = draw(st.integers(0, len(lines) - 1))
        text = "".join(lines[: i + 1] + lines[i:])
    elif how == "tab":
        text = text.replace("  ", "\t", 1)
    elif how == "exponent":
        text = text.replace("2.0", "2e0").replace("0.3", "3E-1")
    elif how == "bytes":
        return draw(st.binary(max_size=64))
    return text.encode()


def answer(result, *, allowed=(0, 2)) -> str:
    """The checks every outcome passes; returns the error line ('' when none)."""
    output = result.output
    assert result.exit_code in allowed, (result.exit_code, output, result.exception)
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in output, output
    if result.exit_code == 0:
        return ""
    errors = [line for line in output.splitlines() if line.startswith("error:")]
    usage = "Usage:" in output and ("Invalid value" in output or "No such option" in output or "Missing" in output)
    assert len(errors) == 1 or (not errors and usage), output
    return errors[0] if errors else "usage"


def listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@FUZZ
@given(text=scenario_texts())
def test_any_scenario_file_is_validated_or_refused_in_one_line(tmp_path, text):
    path = tmp_path / "s.yaml"
    path.write_bytes(text)
    before = listing(tmp_path)
    result = CliRunner().invoke(app, ["scenario", "validate", str(path)])
    assert result.exit_code in (0, 2) and "Traceback" not in result.output, result.output
    lines = [line for line in result.output.splitlines() if line.strip() and not line.startswith("note: ")]
    assert lines == [f"{path}: ok"] if result.exit_code == 0 else len(lines) == 1 and lines[0].startswith(f"{path}: ")
    assert listing(tmp_path) == before


CONFIGS = {
    "missing": None,
    "folder": "FOLDER",
    "binary": b"\x00\xff\x13",
    "duplicate": b"oracle: {}\noracle: {}\n",
    "syntax": b"oracle: [\n",
    "list": b"- oracle\n",
    "unknown system": b"nope: {}\n",
    "bad key": b"oracle: {bogus: 1}\n",
    "bad descriptor": b"navtopo: {descriptor: nope}\n",
    "not a mapping": b"oracle: 3\n",
    "good": b"oracle: {}\n",
}
FLAGS = {
    "--systems": ["oracle", "", " , ", "nope", "oracle,oracle", "oracle,navtopo"],
    "--seed": ["-1", "0", "7", "abc", str(2**70)],
    "--seeds": ["", ",", "1,2", "x", "3,-3", "1,1"],
    "--trials": ["0", "1", "-1", "abc"],
    "--workers": ["0", "1", "2"],
    "--setting": ["precise", "nope", ",", "precise,noisy", "noisy,noisy"],
    "--initial-pose-error": ["0,0", "-1,2", "a", "1,2,3", "inf,1", "nan,0"],
    "--stop-tolerance": ["0", "0.35", "-1", "nan", "inf", "0.6"],
    "--trial-timeout-s": ["60", "0", "nan", "inf"],
    "--trial-memory-mb": ["512", "0", "nan", "inf", "1e300"],
    "--goals": ["map", "x"],
    "--executor": ["local", "ray", "x"],
}


@FUZZ
@given(
    scenario=st.sampled_from(["tiny", "missing.yaml", "FOLDER", "GARBAGE"]),
    flags=st.dictionaries(st.sampled_from(sorted(FLAGS)), st.integers(0, 5), max_size=4),
    config=st.sampled_from([None, *CONFIGS]),
    out=st.sampled_from([None, "fresh", "a file", "under a file", "holds a run"]),
)
def test_run_refuses_any_bad_input_in_one_line_before_creating_anything(tmp_path, monkeypatch, scenario, flags, config, out):
    """`run` either reaches the run (here a double that checks the options can be stored and stops)
    or refuses with one line, leaving the folders as they were."""
    import runners.run

    def reached(plans, pool, on_jobs=None):
        for plan in plans:
            json.dumps(plan.options.protocol.as_json(), allow_nan=False)  # what the manifest will store
            assert all(isinstance(s, int) and s >= 0 for s in [plan.options.seed] if s is not None)
        raise SystemExit(0)

    monkeypatch.setattr(runners.run, "execute_runs", reached)
    work = tmp_path / "work"
    shutil.rmtree(work, ignore_errors=True)
    (work / "FOLDER").mkdir(parents=True)
    (work / "GARBAGE").write_bytes(b"\xff\x00garbage")
    (work / "a file").write_text("")
    (work / "holds a run").mkdir()
    (work / "holds a run" / "manifest.json").write_text("{}")
    args = ["run", scenario if scenario == "tiny" else str(work / scenario), "--results", str(work / "results")]
    for flag, index in flags.items():
        args += [flag, FLAGS[flag][index % len(FLAGS[flag])]]
    if config is not None:
        content = CONFIGS[config]
        path = work / "FOLDER" if content == "FOLDER" else work / f"{config}.yaml"
        if isinstance(content, bytes):
            path.write_bytes(content)
        args += ["--config", str(path)]
    if out is not None:
        args += ["--out", str(work / out / "run" if out == "under a file" else work / out)]
    before = listing(work)
    answer(CliRunner().invoke(app, args))
    assert listing(work) == before


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=4),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=8,
)


@FUZZ
@given(
    manifest=st.one_of(st.binary(max_size=32), JSON_VALUES.map(lambda v: json.dumps(v).encode())),
    summary=st.one_of(st.binary(max_size=32), JSON_VALUES.map(lambda v: json.dumps(v).encode())),
)
def test_resume_and_report_on_any_run_folder_answer_in_one_line(tmp_path, manifest, summary):
    run = tmp_path / "run"
    shutil.rmtree(run, ignore_errors=True)
    run.mkdir()
    (run / "manifest.json").write_bytes(manifest)
    (run / "summary.json").write_bytes(summary)
    answer(CliRunner().invoke(app, ["run", "--resume", str(run)]), allowed=(2,))
    assert listing(run) == ["manifest.json", "summary.json"]
    if answer(CliRunner().invoke(app, ["report", str(run)])):
        assert listing(run) == ["manifest.json", "summary.json"]


def test_the_fuzzed_base_scenario_is_valid(tmp_path):
    """The fuzz starts from a valid file, so that each mutation is what makes it fail."""
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(BASE))
    result = CliRunner().invoke(app, ["scenario", "validate", str(tmp_path / "s.yaml")])
    assert result.exit_code == 0, result.output
