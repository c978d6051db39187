"""Issue 14: every bad input is one clear line and a non-zero exit (never a traceback, a hang or
a navigation result), Ctrl-C stops, nothing is overwritten or half-written."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from runners.cli import app
from scenarios import ScenarioError, load_scenario
from scenarios.schema import MAX_RAYS_PER_SCAN

ROOT = Path(__file__).resolve().parent.parent
TINY = ROOT / "scenarios" / "bundled" / "tiny.yaml"


def small(**overrides) -> dict:
    """A straight 10 m corridor, a short route, one trial: loads in well under a second."""
    spec = {
        "format": "navtopo-scenario/1",
        "name": "t",
        "world": {"corridors": [{"points": [[0, 0], [10, 0]], "width": 2.0}]},
        "mapping_route": {"waypoints": [[1, 0], [9, 0]]},
        "trials": [{"start": [1, 0, 0], "goal": [9, 0]}],
    }
    for key, value in overrides.items():
        section, _, sub = key.partition("__")
        if sub:
            spec.setdefault(section, {})[sub] = value
        else:
            spec[section] = value
    return spec


def write(tmp_path: Path, spec: dict | str, name: str = "s.yaml") -> Path:
    path = tmp_path / name
    path.write_text(spec if isinstance(spec, str) else yaml.safe_dump(spec))
    return path


def refused(path: Path) -> str:
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: "), message
    return message


def one_line_error(result, code: int = 2) -> str:
    """The CLI refused with one `error:` line and no traceback; returns that line."""
    assert result.exit_code == code, (result.exit_code, result.output, result.exception)
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    lines = [line for line in result.output.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    assert len(errors) == 1, result.output
    assert "Traceback" not in result.output
    return errors[0]


# ---------------------------------------------------------------------------------------------
# scenario files


def test_a_binary_file_is_one_line_not_a_unicode_error(tmp_path):
    path = tmp_path / "garbage.yaml"
    path.write_bytes(bytes(range(256)) * 4)
    assert "not a text file" in refused(path)
    path.write_bytes(b"name: \xff\xfe\xfa")
    assert "not a UTF-8 text file" in refused(path)


def test_a_duplicated_key_is_refused_with_its_line(tmp_path):
    text = TINY.read_text().replace("seed: 1\n", "seed: 1\nseed: 2\n")
    assert "duplicate key 'seed'" in refused(write(tmp_path, text))


@pytest.mark.parametrize("written", ["1e-300", "1E-3", "2.5e-2"])
def test_numbers_in_exponent_form_are_numbers(tmp_path, written):
    path = write(tmp_path, TINY.read_text().replace("range_noise: 0.0", f"range_noise: {written}"))
    assert load_scenario(path, with_trials=False).spec.sensor.range_noise == float(written)


def test_an_exponent_beyond_float_is_not_finite(tmp_path):
    path = write(tmp_path, TINY.read_text().replace("max_range: 15.0", "max_range: 1e999"))
    assert "sensor.max_range: " in refused(path) and "finite" in refused(path)


def test_a_map_yaml_syntax_error_is_one_line_naming_the_map_file(tmp_path):
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: [0.05\norigin: [0, 0, 0]\n")
    path = write(tmp_path, small(world={"map": {"yaml": "m.yaml"}}))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert "\n" not in str(info.value) and str(info.value).startswith(f"{tmp_path / 'm.yaml'}: line ")


def test_a_map_path_that_is_a_folder_says_so(tmp_path):
    (tmp_path / "m.yaml").mkdir()
    assert "is a folder" in refused(write(tmp_path, small(world={"map": {"yaml": "m.yaml"}})))


def test_a_huge_map_image_is_refused_from_its_header(tmp_path):
    (tmp_path / "m.pgm").write_bytes(b"P5\n30000 30000\n255\n")  # 900 M pixels, never decoded
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    path = write(tmp_path, small(world={"map": {"yaml": "m.yaml"}}))
    with pytest.raises(ScenarioError, match="too large"):
        load_scenario(path)


def test_a_goal_outside_the_map_is_outside_not_in_a_wall(tmp_path):
    message = refused(write(tmp_path, small(trials=[{"start": [1, 0, 0], "goal": [120, 7]}])))
    assert "trials.0.goal: " in message and "outside the map" in message and "wall" not in message


@pytest.mark.parametrize(
    ("overrides", "key", "reason"),
    [
        ({"sensor__horizontal_resolution": 0.0001}, "sensor", f"{MAX_RAYS_PER_SCAN:,}"),
        ({"sensor__rate_hz": 0.001}, "sensor.rate_hz", "greater than or equal to 1"),
        ({"sensor__rate_hz": 1e6}, "sensor.rate_hz", "less than or equal to 50"),
        ({"sensor__mount_height": 3.0}, "sensor.mount_height", "over the walls"),
        ({"world__wall_height": 0.5, "sensor__mount_height": 0.6}, "sensor.mount_height", "over the walls"),
        ({"robot__max_linear": 100.0}, "robot", "collision check"),
        ({"seed": -1}, "seed", "greater than or equal to 0"),
        ({"trials": [{"start": [1, 0, 0], "goal": [1, 0]}]}, "trials.0.goal", "without moving"),
        ({"trials": [{"start": [1, 0, 0], "goal": [1.3, 0.2]}]}, "trials.0.goal", "goal tolerance"),
        ({"mapping_route": {"waypoints": [[1, 0], [1.2, 0]]}}, "mapping_route", "at least"),
        ({"mapping_route": {"auto": {"min_length": 1e12}}}, "mapping_route.auto.min_length", "less than or equal"),
    ],
)
def test_inputs_that_would_hang_or_fail_later_are_refused_in_validation(tmp_path, overrides, key, reason):
    message = refused(write(tmp_path, small(**overrides)))
    assert message.startswith(f"{tmp_path / 's.yaml'}: {key}: "), message
    assert reason in message, message


def test_a_route_leg_through_a_wall_is_reported_as_rerouted(tmp_path):
    spec = small(
        world={"corridors": [{"points": [[0, 0], [10, 0], [10, 8], [0, 8]], "width": 2.0}]},
        mapping_route={"waypoints": [[1, 0], [1, 8]]},
        trials=[],
    )
    path = write(tmp_path, spec)
    scenario = load_scenario(path)
    assert len(scenario.notes) == 1 and "mapping_route.waypoints.1" in scenario.notes[0]
    assert "8.0 m straight" in scenario.notes[0] and "re-routed" in scenario.notes[0]
    result = CliRunner().invoke(app, ["scenario", "validate", str(path)])
    assert result.exit_code == 0 and "re-routed" in result.output


# ---------------------------------------------------------------------------------------------
# files


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_results_and_maps_are_written_with_the_users_umask(tmp_path, umask):
    import os

    import numpy as np

    from navkit.files import atomic_write
    from runners.results import write_json, write_tum

    old = os.umask(umask)
    try:
        write_json(tmp_path / "a" / "manifest.json", {"x": 1})
        write_tum(tmp_path / "a" / "trial-0.tum", np.zeros((2, 4)))
        atomic_write(tmp_path / "a" / "graph.json", b"{}")
    finally:
        os.umask(old)
    for name in ("manifest.json", "trial-0.tum", "graph.json"):
        assert (tmp_path / "a" / name).stat().st_mode & 0o777 == 0o666 & ~umask, name
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["graph.json", "manifest.json", "trial-0.tum"]


# ---------------------------------------------------------------------------------------------
# the command line: answers at once, one line per refusal, nothing written on refusal


def test_version_and_help_answer_without_the_heavy_modules():
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from typer.testing import CliRunner\n"
        "from runners.cli import app\n"
        "for args in (['--help'], ['run', '--help'], ['--version']):\n"
        "    assert CliRunner().invoke(app, args).exit_code == 0, args\n"
        "print(CliRunner().invoke(app, ['--version']).output.strip())\n"
        "print(sorted(m for m in ('torch', 'scipy', 'shapely', 'numba', 'pybullet', 'cv2', 'matplotlib') if m in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert done.returncode == 0, done.stderr
    version, heavy = done.stdout.splitlines()
    assert version.startswith("navtopo-bench ") and heavy == "[]"


@pytest.mark.parametrize("args", [["--help"], ["scenario", "show", "--help"], ["scenario", "render", "--help"]])
def test_help_gives_flags_no_value_placeholder(args):
    """A flag takes no value: the help lists `--version`, `--json`, `--help` with no type label
    (typer's panels would show `<bool>`), an option that takes one keeps its label."""
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    rows = {cells[0]: cells[1:] for line in result.output.splitlines() if (cells := line.strip("│ *").split())}
    flags = [flag for flag in ("--help", "--version", "--json", "--no-route") if flag in rows]
    assert "--help" in flags and len(flags) >= 2, result.output
    assert all(not rows[flag][0].startswith("<") for flag in flags) and "<bool>" not in result.output, result.output
    assert "<path>" in rows.get("--output", ["<path>"])


@pytest.mark.parametrize("target", ["blocker/out.png", "blocker", "folder", "out.txt"])
def test_render_refuses_an_output_it_cannot_write_before_loading(tmp_path, target):
    (tmp_path / "blocker").write_text("a file where a folder would be")
    (tmp_path / "folder").mkdir()
    before = sorted(tmp_path.rglob("*"))
    result = CliRunner().invoke(app, ["scenario", "render", "tiny", "-o", str(tmp_path / target)])
    line = one_line_error(result)
    assert f"-o {tmp_path / target}" in line
    assert sorted(tmp_path.rglob("*")) == before


def test_plot_graph_refuses_an_output_under_a_file(tmp_path):
    (tmp_path / "run" / "maps" / "navtopo").mkdir(parents=True)
    (tmp_path / "blocker").write_text("")
    result = CliRunner().invoke(app, ["plot-graph", str(tmp_path / "run"), "-o", str(tmp_path / "blocker" / "g.png")])
    assert "is a file, not a folder" in one_line_error(result)


@pytest.mark.parametrize("summary", [b"{", b"\xff\xfe", b"[]", b'{"navtopo": 3}', b'{"navtopo": {"memory": 3}}'])
def test_report_on_a_corrupt_summary_is_one_line_and_writes_no_table(tmp_path, summary):
    import shutil

    from crafted_run import write_crafted_run

    good = write_crafted_run(tmp_path / "good")
    bad = tmp_path / "bad"
    shutil.copytree(good, bad)
    (bad / "summary.json").write_bytes(summary)
    line = one_line_error(CliRunner().invoke(app, ["report", str(good), str(bad)]))
    assert line.startswith("error: ") and str(bad / "summary.json") in line
    assert not (good / "report").exists() and not (bad / "report").exists()


@pytest.mark.parametrize(
    ("flags", "reason"),
    [
        (["--descriptors", "nope"], "unknown descriptor(s) nope"),
        (["--descriptors", " , "], "at least one descriptor"),
        (["--spacing", "0"], "--spacing 0.0"),
        (["--spacing", "-1"], "--spacing -1.0"),
        (["--spacing", "nan"], "--spacing nan"),
        (["--min-gap", "0"], "recall radius"),
        (["--min-gap", "2"], "recall radius"),
    ],
)
def test_eval_place_recognition_refuses_flags_that_crash_or_measure_nothing(flags, reason):
    result = CliRunner().invoke(app, ["eval-place-recognition", "tiny", *flags])
    assert reason in one_line_error(result)


def run_refused(tmp_path, *args: str) -> str:
    """`run` refused with one line, and nothing created: no results folder, no `latest`."""
    results = tmp_path / "results"
    result = CliRunner().invoke(app, ["run", "tiny", "--systems", "oracle,navtopo", "--results", str(results), *args])
    line = one_line_error(result)
    assert not results.exists(), sorted(results.rglob("*"))
    return line


def test_run_with_a_config_that_is_a_folder_or_bad_yaml_is_one_line(tmp_path):
    (tmp_path / "folder").mkdir()
    assert "is a folder" in run_refused(tmp_path, "--config", str(tmp_path / "folder"))
    (tmp_path / "dup.yaml").write_text("oracle: {}\noracle: {}\n")
    assert "line 2: duplicate key 'oracle'" in run_refused(tmp_path, "--config", str(tmp_path / "dup.yaml"))
    (tmp_path / "bin.yaml").write_bytes(b"\x00\x01\x02")
    assert "not a text file" in run_refused(tmp_path, "--config", str(tmp_path / "bin.yaml"))
    assert "no such file" in run_refused(tmp_path, "--config", str(tmp_path / "missing.yaml"))


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (["--seed", "-1"], "--seed -1: a seed is a non-negative integer"),
        (["--seeds", "3,-2"], "--seeds -2"),
        (["--seeds", ","], "at least one seed"),
        (["--systems", ""], "at least one system"),
        (["--systems", " , "], "at least one system"),
        (["--systems", "oracle,oracle"], "named twice"),
        (["--seeds", "1,2,1"], "--seeds '1,2,1': a seed is given twice"),
        (["--setting", "noisy,precise,noisy"], "a setting is named twice"),
        (["--stop-tolerance", "nan"], "--stop-tolerance nan: expected a finite number of metres, 0.01 to 0.5"),
        (["--stop-tolerance", "1e9"], "--stop-tolerance 1e+09: expected a finite number of metres, 0.01 to 0.5"),
        (["--stop-tolerance", "inf"], "--stop-tolerance inf: expected a finite number"),
        (["--stop-tolerance", "-0.5"], "--stop-tolerance -0.5: expected a finite number"),
        (["--trial-timeout-s", "nan"], "--trial-timeout-s nan: expected a number of seconds, at least 1"),
        (["--trial-memory-mb", "inf"], "--trial-memory-mb inf: expected a finite number of MB"),
        (["--trial-memory-mb", "1e300"], "--trial-memory-mb 1e+300: expected a finite number of MB"),
    ],
)
def test_run_refuses_bad_flags_before_creating_anything(tmp_path, args, reason):
    results = tmp_path / "results"
    line = one_line_error(CliRunner().invoke(app, ["run", "tiny", "--results", str(results), *args]))
    assert reason in line and not results.exists()


