"""The mapping drive: the robot follows the scenario's mapping route on its true pose.

One drive for every caller: the mapping stage (``runners.mapping``: every system observes each
tick), the tuning scripts' recorded drives (``benchmarks/_tuning.py``) and the route check
(``tools/check_routes.py``: no scan at all). The shared follower (``navkit.follower``) steers on
the simulator's true pose towards the route's polyline (scenario frame) with a goal tolerance of
``ROUTE_GOAL_TOLERANCE_M``; systems only observe, so the drive depends on the scenario, the seed
and the route alone, never on who watches it.

A drive ends when the follower reaches the route's end (``reached``), when the robot made no
0.1 m of progress along the route for ``STUCK_S`` of simulated time (``stuck``: the route passes
too close to walls or obstacles), or after its tick budget, 3x the route at full speed plus
10 minutes (``out_of_ticks``).
"""

from __future__ import annotations

from collections.abc import Iterator

from navkit.errors import BenchError
from navkit.follower import FollowerConfig, PathFollower
from runners.sim import MAPPING_STREAM, Simulator
from scenarios import Scenario

ROUTE_GOAL_TOLERANCE_M = 0.3
STUCK_S = 60.0  # no progress along the route for this long (simulated time) stops mapping
PROGRESS_M = 0.1  # progress along the route that counts as moving on


class RouteError(BenchError):
    """The mapping route cannot be driven (a property of the scenario: resuming will not help)."""

    exit_code = 1  # the run's mapping stage failed


class RouteDrive:
    """One drive along the mapping route: ``ticks()`` yields once per tick, before the robot moves
    (the caller observes there), and ``ending`` says how the drive ended."""

    def __init__(self, scenario: Scenario, sim: Simulator) -> None:
        """Places the robot at the route's start, its noise from the mapping stream of ``sim``'s seed."""
        robot = scenario.spec.robot
        self.sim = sim
        sim.reset(scenario.route_start, stream=(MAPPING_STREAM,))
        self.follower = PathFollower(
            FollowerConfig(max_linear=robot.max_linear, max_angular=robot.max_angular, goal_tolerance=ROUTE_GOAL_TOLERANCE_M)
        )
        self.follower.set_path(scenario.route)
        self.max_ticks = int((3.0 * scenario.route_length_m / robot.max_linear + 600.0) * scenario.spec.sensor.rate_hz)
        self.ending = ""  # "reached", "stuck" or "out_of_ticks" once the drive is over

    def ticks(self) -> Iterator[int]:
        """Per tick: yield the tick's number, then move the robot by the follower's command on its
        true pose, unless the route's end is reached or the robot is stuck."""
        sim, follower = self.sim, self.follower
        progress_mark, progress_time = -1.0, 0.0
        for tick in range(self.max_ticks):
            yield tick
            command = follower.command(sim.true_pose)
            if follower.reached:
                self.ending = "reached"
                return
            if follower.progress > progress_mark + PROGRESS_M:
                progress_mark, progress_time = follower.progress, sim.time
            elif sim.time - progress_time > STUCK_S:
                self.ending = "stuck"
                return
            sim.step(command)
        self.ending = "out_of_ticks"

    def check(self) -> None:
        """A ``RouteError`` saying why, unless the drive reached the route's end."""
        if self.ending == "stuck":
            x, y = self.sim.true_pose[:2]
            raise RouteError(
                f"the mapping route is blocked at ({x:.2f}, {y:.2f}), {self.follower.progress:.1f} m along it "
                f"({self.sim.collisions} collisions): it passes too close to walls or obstacles for the robot"
            )
        if self.ending != "reached":
            raise RouteError(f"mapping route not completed within {self.max_ticks} ticks")
