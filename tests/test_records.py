"""The records of a results folder (reports/records.py): the runner writes them and the reports
read them through one model each, and the files are the very text the runner wrote before the
models (same keys, key order, values, rounding; no new null keys). The expected texts
(tests/data/records_c372170/) were written by the dict-building runner of c372170 from the same
inputs."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from reports.records import (
    Manifest,
    MappingReport,
    NavigationReport,
    RunFormatError,
    SystemSummary,
    TrialRecord,
    read_trials,
)
from runners.metrics import summarize, trial_record
from runners.results import RunDir, write_json


@dataclass
class _Trial:
    start: np.ndarray
    goal: np.ndarray
    shortest_m: float


TRIAL = _Trial(np.array([1.23456, -2.5, 0.3]), np.array([10.0, 0.1234567]), np.float64(12.345678))
MEMORY = {"map": 100, "localization": 10, "derived": 0, "model": 5, "total": 115}
LOCALIZED = {"seconds": 2.5, "error_m": 0.1, "yaw_error_deg": 1.0, "right": True, "looks": 2, "hypotheses": 1}

BEFORE = Path(__file__).parent / "data" / "records_c372170"  # written by the runner at c372170
SUCCESS_LINE, FAILURE_LINE = (BEFORE / "trials.jsonl").read_text().splitlines()
SUMMARY_TEXT = (BEFORE / "summary.json").read_text()


def _success() -> TrialRecord:
    record = trial_record(
        "navtopo",
        3,
        TRIAL,
        7,
        success=True,
        reason="",
        travelled_m=13.456789,
        final_distance_m=0.2345678,
        collisions=0,
        sim_time_s=41.23456,
        compute_s=1.234567,
        planning_ms=[5.123456, 1.0, 2.5],
        first_plan_ms=5.123456,
        tracking_error_m=[0.1, 0.2, 0.05],
        initial_pose_error=np.array([0.1, -0.2, 0.05]),
        memory=MEMORY,
        diagnostics={"startup_localization": LOCALIZED, "goal_conversion_error_m": 0.0123},
    )
    record.worker = {"host": "h", "pid": 12}  # set by the driver, after the worker's keys
    return record


def _without(text: str, key: str) -> str:
    """A JSON object's text (one object, or one per line) without ``key`` at its top level."""
    return "\n".join(json.dumps({k: v for k, v in json.loads(line).items() if k != key}) for line in text.splitlines())


def test_a_trial_record_is_written_as_before(tmp_path):
    """The same text, but for the key added since (``failure_stage``, right after ``detail``)."""
    failure = trial_record("metric_grid", 0, TRIAL, 7, success=False, reason="crashed", detail="worker process killed by SIGABRT")
    failure.worker = None
    run = RunDir(tmp_path)
    run.append_trial(_success())
    run.append_trial(failure)
    written = run.trials_path.read_text()
    assert _without(written, "failure_stage") == SUCCESS_LINE + "\n" + FAILURE_LINE
    success, crashed = (json.loads(line) for line in written.splitlines())
    assert (success["failure_stage"], crashed["failure_stage"]) == (None, "runner")  # a crash: the runner's stage
    assert list(crashed)[list(crashed).index("detail") + 1] == "failure_stage"


def test_a_trial_record_read_and_written_back_is_the_same_line(tmp_path):
    for line in (SUCCESS_LINE, FAILURE_LINE):
        assert json.dumps(TrialRecord.model_validate(json.loads(line)).as_json(), allow_nan=False) == line
    (tmp_path / "trials.jsonl").write_text(SUCCESS_LINE + "\n" + FAILURE_LINE + "\n")
    assert [(r.system, r.trial, r.worker) for r in read_trials(tmp_path / "trials.jsonl")] == [
        ("navtopo", 3, {"host": "h", "pid": 12}),
        ("metric_grid", 0, None),
    ]