def test_a_config_naming_an_unknown_descriptor_is_refused_before_the_run_folder(tmp_path):
    config = tmp_path / "c.yaml"
    config.write_text("navtopo: {descriptor: nope}\n")
    line = run_refused(tmp_path, "--config", str(config))
    assert f"--config {config}: navtopo.descriptor: " in line and "unknown place descriptor 'nope'" in line


def test_run_out_under_a_file_is_refused(tmp_path):
    (tmp_path / "blocker").write_text("")
    assert "is a file, not a folder" in run_refused(tmp_path, "--out", str(tmp_path / "blocker" / "run"))
    assert "is a file, not a folder" in run_refused(tmp_path, "--out", str(tmp_path / "blocker"))


@pytest.mark.parametrize(
    ("manifest", "reason"),
    [
        (b"{", "not valid JSON"),
        (b"{}", "scenario.file missing"),
        (b"[]", "not a JSON object"),
        (b'{"scenario": {"file": "tiny"}, "systems": ["nope"], "seed": 1, "config": {}}', "unknown system(s) nope"),
        (b'{"scenario": {"file": "tiny"}, "systems": ["oracle"], "seed": "1", "config": {}}', "seed"),
        (b'{"scenario": {"file": "tiny"}, "systems": ["oracle"], "seed": 1, "config": {}}', "config of a system"),
    ],
)
def test_resume_of_a_corrupt_manifest_is_one_line_and_touches_nothing(tmp_path, manifest, reason):
    run = tmp_path / "run"
    run.mkdir()
    (run / "manifest.json").write_bytes(manifest)
    line = one_line_error(CliRunner().invoke(app, ["run", "--resume", str(run)]))
    assert line.startswith(f"error: --resume {run / 'manifest.json'}: ") and reason in line and "cannot be resumed" in line
    assert sorted(p.name for p in run.iterdir()) == ["manifest.json"]


