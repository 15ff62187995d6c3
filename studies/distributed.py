"""Where study work runs: in this process, in a pool of processes here, or on a Dask cluster.

An executor runs tasks (a function and its items) and hands back their results: `Local` in this
process, or with ``jobs > 1`` in a pool of that many processes here (``--jobs``); `Dask` on a
`dask.distributed.Client`'s workers (``--workers``, ``--scheduler``). `connect` gives the one a run
asks for and closes it afterwards. `map` returns the results in the items' order, `as_completed` as
each task finishes (the whole plants of a run, so that its progress moves as they finish).
Results do not depend on where they ran: every sample's noise comes from the run's seed and the
sample's index (`models.monte_carlo`'s ``first_sample``), never from a worker.

An error ending the run (Ctrl-C, SIGTERM, SIGHUP, a failed task) ends the pool's processes at once; a
parent that dies without a word (SIGKILL) takes them with it: each asks the kernel, as it starts,
for a SIGTERM when its parent dies (`die_with_parent`). A Dask
cluster started by `connect` is closed with its workers. A Dask worker that dies is replaced and its
work re-run by Dask, up to its ``distributed.scheduler.allowed-failures``; past that the run stops
with `RunFailed`, naming what was running, and the callers write nothing.

Tasks, plants and Block controllers travel to other processes by pickling: a plant by its registry
name and parameters, so a worker must import the module that declares it (the catalog's plants
always are), and a function by its module and name. Controllers that are not Blocks (MPC, holding
solver objects) run in the process that designed them.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import ctypes
import ctypes.util
import logging
import math
import multiprocessing
import os
import signal
import sys
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING

import numpy as np

import models
from models import checks, deferred

if TYPE_CHECKING:
    import distributed as dask_distributed
    import distributed.comm.core as dask_comm
else:  # optional (the "dask" extra), imported at the first use of a Dask executor
    dask_distributed = deferred.module("distributed")
    dask_comm = deferred.module("distributed.comm.core")


class RunFailed(RuntimeError):
    """Work sent to the cluster could not complete (a worker died too often, or the cluster went away)."""


#: prctl's option that sets the signal a process gets when its parent dies (linux/prctl.h).
PR_SET_PDEATHSIG = 1


def die_with_parent(parent: int) -> None:
    """Make this process end when process `parent` (its parent) ends, by SIGTERM: a pool worker's
    initializer, so that a parent killed by SIGKILL or a closed terminal leaves no worker running.

    On Linux the kernel sends the signal (prctl PR_SET_PDEATHSIG); a parent that died before the call
    is seen by ``os.getppid()`` no longer being `parent`, and this process ends at once. Elsewhere
    nothing is done. The kernel sends it when the *thread* that started the worker ends: `Local`
    starts its pool from the thread that gives it its first tasks (the main one, for the command).
    """
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
        return  # not allowed here (a sandbox): the worker lives as before
    if os.getppid() != parent:  # the parent died before the request: end as the signal would
        os.kill(os.getpid(), signal.SIGTERM)


class Local:
    """Run tasks in this process, or with ``jobs > 1`` in a pool of `jobs` processes started here.

    The pool's processes are started (by "spawn": a fresh interpreter each, which imports this
    package) at the first task given to them, and ended by `close`; `terminate` ends them at once.
    """

    distributed = False

    def __init__(self, jobs: int = 1):
        checks.integer(jobs, "jobs", minimum=1)
        self.jobs = jobs
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None

    @property
    def workers(self) -> int:
        """Tasks run at once: `jobs`."""
        return self.jobs

    def share(self, value):
        """`value` itself: tasks that take it are pickled with it."""
        return value

    def map(self, function: Callable, items: Sequence, what: str = "") -> list:
        """function(item) for every item, results in the items' order (in the pool when ``jobs > 1``)."""
        if self.jobs == 1:
            return [function(item) for item in items]
        with self._ending_on_error():
            futures = [self._started().submit(function, item) for item in items]
            return [future.result() for future in futures]

    def as_completed(self, function: Callable, items: Sequence, labels: Sequence[str] = ()) -> Iterator:
        """function(item) for every item, each result as its task finishes (`labels` name the tasks on
        a Dask executor; here they are not needed). With ``jobs == 1`` the items run here, in order."""
        if self.jobs == 1:
            for item in items:
                yield function(item)
            return
        with self._ending_on_error():
            futures = [self._started().submit(function, item) for item in items]
            for future in concurrent.futures.as_completed(futures):
                yield future.result()

    def _started(self) -> concurrent.futures.ProcessPoolExecutor:
        """The pool, made at the first task given to it."""
        if self._pool is None:
            context = multiprocessing.get_context("spawn")
            self._pool = concurrent.futures.ProcessPoolExecutor(
                self.jobs, mp_context=context, initializer=die_with_parent, initargs=(os.getpid(),)
            )
        return self._pool

    @contextlib.contextmanager
    def _ending_on_error(self) -> Iterator[None]:
        """On any exception (Ctrl-C, SIGTERM, a task's error, a consumer that stops) end the pool's
        processes now: leaving the pool must not wait for the tasks still running."""
        try:
            yield
        except BaseException:
            self.terminate()
            raise

    def terminate(self) -> None:
        """End the pool's processes now (SIGTERM, then wait up to 10 s for each), and the pool with them."""
        if self._pool is None:
            return
        children = multiprocessing.active_children()
        for child in children:
            child.terminate()
        for child in children:
            child.join(10)
        self.close()

    def close(self) -> None:
        """Shut the pool down once its tasks are done (nothing to do without one)."""
        if self._pool is not None:
            pool, self._pool = self._pool, None
            pool.shutdown(wait=True, cancel_futures=True)


