"""Run many independent tasks on Dask distributed, one failure never stopping the others.

The embedded default is a :class:`distributed.LocalCluster` started in-process with one
single-threaded worker process per core (nothing to install or start first); ``scheduler`` names
an existing cluster instead (``tcp://HOST:8786``; its workers need ditherlab installed and the
input files at the same paths). ``scheduler="serial"`` runs the same tasks in a plain loop in
this process: the reference the fleet's results and its benchmark are compared with.

A task is ``fn(*args)`` with plain, picklable arguments and result. Every exception inside a task
is caught on the worker and returned as a one-line message (:class:`TaskResult.error`); a worker
that dies is reported the same way.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from ditherlab.core.errors import ConfigError, DitherlabError

__all__ = ["TaskResult", "guarded", "run_tasks"]


@dataclass
class TaskResult:
    """The outcome of one task: ``value`` when it ran, else ``error`` (one line)."""

    key: str
    value: Any = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


def guarded(fn: Callable[..., Any], key: str, *args: Any) -> TaskResult:
    """``fn(*args)`` as a :class:`TaskResult`: a ditherlab error keeps its own one-line
    message, anything else becomes ``"TypeName: message"`` (first line only)."""
    try:
        return TaskResult(key, fn(*args))
    except DitherlabError as exc:
        return TaskResult(key, error=str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    except Exception as exc:  # noqa: BLE001 - one recording's failure is reported, not raised
        msg = str(exc).splitlines()[0] if str(exc) else ""
        return TaskResult(key, error=f"{type(exc).__name__}: {msg}".rstrip(": "))


def _client(scheduler: str | None, workers: int | None):  # noqa: ANN202 - distributed.Client
    import distributed

    if scheduler:
        try:
            return distributed.Client(scheduler, timeout="10s"), None
        except (OSError, TimeoutError, ValueError) as exc:
            raise ConfigError(
                f"--scheduler {scheduler}: cannot connect ({type(exc).__name__}); expected the "
                "address of a running Dask scheduler, e.g. tcp://HOST:8786"
            ) from None
    n = workers or os.cpu_count() or 1
    with warnings.catch_warnings():
        # no dashboard, but the scheduler still serves /health on 8787 and warns in three
        # lines on stderr when another Dask holds that port (it takes a free one instead)
        warnings.filterwarnings("ignore", message="Port 8787 is already in use")
        cluster = distributed.LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
    return distributed.Client(cluster), cluster


def run_tasks(
    fn: Callable[..., Any],
    tasks: Sequence[tuple[str, tuple]],
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = False,
    on_result: Callable[[TaskResult], None] | None = None,
) -> list[TaskResult]:
    """Run ``fn(*args)`` for every ``(key, args)`` of ``tasks``; results in the tasks' order.

    Parameters
    ----------
    fn : a module-level function (workers import it by name)
    tasks : ``(key, args)`` pairs; keys name the tasks in messages (e.g. the file)
    scheduler : None (a LocalCluster in this process), ``"serial"`` (a loop here, no Dask) or
        the address of a running scheduler
    workers : LocalCluster worker processes (default: one per core)
    progress : Dask's progress bar on stderr (a line per finished task when stderr is not a
        terminal)
    on_result : called in this process as each task finishes (any order)

    Returns
    -------
    One :class:`TaskResult` per task, in the order of ``tasks``.
    """
    if not tasks:
        return []
    bar = progress and scheduler != "serial" and sys.stderr.isatty()
    if progress and not bar:  # a log file, CI or the serial loop: a line per finished task
        done, count = on_result, [0]

        def on_result(r: TaskResult) -> None:
            count[0] += 1
            state = "ok" if r.ok else "failed"
            print(f"fleet: {count[0]}/{len(tasks)} {r.key} {state}", file=sys.stderr, flush=True)
            if done is not None:
                done(r)

    if scheduler == "serial":
        out = []
        for key, args in tasks:
            r = guarded(fn, key, *args)
            if on_result is not None:
                on_result(r)
            out.append(r)
        return out
    import distributed

    client, cluster = _client(scheduler, workers)
    try:
        futures = [
            client.submit(guarded, fn, key, *args, key=f"ditherlab-{i}-{key}", pure=False)
            for i, (key, args) in enumerate(tasks)
        ]
        if bar:
            with contextlib.redirect_stdout(sys.stderr):
                distributed.progress(futures, notebook=False)
        index = {f.key: i for i, f in enumerate(futures)}
        out: list[TaskResult | None] = [None] * len(tasks)
        for fut in distributed.as_completed(futures):
            i = index[fut.key]
            if fut.status == "finished":
                r = fut.result()
            else:  # the worker died or the task was lost: report it like a failure inside
                exc = fut.exception()
                r = TaskResult(tasks[i][0], error=f"{type(exc).__name__}: {exc}".splitlines()[0])
            out[i] = r
            if on_result is not None:
                on_result(r)
            fut.release()
        return [r for r in out if r is not None]
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
