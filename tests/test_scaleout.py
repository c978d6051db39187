"""Scale-out and fault tolerance: crash isolation, determinism across executors, resume after a
killed driver (issue 13). The runs use `tiny`, or a copy of it with a short mapping route."""

from __future__ import annotations

import ipaddress
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import faulty_system  # noqa: F401 - registers the "faulty" system in this process
import numpy as np
import pytest
import yaml
from test_robustness import ctrl_c, wait_for
from typer.testing import CliRunner

from navkit import geometry as se2
from runners.cli import app
from runners.executors import LocalExecutor
from runners.results import RunDir
from scenarios import load_scenario

ROOT = Path(__file__).resolve().parent.parent
# facts of the execution, not of the outcome: timings, memory figures, where the trial ran
TIMING = {"compute_s", "planning_ms", "planning_ms_samples", "first_plan_ms", "memory", "worker"}
HAS_RAY = __import__("importlib.util").util.find_spec("ray") is not None


def short_tiny(folder: Path, extra_trials: int = 0) -> Path:
    """`tiny` with a 3 m mapping route (enough for the oracle, which maps nothing) and, appended,
    copies of its first trial (distinct goals a metre apart, so a test system can tell them apart)."""
    spec = yaml.safe_load((ROOT / "scenarios" / "bundled" / "tiny.yaml").read_text())
    spec["mapping_route"] = {"waypoints": [[1.0, 0.0], [4.0, 0.0]]}
    for k in range(extra_trials):
        spec["trials"].append({"start": [1.0, 0.0, 0], "goal": [11.0, -0.5 + 0.5 * k]})
    path = folder / "short_tiny.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def one_tour_tiny(folder: Path) -> Path:
    """`tiny` with its mapping route one tour of the building (40 m) instead of two: every goal is
    mapped, for tests of the runner's machinery that need a system which maps."""
    spec = yaml.safe_load((ROOT / "scenarios" / "bundled" / "tiny.yaml").read_text())
    spec["mapping_route"] = {"auto": {"min_length": 1.0}}
    path = folder / "one_tour_tiny.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def goal_in_map(scenario, index: int) -> list[float]:
    trial = scenario.trials[index]
    return [float(v) for v in se2.transform_points(se2.inverse(scenario.route_start), trial.goal[None, :])[0]]


def records_of(run: Path) -> dict[tuple[str, int], dict]:
    records = [json.loads(line) for line in (run / "trials.jsonl").read_text().splitlines() if line.strip()]
    keys = [(r["system"], r["trial"]) for r in records]
    assert len(keys) == len(set(keys)), f"a trial recorded twice in {run}"
    return {(r["system"], r["trial"]): r for r in records}


def is_loopback(address: str) -> bool:
    ip = ipaddress.ip_address(address)
    return (getattr(ip, "ipv4_mapped", None) or ip).is_loopback  # '::ffff:127.0.0.1' too


def without_timing(record: dict) -> dict:
    return {k: v for k, v in record.items() if k not in TIMING}


# ---------------------------------------------------------------------------------------------
# crash isolation


@pytest.mark.long
def test_trials_that_raise_crash_hang_or_hog_fail_alone_and_the_run_finishes(tmp_path):
    check_faulty_trials(tmp_path)


def check_faulty_trials(tmp_path: Path, *flags: str) -> None:
    """Trial 0 raises, 1 aborts its worker, 2 hangs past --trial-timeout-s, 3 allocates past
    --trial-memory-mb; 4 behaves. Each is recorded with its reason and a one-line detail, the
    well-behaved trial succeeds, the run exits 0 with a warning count and a summary."""
    path = short_tiny(tmp_path, extra_trials=2)
    scenario = load_scenario(path)
    goals = [goal_in_map(scenario, i) for i in range(5)]
    config = tmp_path / "faulty.yaml"
    config.write_text(
        yaml.safe_dump({"faulty": {"raise_at": [goals[0]], "abort_at": [goals[1]], "hang_at": [goals[2]], "hog_at": [goals[3]]}})
    )
    out = tmp_path / "run"
    args = ["run", str(path), "--systems", "faulty", "--config", str(config), "--workers", "2", "--out", str(out)]
    result = CliRunner().invoke(app, [*args, "--trial-timeout-s", "20", "--trial-memory-mb", "400", *flags])
    assert result.exit_code == 0, result.output
    assert "warning: 4 trial(s) failed in their worker" in result.output
    records = records_of(out)
    reasons = [records[("faulty", i)]["reason"] for i in range(5)]
    assert reasons == ["error", "crashed", "timeout", "out_of_memory", ""], reasons
    assert records[("faulty", 4)]["success"]
    details = [records[("faulty", i)]["detail"] for i in range(4)]
    assert "RuntimeError: faulty: raised on purpose" in details[0]
    assert "SIGABRT" in details[1] or "died" in details[1]  # Ray names no signal
    assert "wall-clock limit of 20 s" in details[2]
    assert "MemoryError" in details[3]
    assert all("\n" not in d and len(d) <= 300 for d in details)
    assert records[("faulty", 4)]["detail"] is None
    assert [records[("faulty", i)]["failure_stage"] for i in range(5)] == ["runner"] * 4 + [None]  # failed in the worker
    summary = json.loads((out / "summary.json").read_text())["faulty"]
    assert summary["failure_reasons"] == {"crashed": 1, "error": 1, "out_of_memory": 1, "timeout": 1}
    assert summary["failure_stages"] == {"runner": 4}
    assert (out / "trajectories" / "faulty" / "trial-4.tum").is_file()