# ---------------------------------------------------------------------------------------------
# Ctrl-C


def wait_for(predicate, timeout: float) -> bool:
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.1)
    return False


def ctrl_c(process, wait_s: float = 30.0) -> None:
    """SIGINT to a driver: it must exit 130, in less than 10 s."""
    import signal
    import time

    process.send_signal(signal.SIGINT)
    started = time.monotonic()
    assert process.wait(timeout=wait_s) == 130
    assert time.monotonic() - started < 10


def write_slow_job(folder) -> None:
    """``slow_job.job(marker)``: writes the marker, then sleeps a minute before its one message."""
    (folder / "slow_job.py").write_text(
        "import time\nfrom pathlib import Path\n\n\n"
        "def job(marker):\n    Path(marker).write_text('started')\n    time.sleep(60)\n    yield {}\n"
    )


def test_ctrl_c_ends_the_running_worker_and_cancels_the_queued_jobs(tmp_path):
    import subprocess
    import sys
    import time

    write_slow_job(tmp_path)
    driver = (
        "import sys\n"
        f"sys.path.insert(0, {str(tmp_path)!r})\n"
        "import slow_job\n"
        "from runners.executors import LocalExecutor\n"
        f"markers = [{str(tmp_path / 'a')!r}, {str(tmp_path / 'b')!r}]\n"
        "with LocalExecutor(1) as pool:\n"
        "    for marker in markers:\n"
        "        pool.submit(marker, slow_job.job, marker)\n"
        "    try:\n"
        "        for _ in pool.events():\n"
        "            pass\n"
        "    except KeyboardInterrupt:\n"
        "        sys.exit(130)\n"
    )
    process = subprocess.Popen([sys.executable, "-c", driver], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: (tmp_path / "a").exists(), 60), "the first job never started"
        ctrl_c(process, wait_s=20)
    finally:
        process.kill()
    assert "Traceback" not in process.stderr.read()
    time.sleep(1.0)
    assert not (tmp_path / "b").exists(), "a queued job ran after Ctrl-C"