class Dask:
    """Run work on a `dask.distributed.Client`'s workers; results come back in the order of the items."""

    distributed = True

    def __init__(self, client):
        self.client = client

    @property
    def workers(self) -> int:
        """The cluster's workers now (at least 1)."""
        return max(1, len(self.client.scheduler_info().get("workers", {})))

    def share(self, value):
        """A future of `value` held by every worker: tasks that take it (in their argument tuple) get one
        deserialized copy per worker, so what it caches (a plant's compiled functions) is built once there."""
        return self.client.scatter([value], broadcast=True, hash=False)[0]

    def map(self, function: Callable, items: Sequence, what: str = "work") -> list:
        """function(item) for every item, on the workers, results in the items' order.

        Raises
        ------
        RunFailed
            When a worker died while running it more often than the scheduler allows, or the
            connection to the cluster was lost; the task's own exceptions propagate unchanged.
        """
        futures = self.client.map(function, list(items), pure=False)
        try:
            with _failing_as_run_failed(what):
                return self.client.gather(futures)
        finally:
            self.client.cancel(futures)

    def as_completed(self, function: Callable, items: Sequence, labels: Sequence[str] = ()) -> Iterator:
        """function(item) for every item, on the workers, each result as its task finishes.

        `labels` name the tasks (their keys are "<label>-<run>", run a random id), so a failure names
        the task. Tasks not finished are cancelled when the iteration ends early.

        Raises
        ------
        RunFailed
            When a worker died while running a task more often than the scheduler allows; the task's
            own exceptions propagate unchanged.
        """
        run = uuid.uuid4().hex[:8]
        names = list(labels) or [f"task{i}" for i in range(len(items))]
        futures = [
            self.client.submit(function, item, pure=False, key=f"{name}-{run}") for name, item in zip(names, items)
        ]
        try:
            for future in dask_distributed.as_completed(futures):
                with _failing_as_run_failed(future.key, connection=False):  # a task's OSError is its own
                    result = future.result()
                yield result
        finally:
            self.client.cancel(futures)


@contextlib.contextmanager
def _failing_as_run_failed(what: str, connection: bool = True) -> Iterator[None]:
    """Turn a dead worker, and with `connection` a lost cluster (a closed connection, an OSError or a
    timeout), into `RunFailed` naming `what`."""
    try:
        yield
    except dask_distributed.KilledWorker as err:
        raise RunFailed(
            f"{what}: a Dask worker died while running it and the scheduler gave up after "
            f"retrying ({err}); nothing was written"
        ) from None
    except (dask_comm.CommClosedError, OSError, TimeoutError) as err:
        if not connection:
            raise
        raise RunFailed(f"{what}: lost the Dask cluster ({type(err).__name__}: {err}); nothing was written") from None


