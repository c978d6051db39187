"""``RunRequest``: the flags of `navtopo-bench run` as one typed model, and their rules.

The fields are the flags as typer parsed them (the comma lists still as given, since a refusal
quotes them). Validation applies the rules in the order the command has always checked them, so
that the first broken rule is the one line a user sees (``Refused``, or ``ExecutorUnavailable``),
and fills what is derived from the flags in one place: the systems, settings and seeds of the
runs, the trial protocol, the limits. It reads no file: besides the flags it looks only at
whether the folders named by ``--resume`` and ``--out`` hold a run. Files (the scenarios, a
``--config``, a suite, a manifest) are read by ``runners.commands.runs``.

Three shapes of request: ``--suite FILE`` (the file lists the runs: SCENARIO, ``--systems``,
``--trials``, ``--seed(s)``, ``--setting``, ``--resume`` and ``--maps-from`` are refused beside
it), ``--resume RUN_DIR`` (the run's manifest decides: flags that would change the run are ignored,
with a note), or new runs, one per scenario x setting x seed.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, PrivateAttr, model_validator

from navkit.types import STOP_TOLERANCE_M
from runners.commands.checks import check_executor_flags, check_number, once_each, systems_list
from runners.commands.errors import Refused

if TYPE_CHECKING:
    from runners.protocol import TrialProtocol

# the defaults of the flags (`runners/cli.py` shows them in `run --help`); this module imports
# the protocol, the metrics and the systems only when a request is made, so that help stays quick
DEFAULT_SYSTEMS = "navtopo,metric_grid,oracle"
DEFAULT_TRIAL_TIMEOUT_S = 3600.0  # runners.run.DEFAULT_TRIAL_WALL_S
DEFAULT_INITIAL_POSE_ERROR = "0.5,10"  # XY_M,YAW_DEG
DEFAULT_STOP_TOLERANCE = STOP_TOLERANCE_M  # m
DEFAULT_GOALS = "map"
DEFAULT_INITIAL_POSE = "perturbed"
GOALS = ("map", "native")
MAX_TRIAL_MEMORY_MB = 1e9  # 1 PB: RLIMIT_AS counts bytes in 63 bits, and no machine has more


class RunRequest(BaseModel):
    """What `run` was asked; ``system_list``, ``setting_list``, ``seed_list`` and ``protocol`` are
    derived from it when it is made (a broken rule raises its own error, never a ValidationError)."""

    model_config = ConfigDict(frozen=True)

    scenarios: list[str] = []
    systems: str = DEFAULT_SYSTEMS
    trials: int | None = None
    seed: int | None = None
    seeds: str | None = None
    out: Path | None = None
    resume: Path | None = None
    workers: int | None = None
    executor: str = "local"
    ray_address: str | None = None
    trial_timeout_s: float = DEFAULT_TRIAL_TIMEOUT_S
    trial_memory_mb: float | None = None
    results: Path = Path("results")
    config_file: Path | None = None
    setting: str | None = None
    initial_pose_error: str = DEFAULT_INITIAL_POSE_ERROR
    initial_pose: str = DEFAULT_INITIAL_POSE
    stop_tolerance: float = DEFAULT_STOP_TOLERANCE
    goals: str = DEFAULT_GOALS
    maps_from: Path | None = None
    suite: Path | None = None

    # derived when the request is made (``_apply_rules``)
    _system_list: list[str] = PrivateAttr(default_factory=list)
    _setting_list: list[str | None] = PrivateAttr(default_factory=list)
    _seed_list: list[int | None] = PrivateAttr(default_factory=list)
    _protocol: TrialProtocol | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _apply_rules(self) -> RunRequest:
        """Every rule in the command's order; the derived values filled as they are checked."""
        from runners.protocol import INITIAL_POSES, TrialProtocol
        from scenarios.schema import GOAL_TOLERANCE_M

        check_executor_flags(self.executor, self.ray_address, self.workers)
        self._system_list = systems_list(self.systems) if self.resume is None else []  # a resume: the manifest's
        self._setting_list = self._parse_settings()
        error_xy, error_yaw = self._parse_initial_pose_error()
        # a system stopping farther out than the runner's STOP rule would fail every trial
        check_number("--stop-tolerance", self.stop_tolerance, "metres", low=0.01, high=GOAL_TOLERANCE_M)
        check_number("--trial-timeout-s", self.trial_timeout_s, "seconds", low=1.0, finite=False)
        check_number("--trial-memory-mb", self.trial_memory_mb, "MB", low=1.0, high=MAX_TRIAL_MEMORY_MB)
        if self.goals not in GOALS:
            raise Refused(f"--goals: {self.goals!r} is not map or native")
        if self.initial_pose not in INITIAL_POSES:
            raise Refused(f"--initial-pose: {self.initial_pose!r} is not perturbed or none")
        self._protocol = TrialProtocol(
            initial_pose_error_xy=error_xy,
            initial_pose_error_yaw_deg=error_yaw,
            stop_tolerance=self.stop_tolerance,
            goals=self.goals,
            initial_pose=self.initial_pose,
        )
        self._seed_list = self._parse_seeds()
        if self.suite is not None:
            self._refuse_beside_suite()
        elif self.resume is not None:
            self._check_resume()
        else:
            self._check_new_runs()
        return self

    # -- derived values ------------------------------------------------------------------------
    @property
    def system_list(self) -> list[str]:
        """The systems of new runs (empty for a resume: its manifest names them)."""
        return list(self._system_list)

    @property
    def setting_list(self) -> list[str | None]:
        """One run per setting; None: the scenario file's own noise."""
        return list(self._setting_list)

    @property
    def seed_list(self) -> list[int | None]:
        """One run per seed; None: the scenario's own seed."""
        return list(self._seed_list)

    @property
    def protocol(self) -> TrialProtocol:
        assert self._protocol is not None  # filled when the request is made
        return self._protocol

    def shared_options(self) -> dict[str, Any]:
        """The ``RunOptions`` every run of this request shares (where jobs run, the protocol, the limits)."""
        return {
            "workers": self.workers,
            "executor": self.executor,
            "ray_address": self.ray_address,
            "results_root": self.results,
            "protocol": self.protocol,
            "trial_wall_s": self.trial_timeout_s,
            "trial_memory_mb": self.trial_memory_mb,
        }

    @property
    def ignored_by_resume(self) -> list[str]:
        """The flags given beside ``--resume`` that the run's manifest overrides."""
        given = (
            ("--systems", self.systems != DEFAULT_SYSTEMS),
            ("--trials", self.trials is not None),
            ("--seed", self.seed is not None),
            ("--config", self.config_file is not None),
            ("--setting", self.setting is not None),
            ("--initial-pose-error", self.initial_pose_error != DEFAULT_INITIAL_POSE_ERROR),
            ("--stop-tolerance", self.stop_tolerance != DEFAULT_STOP_TOLERANCE),
            ("--goals", self.goals != DEFAULT_GOALS),
            ("--initial-pose", self.initial_pose != DEFAULT_INITIAL_POSE),
        )
        return [flag for flag, value in given if value]

    # -- the rules -----------------------------------------------------------------------------
    def _parse_settings(self) -> list[str | None]:
        from runners.protocol import SETTINGS

        if self.setting is None:
            return [None]
        names: list[str | None] = [x.strip() for x in self.setting.split(",") if x.strip()]
        bad = [str(x) for x in names if x not in SETTINGS]
        if bad or not names:
            raise Refused(
                f"--setting: unknown setting {', '.join(bad) or repr(self.setting)} (choose from {', '.join(SETTINGS)})"
            )
        once_each("--setting", self.setting, names, "a setting is named twice (the same run twice)")
        return names

    def _parse_initial_pose_error(self) -> tuple[float, float]:
        try:
            error_xy, error_yaw = (float(v) for v in self.initial_pose_error.split(","))
            if not (0 <= error_xy < math.inf and 0 <= error_yaw < math.inf):
                raise ValueError
        except ValueError:
            raise Refused(
                f"--initial-pose-error: expected two non-negative numbers XY_M,YAW_DEG, got {self.initial_pose_error!r}"
            ) from None
        return error_xy, error_yaw

    def _parse_seeds(self) -> list[int | None]:
        seeds: list[int | None] = [self.seed]
        if self.seeds:
            try:
                seeds = [int(s) for s in self.seeds.split(",") if s.strip()]
            except ValueError:
                raise Refused(f"--seeds: not a list of integers: {self.seeds!r}") from None
            if not seeds:
                raise Refused(f"--seeds {self.seeds!r}: give at least one seed")
            once_each("--seeds", self.seeds, seeds, "a seed is given twice (the same run twice)")
        for flag, value in [("--seed", self.seed)] + [("--seeds", s) for s in seeds]:
            if value is not None and value < 0:
                raise Refused(f"{flag} {value}: a seed is a non-negative integer")
        return seeds

    def _refuse_beside_suite(self) -> None:
        given = (
            ("SCENARIO", bool(self.scenarios)),
            ("--systems", self.systems != DEFAULT_SYSTEMS),
            ("--trials", self.trials is not None),
            ("--seed", self.seed is not None),
            ("--seeds", self.seeds is not None),
            ("--setting", self.setting is not None),
            ("--resume", self.resume is not None),
            ("--maps-from", self.maps_from is not None),
        )
        if refused := [flag for flag, value in given if value]:
            raise Refused(
                f"--suite {self.suite}: {', '.join(refused)}: the suite file lists the runs; give these there, not here"
            )

    def _check_resume(self) -> None:
        assert self.resume is not None
        if not (self.resume / "manifest.json").is_file():
            raise Refused(f"{self.resume}: not a run folder (manifest.json missing)")
        if len(self._seed_list) > 1 or len(self.scenarios) > 1:
            raise Refused("--resume finishes one run folder: give at most its scenario and no --seeds")

    def _check_new_runs(self) -> None:
        if not self.scenarios:
            raise Refused("give at least one SCENARIO (see `navtopo-bench scenario list`)")
        one_run = len(self.scenarios) == 1 and len(self._seed_list) == 1 and len(self._setting_list) == 1
        if self.out is not None and (self.out / "manifest.json").exists():
            raise Refused(f"{self.out}: already holds a run; use --resume {self.out} to finish it, or another --out")
        if self.out is not None and not one_run:
            raise Refused("--out takes one scenario, one seed and one setting; leave it out to get a folder per run")
        if self.maps_from is not None and not one_run:
            raise Refused("--maps-from serves one scenario, one seed and one setting")
        if self.maps_from is not None and self.trials == 0:
            raise Refused("--trials 0 with --maps-from would run nothing: the maps are there already")