def test_a_second_ctrl_c_does_not_cut_the_cleanup_short(tmp_path):
    """Cleanup can take seconds (a private Ray instance shutting down; here a kill made slow): Ctrl-C
    pressed again meanwhile is ignored, the cleanup finishes and the driver exits 130, no traceback."""
    import signal
    import subprocess
    import sys

    write_slow_job(tmp_path)
    driver = (
        "import sys, time\n"
        "from pathlib import Path\n"
        f"sys.path.insert(0, {str(tmp_path)!r})\n"
        "import slow_job\n"
        "from runners.executors import LocalExecutor\n"
        f"folder = Path({str(tmp_path)!r})\n"
        "class SlowToClean(LocalExecutor):\n"
        "    def _kill(self, run):\n"
        "        (folder / 'cleaning').write_text('')\n"
        "        time.sleep(3.0)\n"
        "        super()._kill(run)\n"
        "        (folder / 'cleaned').write_text('')\n"
        "try:\n"
        "    with SlowToClean(1) as pool:\n"
        "        pool.submit('a', slow_job.job, str(folder / 'a'))\n"
        "        for _ in pool.events():\n"
        "            pass\n"
        "except KeyboardInterrupt:\n"
        "    sys.exit(130)\n"
    )
    process = subprocess.Popen([sys.executable, "-c", driver], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: (tmp_path / "a").exists(), 60), "the job never started"
        process.send_signal(signal.SIGINT)
        assert wait_for(lambda: (tmp_path / "cleaning").exists(), 20), "no cleanup began"
        process.send_signal(signal.SIGINT)  # again, while it cleans up
        assert process.wait(timeout=30) == 130
    finally:
        process.kill()
    assert "Traceback" not in process.stderr.read()
    assert (tmp_path / "cleaned").exists(), "the second Ctrl-C cut the cleanup short"


