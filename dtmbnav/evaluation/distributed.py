"""Run independent tasks on a Dask cluster (or in this process) and gather them in order.

One job: submit a list of :class:`Task` (a function and its arguments, e.g.
one Monte Carlo walk or one capture set), show progress, gather the results
in the order of the list, and report every task that failed with its label
(the caller knows how to re-run it alone). A task's result depends only on
its arguments (every random draw of a walk comes from its seed), so the
results are the same for any number of workers and in-process.

That needs one more thing: every task runs with one BLAS (and OpenMP)
thread, wherever it runs. OpenBLAS splits a matrix product differently for
different thread counts, and the rounding with it (a complex64 product
differs in its last bits between one and two threads), and Dask's worker
processes start with one BLAS thread while this process has one per core.
The receiver's decisions (a path's detection threshold, a cycle slip) can
turn on such a bit, and one such decision moves a walk's ranges and its
filters' errors by far more than a rounding (docs/evaluation.md;
docs/decisions.md, D36).

Where the tasks run (:class:`ClusterConfig`):

- ``workers=0``: in this process, one after the other, no Dask;
- ``scheduler="tcp://HOST:PORT"``: an existing ``dask.distributed`` cluster
  (its workers must import this package);
- otherwise a ``LocalCluster`` started for the run and closed after it:
  ``workers`` worker processes (default: one per CPU core, at most one per
  task), one thread each, with ``NUMBA_NUM_THREADS=1`` so that they do not
  oversubscribe the cores; each worker process imports the kernels once and
  loads their numba cache from disk, then runs task after task.
  ``processes=False`` runs the workers as threads of this process instead
  (quicker to start; the kernels release the GIL only in part).

Progress is a tqdm bar on stderr, advanced as tasks complete.
"""

from __future__ import annotations

import os
import sys
import traceback
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from threadpoolctl import threadpool_limits
from tqdm import tqdm

#: Environment of local worker processes: one numba thread each (the worker count is the parallelism).
WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


@dataclass(frozen=True)
class Task:
    """One unit of work.

    Attributes
    ----------
    label : str
        What the task is, for progress and failure messages (e.g. the scenario and seed).
    function : callable
        Importable function (workers receive it by reference).
    args : tuple
        Its positional arguments (picklable).
    """

    label: str
    function: Callable[..., Any]
    args: tuple = ()


@dataclass(frozen=True)
class Failure:
    """A task that raised.

    Attributes
    ----------
    index : int
        Position of the task in the submitted list.
    label : str
        The task's label.
    error : str
        ``ExceptionType: message``.
    traceback : str
        Where it was raised (for a log; the one-line ``error`` is for the user).
    """

    index: int
    label: str
    error: str
    traceback: str = ""


@dataclass
class Outcome:
    """Results in task order (None where the task failed) and the failures."""

    results: list[Any]
    failures: list[Failure] = field(default_factory=list)


@dataclass(frozen=True)
class ClusterConfig:
    """Where tasks run (module docstring).

    Attributes
    ----------
    workers : int or None
        Local workers; None: one per CPU core (at most one per task); 0: in this process, no Dask.
    scheduler : str or None
        Address of an existing scheduler (``tcp://HOST:PORT``); ``workers`` is then ignored.
    processes : bool
        Local workers as processes (True) or as threads of this process.
    """

    workers: int | None = None
    scheduler: str | None = None
    processes: bool = True

    def __post_init__(self) -> None:
        if self.workers is not None and self.workers < 0:
            raise ValueError(f"workers must be >= 0, got {self.workers}")

    @property
    def in_process(self) -> bool:
        """Whether the tasks run here, without Dask."""
        return self.scheduler is None and self.workers == 0


#: Run in this process (no Dask).
IN_PROCESS = ClusterConfig(workers=0)


def _single_threaded(function: Callable[..., Any], *args: Any) -> Any:
    """``function(*args)`` with one BLAS and OpenMP thread (module docstring).

    The limit is set and left (not restored on return): tasks of one process
    may run on several threads, and one task restoring the limit while
    another computes would undo it. :func:`run_tasks` restores this
    process's own limits after a run.
    """
    threadpool_limits(limits=1)
    return function(*args)


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


#: Called in the submitting process with a task's index and result as each task finishes (completion order).
ResultCallback = Callable[[int, Any], None]


def _run_here(tasks: Sequence[Task], bar: tqdm, on_result: ResultCallback | None) -> Outcome:
    outcome = Outcome(results=[None] * len(tasks))
    for i, task in enumerate(tasks):
        try:
            outcome.results[i] = _single_threaded(task.function, *task.args)
        except Exception as exc:  # noqa: BLE001 - every failure is reported with its task
            outcome.failures.append(Failure(i, task.label, _describe(exc), traceback.format_exc()))
        else:
            if on_result is not None:
                on_result(i, outcome.results[i])
        bar.update(1)
    return outcome


def _local_cluster(config: ClusterConfig, n_tasks: int):
    import logging

    from distributed import LocalCluster

    workers = config.workers or max(1, min(os.cpu_count() or 1, n_tasks))
    options: dict[str, Any] = {"n_workers": workers, "threads_per_worker": 1, "processes": config.processes,
                               "dashboard_address": ":0", "silence_logs": logging.CRITICAL}
    if config.processes:
        options["env"] = WORKER_ENV
    return LocalCluster(**options)


def _run_on_dask(tasks: Sequence[Task], config: ClusterConfig, bar: tqdm, on_result: ResultCallback | None
                 ) -> Outcome:
    from distributed import Client, as_completed

    cluster = None if config.scheduler else _local_cluster(config, len(tasks))
    client = Client(config.scheduler if config.scheduler else cluster)
    try:
        # A fresh key per entry: two equal entries run twice, and runs sharing a scheduler never collide.
        futures = [client.submit(_single_threaded, t.function, *t.args, key=f"dtmbnav-{i}-{uuid.uuid4().hex}")
                   for i, t in enumerate(tasks)]
        index = {f.key: i for i, f in enumerate(futures)}
        outcome = Outcome(results=[None] * len(tasks))
        for future in as_completed(futures):
            i = index[future.key]
            if future.status == "finished":
                outcome.results[i] = future.result()
                if on_result is not None:
                    on_result(i, outcome.results[i])
            else:
                exc = future.exception()
                tb = "".join(traceback.format_tb(future.traceback())) if future.traceback() else ""
                outcome.failures.append(Failure(i, tasks[i].label, _describe(exc), tb))
            future.release()
            bar.update(1)
        outcome.failures.sort(key=lambda f: f.index)
        return outcome
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_tasks(tasks: Sequence[Task], cluster: ClusterConfig = IN_PROCESS, progress: bool = True,
              description: str = "tasks", on_result: ResultCallback | None = None) -> Outcome:
    """Run ``tasks`` where ``cluster`` says; results in task order, failures listed (none raised).

    Parameters
    ----------
    tasks : sequence of Task
    cluster : ClusterConfig
        Default: in this process.
    progress : bool
        Show a progress bar on stderr.
    description : str
        The bar's label.
    on_result : callable, optional
        ``on_result(index, result)`` in this process as each task succeeds, in
        the order they finish (e.g. to write each result out at once, so that a
        run that is stopped keeps what finished).
    """
    with tqdm(total=len(tasks), desc=description, unit="task", disable=not progress, file=sys.stderr) as bar:
        if not tasks:
            return Outcome(results=[])
        with threadpool_limits(limits=None):   # restores this process's limits after tasks ran in it
            if cluster.in_process:
                return _run_here(tasks, bar, on_result)
            return _run_on_dask(tasks, cluster, bar, on_result)