def test_the_summary_is_written_as_before(tmp_path):
    ok = _success()
    not_localized = TrialRecord.model_validate(
        {**ok.as_json(), "trial": 4, "success": False, "reason": "not_localized", "efficiency": None, "spl": 0.0}
        | {"failure_stage": "startup"}
        | {"startup_localization": None, "goal_conversion_error_m": None}
    )
    mapping = {
        "navtopo": MappingReport.model_validate(
            {
                "scans": 10,
                "route_length_m": 20.5,
                "ms_per_scan": {"median": 2.0, "mean": 2.5, "p95": 4.0, "max": 5.0},
                "map_bytes": 1000,
                "map_disk_bytes": 3000,
                "map_disk": {"map": 2000, "localization": 0, "derived": 0, "model": 0, "other": 1000},
            }
        ),
        "metric_grid": MappingReport(error="RuntimeError: boom", scans=10, map_bytes=None, map_disk_bytes=None),
    }
    navigation = {
        "navtopo": NavigationReport(
            map_bytes=900,
            map_load_ms=12.345,
            rss_bytes=1000,
            rss_process_bytes=9000,
            rss_before_load=8000,
            memory={"map": 100, "localization": 20, "derived": 0, "model": 5, "total": 125},
            disk_bytes=3000,
            disk={"map": 2000, "localization": 0, "derived": 0, "model": 0, "other": 1000},
        )
    }
    summary = summarize([ok, not_localized], mapping, navigation)
    write_json(
        tmp_path / "summary.json", {name: summary.get(name, SystemSummary()) for name in ["navtopo", "metric_grid", "oracle"]}
    )
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["navtopo"]["failure_stages"] == {"startup": 1}  # added since, after failure_reasons
    assert list(written["navtopo"])[-2:] == ["failure_reasons", "failure_stages"]
    # added since: the efficiencies after the start-up and against the mapped world, the start-up's
    # metres and the start-ups from a given pose
    added = ("failure_stages", "efficiency_after_startup_mean", "efficiency_mapped_world_mean")
    assert written["navtopo"]["efficiency_after_startup_mean"] is None  # no start-up checked in these records
    for value in written.values():
        for key in ("metres", "from_given_pose"):
            (value.get("startup_localization") or {}).pop(key, None)
    assert {name: {k: v for k, v in value.items() if k not in added} for name, value in written.items()} == json.loads(
        SUMMARY_TEXT
    )
    read = {name: SystemSummary.model_validate(value) for name, value in json.loads(SUMMARY_TEXT).items()}
    write_json(tmp_path / "again.json", read)
    assert (tmp_path / "again.json").read_text() == SUMMARY_TEXT


def test_a_record_keeps_the_keys_it_was_given_in_their_order_and_numbers_as_written():
    # a system's own figures ride along after the runner's, even those the model names (vertices)
    given = {"scans": 3, "route_length_m": 5, "map_bytes": 10, "descriptor": "minkloc3d", "vertices": 2, "counters": {"a": 1}}
    report = MappingReport.model_validate(given)
    report.maps_from = "/runs/earlier"  # set later: after the keys given
    assert json.dumps(report.as_json()) == json.dumps({**given, "maps_from": "/runs/earlier"})
    assert report.vertices == 2 and report.route_length_m == 5 and report.error is None
    assert "error" not in report.as_json() and report.given("error", "none given") == "none given"
    assert MappingReport().as_json() == {} and SystemSummary().as_json() == {}


def test_an_unreadable_record_names_the_file_and_the_key(tmp_path):
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps({"scenario": {"name": "tiny"}, "systems": ["oracle"], "seed": "seven"}))
    with pytest.raises(RunFormatError, match=r"manifest.json: seed: .*integer"):
        Manifest.read(path)
    path.write_text("{")
    with pytest.raises(RunFormatError, match="not readable JSON") as caught:
        Manifest.read(path)
    assert caught.value.exit_code == 2


def test_every_file_of_a_crafted_run_reads_and_writes_back_to_the_same_object(tmp_path):
    from crafted_run import write_crafted_run

    root = write_crafted_run(tmp_path / "run")
    files = [root / "manifest.json", root / "summary.json", *sorted((root / "mapping").glob("*.json"))]
    files += sorted((root / "navigation").glob("*.json"))
    for path in files:
        data = json.loads(path.read_text())
        if path.name == "manifest.json":
            again = Manifest.model_validate(data).as_json()
        elif path.name == "summary.json":
            again = {name: SystemSummary.model_validate(value).as_json() for name, value in data.items()}
        else:
            again = (MappingReport if path.parent.name == "mapping" else NavigationReport).model_validate(data).as_json()
        assert json.dumps(again) == json.dumps(data), path  # the same keys, order and numbers
    lines = (root / "trials.jsonl").read_text().split("\n")[:-1]  # its last line is torn on purpose
    assert [json.dumps(TrialRecord.model_validate(json.loads(line)).as_json()) for line in lines] == lines
    assert len(files) >= 5