@pytest.mark.long
def test_ctrl_c_during_trials_exits_130_and_the_run_resumes_with_nothing_lost(tmp_path):
    import json
    import subprocess
    import sys

    from test_scaleout import short_tiny

    out = tmp_path / "run"
    command = [sys.executable, "-m", "runners.cli", "run", str(short_tiny(tmp_path)), "--systems", "oracle", "--out", str(out)]
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    trials = out / "trials.jsonl"
    try:
        assert wait_for(lambda: trials.is_file() and trials.read_text().count("\n") >= 1, 400), "no trial finished"
        if process.poll() is None:
            ctrl_c(process)
            stderr = process.stderr.read()
            assert "Traceback" not in stderr and f"--resume {out}" in one_line_error_text(stderr)
            assert not (out / "summary.json").exists()
    finally:
        process.kill()
    before = [json.loads(line) for line in trials.read_text().splitlines() if line.strip()]

    result = CliRunner().invoke(app, ["run", "--resume", str(out)])
    assert result.exit_code == 0, result.output
    records = [json.loads(line) for line in trials.read_text().splitlines() if line.strip()]
    assert sorted(r["trial"] for r in records) == [0, 1, 2]  # none lost, none twice
    assert records[: len(before)] == before  # the trials finished before Ctrl-C are kept as they were
    assert json.loads((out / "summary.json").read_text())["oracle"]["trials"] == 3