@contextlib.contextmanager
def connect(scheduler=None, workers: int | None = None, jobs: int = 1) -> Iterator[Local | Dask]:
    """The executor for a run: `Local` (with `jobs` processes) by default, else Dask on `scheduler`
    or on a new LocalCluster of `workers` processes. Closed (its pool, or the cluster it started) when
    the block ends; an error ending the block ends the pool's processes at once.

    Parameters
    ----------
    scheduler : None, a scheduler address ("tcp://host:8786"), or a `dask.distributed.Client`
    workers : processes of a LocalCluster started here (one thread each) when no scheduler is given
    jobs : processes of the `Local` executor's pool when neither is given (1: this process only)
    """
    if scheduler is None and workers is None:
        local = Local(jobs)
        try:
            yield local
        except BaseException:
            local.terminate()
            raise
        finally:
            local.close()
        return
    if workers is not None and (int(workers) != workers or workers < 1):
        raise ValueError(f"workers must be a whole number >= 1, got {workers!r}")
    if isinstance(scheduler, dask_distributed.Client):
        yield Dask(scheduler)
        return
    with contextlib.ExitStack() as stack:
        if scheduler is not None:
            try:
                client = stack.enter_context(dask_distributed.Client(scheduler, timeout="20s"))
            except (OSError, TimeoutError) as err:
                raise RunFailed(f"cannot reach the Dask scheduler at {scheduler!r}: {err}") from None
        else:
            cluster = stack.enter_context(
                dask_distributed.LocalCluster(
                    n_workers=int(workers or 1),
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    silence_logs=logging.ERROR,
                )
            )
            client = stack.enter_context(dask_distributed.Client(cluster))
        yield Dask(client)


def executor_of(value) -> Local | Dask:
    """An executor from what a caller passed: None (Local), a Local/Dask, or a `dask.distributed.Client`."""
    if value is None:
        return Local()
    if isinstance(value, (Local, Dask)):
        return value
    if isinstance(value, dask_distributed.Client):
        return Dask(value)
    raise TypeError(
        f"executor must be None, studies.distributed.Local/Dask or a dask.distributed.Client, "
        f"got {type(value).__name__}"
    )


# ---------------------------------------------------------------------------- Monte Carlo in parts
#: Samples per task sent to a worker, at least: fewer make the transfer and the call cost dominate.
MIN_SAMPLES_PER_TASK = 16


def _monte_carlo_part(task: tuple) -> dict:
    """One part of a split Monte Carlo, run on a worker: `models.monte_carlo` of the part's samples from
    their index in the whole run, returned as plain arrays {x, xc, u, measured, diverged_at, t, r, d}."""
    (plant, controller, reference), duration, samples, first, kwargs = task
    batch = models.monte_carlo(plant, controller, reference, duration, samples, first_sample=first, **kwargs)
    return {
        "x": np.array(batch.x),
        "xc": np.array(batch.xc),
        "u": np.array(batch.u),
        "measured": np.array(batch.measured),
        "diverged_at": np.array(batch.diverged_at),
        "t": np.array(batch.t),
        "r": np.array(batch.r),
        "d": np.array(batch.d),
    }


def monte_carlo(executor, plant, controller, reference, duration: float, param_samples, **kwargs):
    """`models.monte_carlo` with its samples split across the executor's workers; the same numbers.

    Parts of at least `MIN_SAMPLES_PER_TASK` samples, about four per worker; each part runs
    ``models.monte_carlo(..., first_sample=start)``, so sample i gets the noise of sample i
    whichever worker runs it. With a `Local` executor this is `models.monte_carlo` itself.

    Returns
    -------
    models.MonteCarloResult of all the samples
    """
    executor = executor_of(executor)
    samples = np.asarray(param_samples, dtype=float)
    if not executor.distributed or len(samples) <= MIN_SAMPLES_PER_TASK:
        return models.monte_carlo(plant, controller, reference, duration, samples, **kwargs)
    size = max(MIN_SAMPLES_PER_TASK, math.ceil(len(samples) / (4 * executor.workers)))
    starts = range(0, len(samples), size)
    kwargs = dict(kwargs, threads=1)
    loop = executor.share((plant, controller, reference))
    parts = executor.map(
        _monte_carlo_part,
        [(loop, duration, samples[a : a + size], a, kwargs) for a in starts],
        what=f"the Monte Carlo of {getattr(controller, 'name', 'a controller')} on {plant.name}",
    )
    x, xc, u, measured, diverged_at = (
        np.concatenate([p[key] for p in parts]) for key in ("x", "xc", "u", "measured", "diverged_at")
    )
    return models.MonteCarloResult(
        plant=plant,
        controller=controller.name,
        t=parts[0]["t"],
        r=parts[0]["r"],
        d=parts[0]["d"],
        x=x,
        xc=xc,
        u=u,
        measured=measured,
        params=samples,
        diverged_at=diverged_at,
    )