def test_a_mapping_job_that_kills_its_worker_fails_that_system_only(tmp_path):
    from runners.run import RunOptions, execute

    out = tmp_path / "run"
    options = RunOptions(
        systems=["faulty", "oracle"], out=out, workers=2, config_overrides={"faulty": {"abort_while_mapping": True}}
    )
    run = execute(load_scenario(short_tiny(tmp_path)), options)
    report = json.loads((out / "mapping" / "faulty.json").read_text())
    assert report["error"].startswith("crashed: worker process killed by SIGABRT")
    assert not (out / "maps" / "faulty").exists() and (out / "maps" / "oracle" / "oracle.json").is_file()
    stage, why = run.failed_stages["faulty"]
    assert stage == "mapping" and why.startswith("crashed: worker process killed by SIGABRT")
    records = records_of(out)  # a map never made is no navigation failure: no trial of it recorded
    assert all(r["success"] for r in records.values()) and sorted(records) == [("oracle", i) for i in range(3)]
    assert run.warnings == 0 and not (out / "summary.json").is_file()  # unfinished: --resume maps it again


@pytest.mark.long
def test_a_system_that_raises_while_mapping_is_a_failed_stage_in_one_line(tmp_path):
    """As a map that cannot be loaded: one line, exit 1, no trial of that system counted; the
    others' trials are kept, and --resume maps the failed system again (not the others)."""
    from test_robustness import one_line_error

    out = tmp_path / "run"
    config = tmp_path / "faulty.yaml"
    config.write_text("faulty: {raise_while_mapping: true}\n")
    args = ["run", str(short_tiny(tmp_path)), "--systems", "faulty,oracle", "--config", str(config), "--out", str(out)]
    line = one_line_error(CliRunner().invoke(app, [*args, "--workers", "2"]), code=1)
    assert line == (
        "error: mapping stage failed, no trial counted (faulty: RuntimeError: faulty: raised while mapping); "
        f"after fixing it: --resume {out}"
    )
    records = records_of(out)
    assert sorted(records) == [("oracle", i) for i in range(3)] and all(r["success"] for r in records.values())
    assert not (out / "summary.json").exists() and not (out / "maps" / "faulty").exists()
    oracle_map = (out / "mapping" / "oracle.json").stat().st_mtime_ns

    line = one_line_error(CliRunner().invoke(app, ["run", "--resume", str(out), "--workers", "1"]), code=1)
    assert "mapping stage failed" in line and "(faulty: RuntimeError: faulty: raised while mapping)" in line
    assert records_of(out) == records and (out / "mapping" / "oracle.json").stat().st_mtime_ns == oracle_map


# ---------------------------------------------------------------------------------------------
# determinism


def _run_tiny(out: Path, *flags: str, env: dict[str, str] | None = None) -> Path:
    scenario = str(one_tour_tiny(out.parent))
    command = [sys.executable, "-m", "runners.cli", "run", scenario, "--systems", "oracle,metric_grid", "--out", str(out), *flags]
    environment = {**os.environ, **(env or {})}
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600, env=environment)
    assert done.returncode == 0, done.stderr[-2000:]
    return out


def _assert_same_outcomes(a: Path, b: Path) -> None:
    first, second = records_of(a), records_of(b)
    assert sorted(first) == sorted(second)
    for key in first:
        assert without_timing(first[key]) == without_timing(second[key]), key
        system, index = key
        assert (a / "trajectories" / system / f"trial-{index}.tum").read_bytes() == (
            b / "trajectories" / system / f"trial-{index}.tum"
        ).read_bytes(), key
    for report in (a / "mapping").glob("*.json"):
        mine, theirs = json.loads(report.read_text()), json.loads((b / "mapping" / report.name).read_text())
        mine.pop("ms_per_scan"), theirs.pop("ms_per_scan")
        assert mine == theirs, report.name