def one_line_error_text(stderr: str) -> str:
    errors = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, stderr
    return errors[0]


# ---------------------------------------------------------------------------------------------
# runs


@pytest.mark.long
def test_a_map_that_cannot_be_loaded_is_a_failed_stage_not_failed_trials(tmp_path):
    import json
    import shutil

    from test_scaleout import short_tiny

    first, second = tmp_path / "first", tmp_path / "second"
    scenario = str(short_tiny(tmp_path))  # the oracle maps nothing: a 3 m route
    result = CliRunner().invoke(app, ["run", scenario, "--systems", "oracle", "--trials", "0", "--out", str(first)])
    assert result.exit_code == 0, result.output
    assert f"no trials run (--trials 0): navigate these maps with --maps-from {first}" in result.output
    assert "success" not in result.output  # no empty table
    route_m = round(load_scenario(scenario, with_trials=False).route_length_m)
    assert f"{route_m}/{route_m}" in result.output  # the mapping bar ends full, with no trials to fill it
    (first / "maps" / "oracle" / "oracle.json").unlink()  # a damaged map folder
    result = CliRunner().invoke(
        app, ["run", scenario, "--systems", "oracle", "--trials", "2", "--maps-from", str(first), "--out", str(second)]
    )
    line = one_line_error(result, code=1)
    assert "navigation stage failed" in line and "oracle: the map in " in line and f"--resume {second}" in line
    assert "maps/oracle: not an oracle map folder" in line and "navtopo-job" not in line  # not the job's temporary copy
    assert not (second / "trials.jsonl").exists() or not (second / "trials.jsonl").read_text().strip()
    assert not (second / "summary.json").exists()  # unfinished: `report` refuses it, --resume retries

    shutil.copytree(first / "maps" / "oracle", second / "maps" / "oracle", dirs_exist_ok=True)
    (second / "maps" / "oracle" / "oracle.json").write_text("{}")  # repaired
    result = CliRunner().invoke(app, ["run", "--resume", str(second)])
    assert result.exit_code == 0, result.output
    assert "mapping (m)" not in result.output  # every map is there: no mapping bar stuck at 0
    assert json.loads((second / "summary.json").read_text())["oracle"]["trials"] == 2


