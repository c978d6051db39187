"""Where a command's jobs run: the typer options of `run` and `sweep`, and the one executor of a command."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import TYPE_CHECKING, Annotated, Protocol

import typer

if TYPE_CHECKING:
    from runners.executors import Executor

WorkersOption = Annotated[
    int | None, typer.Option(help="jobs at once (default: the cores; with --executor ray: the cluster's CPUs)", min=1)
]
ExecutorOption = Annotated[str, typer.Option(help="where jobs run: local (a fresh process each) or ray")]
RayAddressOption = Annotated[
    str | None, typer.Option(help="with --executor ray: auto or HOST:PORT of a running cluster (default: a private one)")
]


class JobPlace(Protocol):
    """Where the jobs of a command run (``RunOptions``, a sweep's options)."""

    executor: str
    workers: int | None
    ray_address: str | None


@contextlib.contextmanager
def executor_for(place: JobPlace) -> Iterator[Executor]:
    """The executor every run of one command shares (one Ray instance, not one per run)."""
    from runners.executors import open_executor

    with open_executor(place.executor, place.workers, place.ray_address) as pool:
        yield pool