@pytest.mark.long
def test_one_worker_two_workers_and_ray_give_identical_trials_maps_and_trajectories(tmp_path):
    """`tiny` with the oracle and the metric baseline: --workers 1 and 2 (other chunks, other
    processes) and a private Ray instance give the same outcomes. Without Ray the test compares
    the local runs, then skips with the reason."""
    one = _run_tiny(tmp_path / "w1", "--workers", "1", "--trials", "2")
    _assert_same_outcomes(one, _run_tiny(tmp_path / "w2", "--workers", "2", "--trials", "2"))
    if not HAS_RAY:
        pytest.skip("Ray is not installed (pip install -e '.[ray]'): compared --workers 1 and 2 only")
    _assert_same_outcomes(one, _run_tiny(tmp_path / "ray", "--executor", "ray", "--workers", "2", "--trials", "2"))


class RecordingExecutor(LocalExecutor):
    """The local executor, noting when each job starts and ends: (event, kind, seed, time)."""

    opened: list[RecordingExecutor] = []

    def __init__(self, slots: int | None = None) -> None:
        super().__init__(slots)
        self.log: list[tuple[str, str, int, float]] = []
        RecordingExecutor.opened.append(self)

    def _start(self, run) -> None:
        self.log.append(("start", type(run.job).__name__, run.job.seed, time.monotonic()))
        super()._start(run)

    def _put(self, run, kind: str, payload) -> None:  # from the thread that reads the job's pipe
        if kind == "end":
            self.log.append(("end", type(run.job).__name__, run.job.seed, time.monotonic()))
        super()._put(run, kind, payload)


def _run_two_seeds(results: Path, workers: int, monkeypatch) -> RecordingExecutor:
    import runners.executors

    RecordingExecutor.opened = []
    monkeypatch.setattr(runners.executors, "LocalExecutor", RecordingExecutor)
    results.mkdir(parents=True)
    scenario = str(one_tour_tiny(results))
    args = ["run", scenario, "--seeds", "1,2", "--systems", "oracle,metric_grid", "--trials", "1", "--workers", str(workers)]
    result = CliRunner().invoke(app, [*args, "--results", str(results)])
    assert result.exit_code == 0, result.output
    assert len(RecordingExecutor.opened) == 1, "one executor for the runs of one command"
    return RecordingExecutor.opened[0]


def _span(log, seed: int, kind: str | None = None) -> tuple[float, float]:
    """When the first job of ``seed`` (of that kind) started and its last ended."""
    times = [(event, t) for event, k, s, t in log if s == seed and kind in (None, k)]
    return min(t for e, t in times if e == "start"), max(t for e, t in times if e == "end")


@pytest.mark.long
def test_the_runs_of_one_command_overlap_on_one_executor_and_give_the_sequential_outcomes(tmp_path, monkeypatch):
    """`run tiny --seeds 1,2 --workers 2`: seed 2's jobs start while seed 1's still run, each run's
    navigation starts once its own maps are in, and the outcomes are those of the runs one after
    another (--workers 1: with one slot, every job of the first run goes before the second's)."""
    together = _run_two_seeds(tmp_path / "together", 2, monkeypatch).log
    assert len([e for e in together if e[0] == "end"]) == len([e for e in together if e[0] == "start"])
    assert _span(together, 2)[0] < _span(together, 1)[1], "seed 2 waited for seed 1 to end"
    for seed in (1, 2):
        assert _span(together, seed, "MappingJob")[1] <= _span(together, seed, "TrialJob")[0]
    one_by_one = _run_two_seeds(tmp_path / "one_by_one", 1, monkeypatch).log
    assert _span(one_by_one, 1)[1] <= _span(one_by_one, 2)[0]
    for seed in (1, 2):
        [a] = (tmp_path / "together" / "tiny").glob(f"*-s{seed}")
        [b] = (tmp_path / "one_by_one" / "tiny").glob(f"*-s{seed}")
        assert sorted(p.relative_to(a) for p in a.rglob("*")) == sorted(p.relative_to(b) for p in b.rglob("*"))
        _assert_same_outcomes(a, b)
        assert json.loads((a / "summary.json").read_text()).keys() == {"oracle", "metric_grid"}