def test_training_never_overwrites_weights_and_defaults_to_a_new_folder(tmp_path):
    from navtopo.place_recognition import WEIGHTS_DIR
    from runners.place_recognition_data import default_training_out

    shipped = WEIGHTS_DIR / "minkloc3d.pt"
    stamp = shipped.stat().st_mtime_ns
    line = one_line_error(CliRunner().invoke(app, ["train-descriptor", "--out", str(WEIGHTS_DIR), "--data-dir", str(tmp_path)]))
    assert "already holds minkloc3d.pt" in line and shipped.stat().st_mtime_ns == stamp
    default = default_training_out("minkloc3d")
    assert not default.is_absolute() and default.parts[0] == "weights" and default.name.startswith("minkloc3d-")
    (tmp_path / "file").write_text("")
    assert "is a file" in one_line_error(CliRunner().invoke(app, ["train-descriptor", "--out", str(tmp_path / "file")]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_the_map_frame_beside_the_estimates_takes_them_into_the_scenario_frame(tmp_path):
    import json

    import numpy as np

    from navkit import geometry as se2
    from runners.results import write_map_frame

    world_from_map = np.array([3.0, -2.0, np.radians(40.0)])
    write_map_frame(tmp_path / "map_frame.json", world_from_map)
    t = json.loads((tmp_path / "map_frame.json").read_text())
    assert {"x", "y", "z", "qx", "qy", "qz", "qw"} <= set(t)  # evo's transform keys
    yaw = 2 * np.arctan2(t["qz"], t["qw"])
    rotation = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    estimate_in_map = np.array([5.0, 1.0, 0.3])
    in_scenario = rotation @ estimate_in_map[:2] + [t["x"], t["y"]]
    assert in_scenario == pytest.approx(se2.compose(world_from_map, estimate_in_map)[:2])
    assert t["yaw_deg"] == pytest.approx(40.0)


def test_trials_0_with_maps_from_would_run_nothing_and_is_refused(tmp_path):
    assert "would run nothing" in run_refused(tmp_path, "--trials", "0", "--maps-from", str(tmp_path / "earlier"))


def test_pybullet_prints_no_banner():
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", "import runners.sim"], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0 and done.stdout == "" and done.stderr == "", done.stderr


@pytest.mark.parametrize("name", ["metric_grid", "navtopo"])
def test_scans_with_no_returns_are_mapped_without_error(name):
    """Open space beyond the lidar's range gives scans with no returns: every system maps on."""
    import numpy as np

    from navkit.types import Observation
    from runners.systems import SystemContext, get_system

    tiny = load_scenario(TINY, with_trials=False)
    entry = get_system(name)
    system = entry.create(entry.config_model(), SystemContext(robot=tiny.spec.robot, sensor=tiny.spec.sensor))
    for i in range(12):
        system.observe(Observation(stamp=0.2 * i, points=np.zeros((0, 3), np.float32), odom=np.array([0.2 * i, 0.0, 0.0])))
    system.finish_mapping()
    assert system.mapping_stats()["map_bytes"] >= 0


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (["run", "tiny", "--trials", "-1"], "Invalid value for '--trials'"),
        (["run", "tiny", "--workers", "0"], "Invalid value for '--workers'"),
        (["run", "tiny", "--workers", "100000"], "--workers 100000: more than 4 per core"),
        (["sweep", "drift", "--workers", "100000"], "--workers 100000: more than 4 per core"),
        (["run", "tiny", "--seed", "abc"], "Invalid value for '--seed'"),
        (["run", "tiny", "--bogus"], "No such option: --bogus"),
        (["nope"], "No such command 'nope'"),
    ],
)
def test_usage_errors_of_the_command_are_one_line_too(args, reason):
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "runners.cli", *args], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert done.returncode == 2 and done.stdout == ""
    assert len(done.stderr.splitlines()) == 1 and done.stderr.startswith("error: ") and reason in done.stderr, done.stderr


def test_a_map_image_that_is_not_an_image_is_one_line(tmp_path):
    (tmp_path / "m.pgm").write_bytes(b"not an image at all")
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(ScenarioError) as info:
        load_scenario(write(tmp_path, small(world={"map": {"yaml": "m.yaml"}})))
    assert str(info.value) == f"{tmp_path / 'm.yaml'}: image: cannot decode map image m.pgm"
