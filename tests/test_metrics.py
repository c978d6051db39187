"""runners/metrics.py against hand-computed cases: the STOP rule, the timeout, capped efficiency,
SPL, planning statistics, memory and tracking summaries, and null (never NaN) when undefined."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from reports.records import MappingReport, NavigationReport, Stats
from runners.metrics import (
    edge_errors,
    efficiency,
    judge,
    stats_ms,
    summarize,
    timeout_s,
    trajectory_length,
    trial_record,
    unjoined_neighbours,
)


@dataclass
class _Trial:
    start: np.ndarray
    goal: np.ndarray
    shortest_m: float


TRIAL = _Trial(start=np.array([0.0, 0.0, np.pi / 2]), goal=np.array([10.0, 0.0]), shortest_m=10.0)


@pytest.mark.parametrize(
    ("ending", "distance", "failure", "expected"),
    [
        ("reached", 0.3, "", (True, "")),  # stopped 0.3 m from the goal: within the 0.5 m rule
        ("reached", 0.5, "", (True, "")),  # exactly at the tolerance counts
        ("reached", 0.51, "", (False, "reached_wrong_place")),  # declared reached, but too far
        ("reached", 7.0, "", (False, "reached_wrong_place")),
        ("failed", 0.1, "no_path", (False, "no_path")),  # the system's own reason, even at the goal
        ("failed", 3.0, "", (False, "failed")),
        ("timeout", 0.1, "", (False, "timeout")),  # passing the goal without declaring is no success
        ("collision", 0.2, "", (False, "collision")),
        ("stuck", 4.0, "", (False, "stuck")),
    ],
)
def test_the_stop_rule(ending, distance, failure, expected):
    assert judge(ending, distance, 0.5, failure) == expected


def test_an_unknown_ending_is_refused():
    with pytest.raises(ValueError, match="unknown trial ending"):
        judge("teleported", 0.0)


def test_timeout_is_three_times_the_shortest_path_at_full_speed_plus_a_minute():
    assert timeout_s(80.0, 1.0) == pytest.approx(300.0)
    assert timeout_s(80.0, 0.5) == pytest.approx(540.0)
    assert timeout_s(80.0, 1.0, mapped_m=40.0) == pytest.approx(420.0)  # a changed world: the way as mapped too


def test_trajectory_length_sums_the_2d_steps():
    rows = np.array([[0.0, 0.0, 0.0, 0.0], [1.0, 3.0, 4.0, 1.0], [2.0, 3.0, 4.0, 2.0], [3.0, 6.0, 8.0, 0.0]])
    assert trajectory_length(rows) == pytest.approx(10.0)  # turning in place adds nothing
    assert trajectory_length(rows[:1]) == 0.0


def test_efficiency_is_capped_at_one():
    assert efficiency(10.0, 12.5) == pytest.approx(0.8)
    assert efficiency(10.0, 9.6) == 1.0  # stopped 0.4 m short: capped, not 1.04
    assert efficiency(0.0, 0.0) == 1.0


def test_a_successful_record_has_efficiency_spl_and_efficiency_to_goal():
    record = trial_record("x", 3, TRIAL, 7, success=True, reason="", travelled_m=12.5, final_distance_m=0.3)
    assert record.efficiency == pytest.approx(0.8) and record.spl == pytest.approx(0.8)
    assert record.efficiency_to_goal == pytest.approx(10.0 / 12.8, abs=1e-6)
    assert record.start == [0.0, 0.0, 90.0] and record.goal == [10.0, 0.0]
    assert record.trial == 3 and record.seed == 7


def test_a_failed_record_has_no_efficiency_and_zero_spl():
    record = trial_record("x", 0, TRIAL, 7, success=False, reason="timeout", travelled_m=30.0)
    assert record.efficiency is None and record.spl == 0.0 and record.efficiency_to_goal is None


def test_planning_statistics_of_hand_made_samples():
    stats = stats_ms([1.0, 2.0, 3.0, 4.0, 100.0])
    assert stats.as_json() == {"median": 3.0, "mean": 22.0, "p95": pytest.approx(80.8), "max": 100.0, "count": 5}
    assert stats_ms([]).as_json() == {"median": None, "mean": None, "p95": None, "max": None, "count": 0}


def _record(system, trial, success, travelled, planning, first=None, memory=None, tracking=None, reason="timeout"):
    return trial_record(
        system,
        trial,
        TRIAL,
        1,
        success=success,
        reason="" if success else reason,
        travelled_m=travelled,
        final_distance_m=0.2,
        planning_ms=planning,
        first_plan_ms=first,
        memory=memory,
        tracking_error_m=tracking,
    )


def test_summary_means_efficiency_over_successes_and_spl_over_all_trials():
    records = [
        _record("a", 0, True, 10.0, [5.0, 1.0], first=5.0),  # efficiency 1.0
        _record("a", 1, True, 12.5, [7.0, 1.0, 1.0], first=7.0),  # 0.8
        _record("a", 2, False, 40.0, [9.0], first=9.0, reason="collision"),  # failure: SPL 0
        _record("a", 3, False, 3.0, [], reason="collision"),
    ]
    mapping = {"a": MappingReport(ms_per_scan=Stats(median=2.0))}
    summary = summarize(records, mapping, {"a": NavigationReport(map_load_ms=12.5)})["a"]
    assert summary.trials == 4 and summary.successes == 2 and summary.success_rate == 0.5
    assert summary.efficiency_mean == pytest.approx(0.9)
    assert summary.spl_mean == pytest.approx((1.0 + 0.8) / 4)
    # every planning call of every trial, and the first plans apart
    assert summary.planning_ms.count == 6 and summary.planning_ms.median == pytest.approx(3.0)
    assert summary.first_plan_ms.count == 3 and summary.first_plan_ms.median == 7.0
    assert summary.map_load_ms == 12.5
    assert summary.failure_reasons == {"collision": 2}
    assert summary.as_json()["mapping_ms_per_scan"] == {"median": 2.0}


def test_summary_figures_are_null_not_nan_when_nothing_succeeds():
    records = [_record("b", 0, False, 5.0, []), _record("b", 1, False, 5.0, [])]
    summary = summarize(records, {})
    text = json.dumps({name: s.as_json() for name, s in summary.items()}, allow_nan=False)  # would raise on NaN
    assert "NaN" not in text
    b = summary["b"]
    assert b.success_rate == 0.0 and b.efficiency_mean is None and b.spl_mean == 0.0
    assert b.planning_ms.median is None and b.first_plan_ms.count == 0
    assert b.tracking_error_m is None
    assert b.memory.total is None


def test_memory_summary_takes_each_parts_peak_and_the_workers_rss():
    small = {"map": 100, "localization": 10, "derived": 0, "model": 5, "total": 115}
    grown = {"map": 100, "localization": 40, "derived": 30, "model": 5, "total": 175}
    records = [_record("c", 0, True, 10.0, [1.0], memory=small), _record("c", 1, True, 10.0, [1.0], memory=grown)]
    navigation = NavigationReport.model_validate(
        {"rss_bytes": 1000, "rss_process_bytes": 9000, "disk_bytes": 77, "disk": {"map": 70}, "memory": small}
    )
    memory = summarize(records, {"c": MappingReport(map_bytes=100)}, {"c": navigation})["c"].memory
    assert (memory.map, memory.localization, memory.derived, memory.model, memory.total) == (100, 40, 30, 5, 175)
    assert memory.rss_bytes == 1000 and memory.rss_process_bytes == 9000
    assert memory.disk_bytes == 77 and memory.as_json()["disk"] == {"map": 70} and memory.map_bytes == 100


def test_tracking_error_per_trial_and_over_trials():
    one = _record("d", 0, True, 10.0, [1.0], tracking=[0.0, 0.1, 0.2, 0.3, 0.04])
    assert one.tracking_error_m == {"median": 0.1, "p95": pytest.approx(0.28), "max": 0.3, "final": 0.04}
    two = _record("d", 1, True, 10.0, [1.0], tracking=[0.5, 0.5, 0.5])
    summary = summarize([one, two], {})["d"].tracking_error_m
    assert (
        summary is not None
        and summary["median"] == pytest.approx(0.3)
        and summary["max"] == 0.5
        and summary["final_median"] == pytest.approx(0.27)
    )


def test_edge_errors_compare_each_edge_with_the_true_relative_pose():
    truth = {0.0: np.array([0.0, 0.0, 0.0]), 1.0: np.array([2.0, 0.0, np.pi / 2])}
    exact = edge_errors([(0.0, 1.0, [2.0, 0.0, np.pi / 2])], truth)
    assert exact.translation_m.max == 0.0 and exact.rotation_deg.max == 0.0 and exact.count == 1
    off = edge_errors([(0.0, 1.0, [2.3, 0.4, np.pi / 2 + np.radians(2.0)]), (0.0, 9.0, [0, 0, 0])], truth)
    assert off.translation_m.max == pytest.approx(0.5) and off.rotation_deg.max == pytest.approx(2.0)
    assert off.count == 1  # an edge whose stamps have no true pose is left out


def test_late_locations_count_as_revisits_only_where_the_first_half_had_been():
    from runners.mapping import revisited_late

    # the robot drives x = 0..10 m (first half), then back and into a room at (5, 4)
    stamps = [float(i) for i in range(31)]
    xs = [*range(11), *range(10, 0, -1), *([5.0] * 10)]
    ys = [0.0] * 21 + [0.4 * k for k in range(1, 11)]
    true_at = {s: np.array([x, y, 0.0]) for s, x, y in zip(stamps, xs, ys, strict=True)}
    travelled, total = {}, 0.0
    for i, s in enumerate(stamps):
        if i:
            total += float(np.hypot(xs[i] - xs[i - 1], ys[i] - ys[i - 1]))
        travelled[s] = total
    half = total / 2.0
    # a location at (5, 0) on the way back (a place mapped twice), one in the room at (5, 4)
    late = [stamps[16], stamps[30]]
    assert travelled[stamps[16]] > half and np.allclose(true_at[stamps[16]][:2], [5, 0])
    assert revisited_late([0.0, *late], true_at, travelled, half) == 1


def test_locations_close_in_the_open_but_joined_only_the_long_way_round_are_counted():
    # a 3 m square of locations A(0,0) B(3,0) C(3,3) D(0,3), joined A-B-C-D but not D-A: A and D
    # are 3 m apart and 9 m apart over the graph (> 2 x 3 + 2), the diagonals 4.2 and 6 (not counted)
    square = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 3.0], [0.0, 3.0]])
    chain = [(0, 1), (1, 2), (2, 3)]

    def open_floor(points):
        return np.full(len(points), 1.0)

    def wall_between_a_and_d(points):  # a wall across x = 0 at y = 1.5 (and nowhere else)
        return np.where((np.abs(points[:, 1] - 1.5) < 0.1) & (np.abs(points[:, 0]) < 0.5), 0.0, 1.0)

    assert unjoined_neighbours(square, chain, open_floor, clearance=0.3) == [(0, 3)]
    assert unjoined_neighbours(square, [*chain, (3, 0)], open_floor, clearance=0.3) == []
    assert unjoined_neighbours(square, chain, wall_between_a_and_d, clearance=0.3) == []  # no way between them
    assert unjoined_neighbours(square, chain, open_floor, clearance=0.3, radius=2.9) == []  # farther than the radius
    assert unjoined_neighbours(square, [(0, 1)], open_floor, clearance=0.3) == [(0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]  # apart
