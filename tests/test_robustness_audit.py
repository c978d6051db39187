"""Issue 14, audited as a new user would try it: inputs the first pass let through (map_server
thresholds, read-only folders as root, sweep flags, a run folder named twice, config knobs that
validate and then fail the mapping stage), each one line and a non-zero exit with nothing created."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from test_robustness import one_line_error, small, write
from typer.testing import CliRunner

from runners.cli import app


def map_scenario(tmp_path: Path, **meta) -> Path:
    """A scenario on a 4 x 4 m map_server map (free inside a wall border), its YAML keys overridden."""
    import numpy as np
    from PIL import Image

    image = np.full((80, 80), 254, np.uint8)
    image[:2], image[-2:], image[:, :2], image[:, -2:] = 0, 0, 0, 0
    Image.fromarray(image).save(tmp_path / "m.pgm")
    keys = {"image": "m.pgm", "resolution": 0.05, "origin": [0.0, 0.0, 0.0], "occupied_thresh": 0.65, "free_thresh": 0.25}
    keys.update(meta)
    (tmp_path / "m.yaml").write_text("".join(f"{key}: {value}\n" for key, value in keys.items()))
    spec = small(world={"map": {"yaml": "m.yaml"}}, mapping_route={"waypoints": [[1, 1], [3, 3]]}, trials=[])
    return write(tmp_path, spec)


def refused_by_main(monkeypatch, capsys, *args: str) -> str:
    """The command (its entry point, which makes usage errors one line too) refused with one
    `error:` line on stderr and exit 2; returns that line."""
    import sys

    from runners.cli import main

    monkeypatch.setattr(sys, "argv", ["navtopo-bench", *args])
    code = main()
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and len(err.splitlines()) == 1 and err.startswith("error: "), (code, out, err)
    return err


@pytest.fixture
def read_only() -> Path:
    """A folder this process cannot write: os.access answers yes to root everywhere, so as root
    the folder is /sys (sysfs refuses new files even to root)."""
    if os.geteuid() != 0:
        pytest.skip("as a user, a folder's mode is what refuses (tests/test_robustness.py)")
    try:
        Path("/sys/navtopo-probe").touch()
    except OSError:
        return Path("/sys")
    Path("/sys/navtopo-probe").unlink()
    pytest.skip("/sys is writable here")


# ---------------------------------------------------------------------------------------------
# map_server maps


@pytest.mark.parametrize(
    ("meta", "key", "reason"),
    [
        ({"occupied_thresh": 2}, "occupied_thresh", "between 0 and 1"),
        ({"occupied_thresh": "high"}, "occupied_thresh", "finite number"),
        ({"free_thresh": 1.5}, "free_thresh", "between 0 and 1"),  # every unknown pixel would be free
        ({"free_thresh": -0.1}, "free_thresh", "between 0 and 1"),
        ({"free_thresh": 0.9}, "free_thresh", "not below occupied_thresh 0.65"),
        ({"image": "."}, "image", "is a folder"),
    ],
)
def test_a_map_yaml_out_of_map_servers_ranges_is_refused_naming_its_key(tmp_path, meta, key, reason):
    from scenarios import ScenarioError, load_scenario

    with pytest.raises(ScenarioError) as info:
        load_scenario(map_scenario(tmp_path, **meta))
    message = str(info.value)
    assert message.startswith(f"{tmp_path / 'm.yaml'}: {key}: ") and reason in message, message


def test_the_default_thresholds_and_an_rgba_png_load(tmp_path):
    import numpy as np
    from PIL import Image

    from scenarios import load_scenario

    path = map_scenario(tmp_path)
    grey = np.asarray(Image.open(tmp_path / "m.pgm"))
    Image.fromarray(np.dstack([grey, grey, grey, np.full_like(grey, 255)]), "RGBA").save(tmp_path / "m.png")
    free = load_scenario(path).world.free.sum()
    (tmp_path / "m.yaml").write_text("image: m.png\nresolution: 0.05\norigin: [0, 0, 0]\n")
    assert load_scenario(path).world.free.sum() == free


def test_a_truncated_map_image_is_our_one_line_without_opencvs_own(tmp_path, capfd):
    from scenarios import ScenarioError, load_scenario

    path = map_scenario(tmp_path)
    data = (tmp_path / "m.pgm").read_bytes()
    (tmp_path / "m.pgm").write_bytes(data[: len(data) // 3])
    with pytest.raises(ScenarioError, match="image: cannot decode map image m.pgm"):
        load_scenario(path)
    assert "ERROR" not in capfd.readouterr().err  # OpenCV prints three lines of its own by default


# ---------------------------------------------------------------------------------------------
# outputs that cannot be written, as root


@pytest.mark.parametrize(
    "args",
    [
        ["run", "tiny", "--out", "{ro}/run"],
        ["run", "tiny", "--results", "{ro}/results"],
        ["scenario", "render", "tiny", "-o", "{ro}/map.png"],
        ["train-descriptor", "--data-dir", "{ro}/data", "--out", "{tmp}/weights"],
        ["sweep", "drift", "tiny", "--out", "{ro}/drift"],
    ],
)
def test_an_output_on_a_read_only_folder_is_refused_before_any_work(tmp_path, read_only, args):
    args = [a.format(ro=read_only, tmp=tmp_path) for a in args]
    line = one_line_error(CliRunner().invoke(app, args))
    assert f"{read_only} is not writable" in line
    assert list(tmp_path.iterdir()) == []


def test_report_and_plot_graph_into_a_read_only_folder_are_refused(tmp_path, read_only):
    from crafted_run import write_crafted_run

    run = write_crafted_run(tmp_path / "run")
    for args in (["report", str(run), "--out", f"{read_only}/r"], ["plot-graph", str(run), "-o", f"{read_only}/g.png"]):
        assert f"{read_only} is not writable" in one_line_error(CliRunner().invoke(app, args))
    assert not (run / "report").exists()


@pytest.mark.parametrize(
    ("args", "reason"), [(["--threads", "0"], "--threads"), (["--minutes", "nan"], "--minutes nan: expected a")]
)
def test_training_flags_out_of_range_are_refused_before_generating_scans(tmp_path, monkeypatch, capsys, args, reason):
    line = refused_by_main(monkeypatch, capsys, "train-descriptor", *args, "--data-dir", str(tmp_path / "data"))
    assert reason in line and list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------
# files


@pytest.mark.parametrize("umask", [0o002, 0o022, 0o077])
def test_a_map_installed_from_its_job_has_the_users_umask_too(tmp_path, umask):
    from runners.payload import install_dir, pack_dir

    (tmp_path / "made" / "grids").mkdir(parents=True)
    (tmp_path / "made" / "grids" / "000000.png").write_bytes(b"png")
    old = os.umask(umask)
    try:
        install_dir(pack_dir(tmp_path / "made"), tmp_path / "maps")
    finally:
        os.umask(old)
    assert (tmp_path / "maps" / "grids").stat().st_mode & 0o777 == 0o777 & ~umask
    assert (tmp_path / "maps" / "grids" / "000000.png").stat().st_mode & 0o777 == 0o666 & ~umask


# ---------------------------------------------------------------------------------------------
# runs


def test_a_scenario_without_trials_maps_and_says_why_none_ran(tmp_path):
    spec = small()
    del spec["trials"]
    result = CliRunner().invoke(app, ["run", str(write(tmp_path, spec)), "--systems", "oracle", "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    assert f"mapped, no trials run: {tmp_path / 's.yaml'} lists no trials" in result.output and "--trials 0" not in result.output


# ---------------------------------------------------------------------------------------------
# report, eval-place-recognition


def test_a_run_folder_named_twice_is_counted_once(tmp_path):
    from crafted_run import write_crafted_run

    run = write_crafted_run(tmp_path / "20260101-000000-s1")
    (tmp_path / "latest").symlink_to(run.name)  # what `report results/tiny/*` also names
    result = CliRunner().invoke(app, ["report", str(run), str(tmp_path / "latest")])
    assert result.exit_code == 0, result.output
    assert f"note: {tmp_path / 'latest'} is the run folder {run}: counted once" in result.output
    assert "| 5/6 (83 %)" in (run / "report" / "table.md").read_text()  # navtopo's six trials, not twelve


@pytest.mark.long
def test_a_copy_of_a_run_beside_it_is_counted_once_and_a_diverged_copy_refused(tmp_path):
    import json
    import shutil

    from crafted_run import write_crafted_run

    run = write_crafted_run(tmp_path / "run")
    shutil.copytree(run, tmp_path / "backup")  # the same run twice: `report results/x/* backup/x/*`
    result = CliRunner().invoke(app, ["report", str(run), str(tmp_path / "backup"), "--out", str(tmp_path / "both")])
    assert result.exit_code == 0, result.output
    assert f"note: {tmp_path / 'backup'} is a copy of the run in {run} (the same manifest as {run}, created " in result.output
    assert "| 5/6 (83 %)" in (tmp_path / "both" / "table.md").read_text()  # navtopo's six trials, not twelve
    assert result.output.count("summary of") == 1

    trials = tmp_path / "backup" / "trials.jsonl"
    trials.write_text(trials.read_text().replace('"success": true', '"success": false', 1))  # the copy went on apart
    line = one_line_error(CliRunner().invoke(app, ["report", str(run), str(tmp_path / "backup"), "--out", str(tmp_path / "no")]))
    assert f"{tmp_path / 'backup'}: a copy of the run in {run}" in line and "with other trials: report one of them" in line
    assert not (tmp_path / "no").exists()

    manifest = json.loads((tmp_path / "backup" / "manifest.json").read_text())
    manifest["created"] = "2026-01-01T00:00:01+00:00"  # another run of the same command: both count
    (tmp_path / "backup" / "manifest.json").write_text(json.dumps(manifest))
    result = CliRunner().invoke(app, ["report", str(run), str(tmp_path / "backup"), "--out", str(tmp_path / "two")])
    assert result.exit_code == 0 and "is a copy" not in result.output, result.output
    assert "| 9/12 (75 %)" in (tmp_path / "two" / "table.md").read_text()  # the edited copy counted too


LATIN1 = os.fsdecode(b"caf\xe9")  # a folder named in Latin-1: not UTF-8 (Python keeps the byte as a surrogate)


def test_a_report_of_a_run_in_a_folder_whose_name_is_not_utf8_is_written(tmp_path):
    import json
    import subprocess

    from crafted_run import write_crafted_run

    run = write_crafted_run(tmp_path / "run").rename(tmp_path / LATIN1)  # OpenCV cannot write there: copy it in
    manifest = json.loads((run / "manifest.json").read_text())
    manifest["scenario"]["file"] = str(tmp_path / LATIN1 / "my scene.yaml")  # run from a scenario file beside it
    (run / "manifest.json").write_text(json.dumps(manifest))
    result = CliRunner().invoke(app, ["report", str(run)])
    assert result.exit_code == 0, result.output
    page = (run / "report" / "report.html").read_bytes().decode("utf-8")  # strict: the page is UTF-8
    assert f"{tmp_path}/caf\\xe9/my scene.yaml" in page  # the byte shown, not dropped
    command = next(line for line in page.splitlines() if "navtopo-bench run " in line)
    quoted = command.split("navtopo-bench run ")[1].split(" --systems")[0].replace("&#x27;", "'")
    assert quoted.startswith("$'")  # bash gives back the very bytes of the file name
    echoed = subprocess.run(["bash", "-c", f"printf %s {quoted}"], capture_output=True, check=True).stdout
    assert echoed == os.fsencode(tmp_path / LATIN1 / "my scene.yaml")
    assert "| 5/6 (83 %)" in (run / "report" / "table.md").read_text(encoding="utf-8")


def test_a_scenario_whose_map_is_in_a_folder_not_named_in_utf8_loads(tmp_path):
    from scenarios import load_scenario

    folder = tmp_path / LATIN1
    folder.mkdir()
    assert load_scenario(map_scenario(folder)).route_length_m > 0  # OpenCV, given the path, crashed the process


def test_a_report_of_an_interrupted_run_says_how_to_finish_it(tmp_path):
    from crafted_run import write_crafted_run

    run = write_crafted_run(tmp_path / "run")
    (run / "summary.json").unlink()
    assert f"`run --resume {run}` finishes it" in one_line_error(CliRunner().invoke(app, ["report", str(run)]))


def test_the_recall_table_is_rounded(monkeypatch):
    import runners.place_recognition_data as data

    recalls = {"scan_context": {"recall_at_1": 0.9574468085106383, "recall_at_5": 1.0, "queries": 47}}
    monkeypatch.setattr(data, "evaluate_scenario", lambda *args, **kwargs: recalls)
    result = CliRunner().invoke(app, ["eval-place-recognition", "tiny", "--descriptors", "scan_context"])
    assert result.exit_code == 0, result.output
    assert "0.957" in result.output and "0.9574" not in result.output and "1.000" in result.output


# ---------------------------------------------------------------------------------------------
# configs that validate and then fail the mapping stage


@pytest.mark.parametrize(
    ("config", "reason"),
    [
        ("navtopo: {grid: {resolution: 1e-300}}", "navtopo.grid: radius 15.0 m at resolution 1e-300 m"),
        ("navtopo: {grid: {radius: .inf}}", "navtopo.grid: radius inf m"),
        ("navtopo: {grid: {radius: 0.05}}", "(2 to 4096 allowed)"),
        ("metric_grid: {occupancy: {resolution: 0.001}}", "metric_grid.occupancy.resolution: "),
    ],
)
def test_a_grid_no_machine_holds_is_refused_before_the_run_folder(tmp_path, config, reason):
    (tmp_path / "c.yaml").write_text(config + "\n")
    results = tmp_path / "results"
    args = ["run", "tiny", "--systems", "navtopo,metric_grid", "--results", str(results), "--config", str(tmp_path / "c.yaml")]
    line = one_line_error(CliRunner().invoke(app, args))
    assert reason in line and "Value error" not in line and not results.exists()


# ---------------------------------------------------------------------------------------------
# sweeps


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (["scaling", "--lengths", "nan"], "--lengths: expected"),
        (["scaling", "--lengths", "inf"], "--lengths: expected"),
        (["scaling", "--lengths", "1e9"], "--lengths: expected"),
        (["scaling", "--lengths", "20"], "--lengths 20: no lattice"),
        (["scaling", "--lengths", "150,150.2"], "given twice"),
        (["scaling", "--building", "tree", "--lengths", "4000"], "--lengths 4000: a raster of"),
        (["scaling", "--route-factor", "inf"], "--route-factor inf"),
        (["scaling", "--route-factor", "nan"], "--route-factor nan: expected a finite number"),
        (["scaling", "--systems", ""], "at least one system"),
        (["scaling", "--systems", "navtopo,navtopo"], "named twice"),
        (["scaling", "--seed", "-1"], "--seed"),
        (["scaling", "--trials", "0"], "--trials"),
        (["drift", "tiny", "--levels", "precise,precise"], "named twice"),
        (["drift", "tiny", "--systems", ""], "at least one system"),
        (["drift", "tiny", "--trials", "0"], "--trials"),
    ],
)
def test_a_sweep_refuses_bad_flags_before_creating_anything(tmp_path, monkeypatch, capsys, args, reason):
    line = refused_by_main(monkeypatch, capsys, "sweep", *args, "--out", str(tmp_path / "sweep"))
    assert reason in line and not (tmp_path / "sweep").exists()


def test_a_sweep_never_keeps_another_sweeps_run_as_its_own(tmp_path):
    import json

    from runners.sweep import DriftOptions, ScalingOptions, SweepError, run_drift, scaling_scenario_files

    # `sweep drift tiny`, then `sweep drift loop_office` into the same folder
    (tmp_path / "drift" / "precise").mkdir(parents=True)
    manifest = {"scenario": {"name": "tiny"}, "systems": ["navtopo", "metric_grid"], "trial_count": 3, "setting": "precise"}
    (tmp_path / "drift" / "precise" / "manifest.json").write_text(json.dumps(manifest))
    (tmp_path / "drift" / "precise" / "summary.json").write_text("{}")
    ran = []
    with pytest.raises(SweepError, match="holds a run of tiny, precise, systems metric_grid,navtopo, 3 trials; this sweep asks"):
        run_drift(DriftOptions(scenario="loop_office", out=tmp_path / "drift"), lambda *args: ran.append(args))
    assert ran == []
    # `sweep scaling --seed 5` where a seed-31 building was generated
    options = ScalingOptions(lengths=[150.0], out=tmp_path / "scaling")
    (building,) = scaling_scenario_files(options)
    text = building.read_text()
    options.seed = 5
    with pytest.raises(SweepError, match=r"an earlier sweep's building, seed 31 \(asked 5\)"):
        scaling_scenario_files(options)
    assert building.read_text() == text


def test_a_sweep_checks_an_existing_folder_before_any_run(tmp_path):
    (tmp_path / "sweep" / "precise").mkdir(parents=True)
    (tmp_path / "sweep" / "precise" / "manifest.json").write_text('{"scenario": {"name": "loop_office"}}')
    result = CliRunner().invoke(app, ["sweep", "drift", "tiny", "--out", str(tmp_path / "sweep")])
    assert "holds a run of loop_office" in one_line_error(result)
    assert sorted(p.name for p in (tmp_path / "sweep").rglob("*")) == ["manifest.json", "precise"]