@pytest.mark.long
def test_ctrl_c_during_several_runs_exits_130_naming_each_unfinished_run_and_each_resumes(tmp_path):
    """Two seeds in flight together; Ctrl-C once a trial is recorded: every job ends, exit 130 in
    seconds, the one error line names the --resume of each unfinished folder, and each resumes with
    no trial lost or twice."""
    path = short_tiny(tmp_path)
    results = tmp_path / "results"
    command = [sys.executable, "-m", "runners.cli", "run", str(path), "--seeds", "1,2", "--systems", "oracle"]
    process = subprocess.Popen(
        [*command, "--trials", "3", "--workers", "2", "--results", str(results)],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        recorded = wait_for(lambda: any(p.stat().st_size for p in results.glob("tiny/*/trials.jsonl")), 300)
        assert recorded and process.poll() is None, "no trial recorded, or the runs ended before Ctrl-C"
        ctrl_c(process)
    finally:
        process.kill()
    errors = [line for line in process.stderr.read().splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith("error: interrupted; finish the run"), errors
    folders = sorted(p.parent for p in results.glob("tiny/*-s*/manifest.json"))
    assert len(folders) == 2
    unfinished = [folder for folder in folders if not (folder / "summary.json").is_file()]
    assert unfinished and all(f"--resume {folder}" in errors[0] for folder in unfinished)
    for folder in unfinished:
        before = {(r.system, r.trial): r.as_json() for r in RunDir(folder).read_trials()}  # perhaps none yet
        result = CliRunner().invoke(app, ["run", "--resume", str(folder), "--workers", "2"])
        assert result.exit_code == 0, result.output
        after = records_of(folder)
        assert sorted(after) == [("oracle", 0), ("oracle", 1), ("oracle", 2)]
        assert all(after[key] == record for key, record in before.items())


@pytest.mark.ray
@pytest.mark.slow
@pytest.mark.skipif(not HAS_RAY, reason="Ray is not installed (pip install -e '.[ray]')")
def test_a_two_node_ray_cluster_on_loopback_gives_the_outcomes_of_one_worker_and_uses_both_nodes(tmp_path):
    """A head and a second node of one CPU each on 127.0.0.1 (``tests/ray_cluster.py``, each node its
    own raylet); the driver joins it with --ray-address. The trials ran on both nodes, the outcomes
    are those of --workers 1, every socket of the cluster's processes is on loopback, and none of
    its processes outlives the test."""
    import psutil

    temp_dir = tempfile.mkdtemp(prefix="ntb-ray-")  # short: Ray's socket paths must fit 107 bytes
    helper = subprocess.Popen(
        [sys.executable, str(ROOT / "tests" / "ray_cluster.py"), temp_dir, "2"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    processes: list[psutil.Process] = []
    try:
        ready, _, _ = select.select([helper.stdout], [], [], 120)
        assert ready, "the cluster did not start within 120 s"
        cluster = json.loads(helper.stdout.readline())
        assert cluster["nodes"] == ["127.0.0.1", "127.0.0.1"] and cluster["address"].startswith("127.0.0.1:")
        on_ray = _run_tiny(
            tmp_path / "cluster",
            *("--executor", "ray", "--ray-address", cluster["address"], "--trials", "2"),
            env={"RAY_TMPDIR": temp_dir},
        )
        processes = psutil.Process(helper.pid).children(recursive=True)  # GCS, raylets, agents, workers
        addresses = {
            address.ip
            for process in processes
            for connection in process.net_connections(kind="inet")
            for address in (connection.laddr, connection.raddr)
            if address
        }
        assert addresses and all(is_loopback(a) for a in addresses), f"the cluster's processes use {addresses}"
    finally:
        helper.stdin.close()  # the helper shuts its nodes down
        try:
            helper.wait(timeout=60)
        finally:
            helper.kill()
            shutil.rmtree(temp_dir, ignore_errors=True)
    _, alive = psutil.wait_procs(processes, timeout=10)
    assert not alive, f"processes of the test cluster still run: {alive}"
    _assert_same_outcomes(on_ray, _run_tiny(tmp_path / "w1", "--workers", "1", "--trials", "2"))
    nodes = {r["worker"]["node"] for r in records_of(on_ray).values()}
    assert len(nodes) == 2 and None not in nodes, f"the trials ran on {nodes}, not on both nodes"


@pytest.mark.ray
@pytest.mark.slow
@pytest.mark.skipif(not HAS_RAY, reason="Ray is not installed (pip install -e '.[ray]')")
def test_on_ray_trials_that_raise_crash_hang_or_hog_fail_alone_too(tmp_path):
    check_faulty_trials(tmp_path, "--executor", "ray")


# ---------------------------------------------------------------------------------------------
# resume after the driver was killed


def _kill_driver_mid_run(out: Path, *flags: str) -> list[dict]:
    """Start a run of `tiny` (the oracle, 2 workers), SIGKILL the driver alone once a trial is
    recorded; returns the records it left."""
    command = [sys.executable, "-m", "runners.cli", "run", "tiny", "--systems", "oracle", "--out", str(out), *flags]
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    trials = out / "trials.jsonl"
    deadline = time.monotonic() + 400
    while time.monotonic() < deadline and process.poll() is None:
        if trials.is_file() and trials.read_text().count("\n") >= 1:
            break
        time.sleep(0.1)
    if process.poll() is None:
        os.kill(process.pid, signal.SIGKILL)  # the driver only: its workers must notice and end
    process.wait()
    return [r.as_json() for r in RunDir(out).read_trials()]


@pytest.mark.parametrize(
    "flags",
    [
        pytest.param(("--workers", "2"), id="local"),
        pytest.param(
            ("--workers", "2", "--executor", "ray"),
            id="ray",
            marks=[pytest.mark.ray, pytest.mark.slow, pytest.mark.skipif(not HAS_RAY, reason="Ray is not installed")],
        ),
    ],
)
@pytest.mark.long
def test_a_killed_driver_resumes_with_no_trial_lost_or_twice_and_no_mapping_redone(tmp_path, flags):
    out = tmp_path / "run"
    before = _kill_driver_mid_run(out, *flags)
    assert len(before) >= 1
    mapped = (out / "mapping" / "oracle.json").stat().st_mtime_ns
    result = CliRunner().invoke(app, ["run", "--resume", str(out), *flags])
    assert result.exit_code == 0, result.output
    assert "mapping (m)" not in result.output
    assert (out / "mapping" / "oracle.json").stat().st_mtime_ns == mapped
    records = records_of(out)
    assert sorted(records) == [("oracle", 0), ("oracle", 1), ("oracle", 2)]
    for record in before:  # what was recorded before the kill stays as it was
        assert records[(record["system"], record["trial"])] == record
    assert all(r["success"] for r in records.values())


def test_ray_without_ray_installed_is_one_line_and_exit_2(tmp_path):
    """Ray hidden from the interpreter: `--executor ray` refuses before any file is written."""
    code = (
        "import sys\n"
        "sys.modules['ray'] = None\n"  # import ray -> ImportError, find_spec -> ValueError/None
        "from runners.cli import main\n"
        f"sys.argv = ['navtopo-bench', 'run', 'tiny', '--executor', 'ray', '--results', {str(tmp_path / 'r')!r}]\n"
        "sys.exit(main())\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --executor ray: Ray is not installed"), done.stderr
    assert not (tmp_path / "r").exists()


def test_jobs_carry_content_not_paths(tmp_path):
    """A navigation job holds the scenario's files and the map's bytes: it runs after both are gone."""
    from runners.navigation import TrialJob, run_trial_job
    from runners.run import RunOptions, execute

    path = short_tiny(tmp_path)
    out = tmp_path / "run"
    execute(load_scenario(path), RunOptions(systems=["oracle"], trials=0, out=out, workers=1))
    job = TrialJob.packed(load_scenario(path), out / "maps" / "oracle", system="oracle", config={}, trials=[0], seed=1)
    assert not any(isinstance(v, (str, Path)) and "/" in str(v) for v in vars(job).values())
    path.unlink()
    (out / "maps" / "oracle" / "oracle.json").unlink()
    record = run_trial_job(job)["records"][0]
    assert record.success and np.isfinite(record.travelled_m)


@pytest.mark.ray
@pytest.mark.skipif(not HAS_RAY, reason="Ray is not installed (pip install -e '.[ray]')")
def test_a_ray_address_where_nothing_listens_is_one_line_and_exit_2(tmp_path):
    results = tmp_path / "results"
    command = [sys.executable, "-m", "runners.cli", "run", "tiny", "--systems", "oracle", "--results", str(results)]
    done = subprocess.run(
        [*command, "--executor", "ray", "--ray-address", "127.0.0.1:1"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 2, done.stderr
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "--ray-address 127.0.0.1:1: cannot join the Ray cluster" in errors[0], done.stderr
    assert "Traceback" not in done.stderr and not results.exists()


def test_ray_address_without_the_ray_executor_is_refused(tmp_path):
    result = CliRunner().invoke(app, ["run", "tiny", "--ray-address", "auto", "--results", str(tmp_path / "r")])
    assert result.exit_code == 2 and "--ray-address: only with --executor ray" in result.output
