"""Candidate evaluation in parallel: one interface, the engine a setting (``experiment.parallel``).

The searches (``gait_search``, ``identify``) hand a list of independent, picklable tasks
to :func:`pool` and get the results back in order. Where they run is a setting:

- ``engine=processes`` (default): local worker processes (``concurrent.futures``,
  started by *spawn*: numba's state is not fork-safe), one per core; with one worker
  the tasks run in this process, which is also what a Hydra joblib sweep job needs (its
  children cannot start processes of their own).
- ``engine=dask``: a Dask distributed cluster. With ``address`` unset it starts a local
  cluster of ``workers`` processes (one thread each); with ``address`` it connects to a
  running scheduler, e.g. one started on SLURM nodes by ``dask-jobqueue``'s
  ``SLURMCluster`` or by ``dask scheduler`` / ``dask worker``.

Dask rather than Ray or submitit: it is pure Python and a small install, its scheduler
keeps one pool of workers alive across a search's generations (submitit starts a
cluster job per call, seconds to minutes each, far more than one candidate costs), and
``dask-jobqueue`` gives the SLURM deployment our users already run sweeps on. The
tasks carry everything they need (the config is a few kB pickled), so no engine needs
worker-side set-up.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import os
import re
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

from .config import choice_field, num_field
from .errors import ConfigError
from .signals import die_with_parent

ENGINES = ("processes", "dask")
_ADDRESS = re.compile(
    r"((tcp|tls|ws|wss|ucx)://)?[A-Za-z0-9._\-]+(:\d{1,5})?|((tcp|tls)://)?\[[0-9A-Fa-f:]+\](:\d{1,5})?"
)


@dataclass
class ParallelConfig:
    """Where candidates are evaluated (``experiment.parallel.*``)."""

    engine: str = choice_field("processes", *ENGINES)
    workers: int = num_field(0, lo=0, unit="processes")  # 0 = one per core (dask with an address: the cluster's)
    address: str | None = None  # engine=dask: a running scheduler, e.g. tcp://host:8786; unset = a local cluster
    # engine=dask with an address: how long to wait for the scheduler's first worker (a SLURM job may queue)
    worker_wait_s: float = num_field(60.0, lo=0.0, unit="s")

    def check(self) -> None:
        if self.address is not None and self.engine != "dask":
            raise ConfigError(
                f"experiment.parallel.address is set but the engine is {self.engine!r}: "
                "add experiment.parallel.engine=dask, or drop the address"
            )
        if self.address is not None and not _ADDRESS.fullmatch(self.address):
            raise ConfigError(
                f"experiment.parallel.address = {self.address!r} is not a Dask scheduler address: "
                "give [tcp://]host:port (tls://, ws://, wss:// and ucx:// too), e.g. tcp://10.0.0.5:8786"
            )


class Pool(Protocol):
    """What a search needs of an engine."""

    workers: int

    def map(self, fn: Callable[[Any], Any], tasks: Sequence[Any]) -> list[Any]:
        """``[fn(t) for t in tasks]``, evaluated in parallel, in order."""
        ...


def inside_foreign_pool() -> bool:
    """True in a worker of another process pool, e.g. a Hydra joblib sweep job (loky): its start method is
    not one multiprocessing knows, so a process started from here could not start (it would look for it)."""
    method = mp.get_start_method(allow_none=True)
    return method is not None and method not in mp.get_all_start_methods()


def n_workers(requested: int, n_tasks: int) -> int:
    """Workers for ``n_tasks`` parallel tasks: ``requested`` (0 = one per core), never more than the tasks;
    one (this process) inside another pool's worker, where the sweep is already the parallel level."""
    if inside_foreign_pool():
        return 1
    cores = os.cpu_count() or 1
    return max(1, min(n_tasks, requested if requested > 0 else cores))


class _InProcess:
    def __init__(self) -> None:
        self.workers = 1

    def map(self, fn: Callable[[Any], Any], tasks: Sequence[Any]) -> list[Any]:
        return [fn(t) for t in tasks]


class _Processes:
    def __init__(self, executor: ProcessPoolExecutor, workers: int) -> None:
        self.executor, self.workers = executor, workers

    def map(self, fn: Callable[[Any], Any], tasks: Sequence[Any]) -> list[Any]:
        return list(self.executor.map(fn, tasks))


class _Dask:
    def __init__(self, client: Any, workers: int) -> None:
        self.client, self.workers = client, workers

    def map(self, fn: Callable[[Any], Any], tasks: Sequence[Any]) -> list[Any]:
        # pure=False: two equal tasks are still two evaluations (a search may repeat a candidate)
        return self.client.gather(self.client.map(fn, list(tasks), pure=False))


@contextmanager
def pool(cfg: ParallelConfig, max_tasks: int) -> Iterator[Pool]:
    """An engine for up to ``max_tasks`` tasks at a time, shut down on leaving."""
    cfg.check()
    if cfg.engine == "dask":
        yield from _dask_pool(cfg, max_tasks)
        return
    workers = n_workers(cfg.workers, max_tasks)
    if workers == 1:
        yield _InProcess()
        return
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=die_with_parent) as executor:
        yield _Processes(executor, workers)


def _dask_pool(cfg: ParallelConfig, max_tasks: int) -> Iterator[Pool]:
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ConfigError(
            "experiment.parallel.engine=dask needs Dask distributed: pip install 'slotexp[cluster]'"
        ) from None
    if cfg.address is not None:
        try:
            client = Client(cfg.address, timeout="20s")
        except (OSError, ValueError, TypeError) as exc:  # nobody there, or an address Dask cannot parse
            raise ConfigError(
                f"experiment.parallel.address = {cfg.address!r}: no Dask scheduler answers there ({exc}); "
                "start one (dask scheduler, or dask-jobqueue's SLURMCluster) or drop the address for a local cluster"
            ) from None
        with client:
            try:  # a scheduler with no workers would take the tasks and never run them
                client.wait_for_workers(1, timeout=cfg.worker_wait_s)
            except (TimeoutError, asyncio.TimeoutError):
                raise ConfigError(
                    f"the Dask scheduler at {cfg.address} has no workers after {cfg.worker_wait_s:g} s: start some "
                    f"(dask worker {cfg.address}, or SLURMCluster.scale) or raise experiment.parallel.worker_wait_s"
                ) from None
            yield _Dask(client, max(1, len(client.scheduler_info().get("workers", {}))))
        return
    workers = n_workers(cfg.workers, max_tasks)
    with (
        LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield _Dask(client, workers)
