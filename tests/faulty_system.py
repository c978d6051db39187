"""A system registered only in the tests: the oracle, misbehaving when given chosen goals.

Goals are map-frame points (``set_goal``), the one thing that tells trials apart whatever worker
or chunk runs them; each list in the config holds the goals on which to misbehave that way.
"""

from __future__ import annotations

import os
import time

import numpy as np

from runners.systems import Oracle, OracleConfig, register_system


class FaultyConfig(OracleConfig):
    raise_at: list[list[float]] = []  # raise an exception
    abort_at: list[list[float]] = []  # kill the worker process (os.abort: SIGABRT)
    hang_at: list[list[float]] = []  # never return (the wall-clock limit ends it)
    hog_at: list[list[float]] = []  # allocate until the address-space limit refuses
    abort_while_mapping: bool = False  # kill the mapping worker at the first scan
    raise_while_mapping: bool = False  # raise at the first scan


def _near(goal: np.ndarray, points: list[list[float]]) -> bool:
    return any(np.hypot(*(np.asarray(p[:2]) - goal[:2])) < 1e-3 for p in points)


@register_system("faulty", config=FaultyConfig, privileged=True, description="the oracle, misbehaving on chosen goals (tests)")
class Faulty(Oracle):
    def observe(self, obs) -> None:
        if self.config.abort_while_mapping:
            os.abort()
        if self.config.raise_while_mapping:
            raise RuntimeError("faulty: raised while mapping")
        super().observe(obs)

    def set_goal(self, goal: np.ndarray) -> None:
        config: FaultyConfig = self.config
        if _near(goal, config.raise_at):
            raise RuntimeError("faulty: raised on purpose")
        if _near(goal, config.abort_at):
            os.abort()
        if _near(goal, config.hang_at):
            time.sleep(3600)
        if _near(goal, config.hog_at):
            blocks = []
            for _ in range(64):  # at most 2 GB: a missing limit fails the test, not the machine
                blocks.append(np.ones(2**25, dtype=np.uint8))
            raise AssertionError("faulty: 2 GB allocated, no memory limit stopped it")
        super().set_goal(goal)
