"""Drive scenarios' mapping routes with the simulator's kinematics and collision checks only.

The robot is driven as the mapping stage drives it (``runners.route.RouteDrive``: the shared
follower on the true pose, the same goal tolerance and stuck rule) but no lidar scan is cast, so a
1 km route takes seconds.
Prints per scenario: route length, whether it was completed, collisions, the least margin
between the robot and a wall along the way (clearance minus radius, on the GT raster), the
simulated and the wall-clock time of the drive.

    .venv/bin/python tools/check_routes.py [SCENARIO ...]   # default: every bundled scenario
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass

import numpy as np

from runners.route import RouteDrive
from runners.sim import Simulator
from scenarios import Scenario, bundled_names, load_scenario


@dataclass
class Drive:
    name: str
    route_m: float
    completed: bool
    collisions: int
    travelled_m: float
    least_margin_m: float  # least (clearance - radius) of the robot's centre along the drive
    where: tuple[float, float]  # where that least margin was, or where the drive stopped
    sim_s: float
    wall_s: float

    def line(self) -> str:
        state = "completed" if self.completed else f"STOPPED at ({self.where[0]:.2f}, {self.where[1]:.2f})"
        return (
            f"{self.name:22s} route {self.route_m:7.1f} m  {state}  collisions {self.collisions}  "
            f"least margin {self.least_margin_m:.3f} m at ({self.where[0]:.2f}, {self.where[1]:.2f})  "
            f"sim {self.sim_s:6.0f} s  drive {self.wall_s:5.1f} s"
        )


def drive_route(scenario: Scenario) -> Drive:
    """Drive the mapping route without scans; stop at the first stuck period, as mapping does."""
    robot = scenario.spec.robot
    t0 = time.perf_counter()
    with Simulator(scenario) as sim:
        drive = RouteDrive(scenario, sim)
        for _ in drive.ticks():
            pass  # no scan: the drive alone
        stuck = drive.ending == "stuck"
        trajectory = sim.trajectory_array()
        margins = scenario.world.clearances_at(trajectory[:, 1:3]) - robot.radius
        k = int(np.argmin(margins)) if not stuck else len(trajectory) - 1
        return Drive(
            name=scenario.name,
            route_m=scenario.route_length_m,
            completed=drive.ending == "reached",
            collisions=sim.collisions,
            travelled_m=sim.travelled_m,
            least_margin_m=float(margins.min()),
            where=(float(trajectory[k, 1]), float(trajectory[k, 2])),
            sim_s=sim.time,
            wall_s=time.perf_counter() - t0,
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenarios", nargs="*", help="bundled names or YAML files (default: every bundled scenario)")
    args = parser.parse_args()
    failed = 0
    for name in args.scenarios or bundled_names():
        t0 = time.perf_counter()
        scenario = load_scenario(name, with_trials=False)
        load_s = time.perf_counter() - t0
        result = drive_route(scenario)
        print(f"{result.line()}  (route built in {load_s:.1f} s)", flush=True)
        failed += not result.completed or result.collisions > 0
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
