"""Study work on Dask: Monte Carlo samples, parameter sweeps and whole plants on a cluster.

Without a scheduler everything runs in this process, as it always did
(`Local`). With one (`connect(scheduler=ADDRESS)`, or a `LocalCluster` of
`workers` processes with `connect(workers=N)`), `Dask.map` sends work to the
workers and gathers the results in order. Results do not depend on where
they ran: every sample's noise comes from the run's seed and the sample's
index (`models.monte_carlo`'s ``first_sample``), never from a worker.

A worker that dies is replaced and its work re-run by Dask, up to its
``distributed.scheduler.allowed-failures``; past that the run stops with
`RunFailed`, naming what was running, and the callers write nothing.

Plants and Block controllers travel to the workers by pickling: a plant by
its registry name and parameters, so a worker must import the module that
declares it (the catalog's plants always are). Controllers that are not
Blocks (MPC, holding solver objects) run in this process.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Callable, Iterator, Sequence

import numpy as np


class RunFailed(RuntimeError):
    """Work sent to the cluster could not complete (a worker died too often, or the cluster went away)."""


class Local:
    """Run everything in this process, in order."""

    workers = 1
    distributed = False

    def map(self, function: Callable, items: Sequence, what: str = "") -> list:
        return [function(item) for item in items]

    def share(self, value):
        """`value` itself: in this process there is nothing to send."""
        return value


class Dask:
    """Run work on a `dask.distributed.Client`'s workers; results come back in the order of the items."""

    distributed = True

    def __init__(self, client):
        self.client = client

    @property
    def workers(self) -> int:
        return max(1, len(self.client.scheduler_info().get("workers", {})))

    def share(self, value):
        """A future of `value` held by every worker: tasks that take it (in their argument tuple) get one
        deserialized copy per worker, so what it caches (a plant's compiled functions) is built once there."""
        return self.client.scatter([value], broadcast=True, hash=False)[0]

    def map(self, function: Callable, items: Sequence, what: str = "work") -> list:
        """function(item) for every item, on the workers.

        Raises
        ------
        RunFailed
            When a worker died while running it more often than the scheduler allows, or the
            connection to the cluster was lost; the task's own exceptions propagate unchanged.
        """
        from distributed import KilledWorker
        from distributed.comm.core import CommClosedError

        futures = self.client.map(function, list(items), pure=False)
        try:
            return self.client.gather(futures)
        except KilledWorker as err:
            raise RunFailed(
                f"{what}: a Dask worker died while running it and the scheduler gave up after "
                f"retrying ({err}); nothing was written"
            ) from None
        except (CommClosedError, OSError, TimeoutError) as err:
            raise RunFailed(
                f"{what}: lost the Dask cluster ({type(err).__name__}: {err}); nothing was written"
            ) from None
        finally:
            self.client.cancel(futures)


@contextlib.contextmanager
def connect(scheduler=None, workers: int | None = None) -> Iterator[Local | Dask]:
    """The executor for a run: `Local` by default, else Dask on `scheduler` or on a new LocalCluster.

    Parameters
    ----------
    scheduler : None, a scheduler address ("tcp://host:8786"), or a `dask.distributed.Client`
    workers : processes of a LocalCluster started here (one thread each) when no scheduler is given
    """
    if scheduler is None and workers is None:
        yield Local()
        return
    if workers is not None and (int(workers) != workers or workers < 1):
        raise ValueError(f"workers must be a whole number >= 1, got {workers!r}")
    from distributed import Client, LocalCluster

    if isinstance(scheduler, Client):
        yield Dask(scheduler)
        return
    with contextlib.ExitStack() as stack:
        if scheduler is not None:
            try:
                client = stack.enter_context(Client(scheduler, timeout="20s"))
            except (OSError, TimeoutError) as err:
                raise RunFailed(f"cannot reach the Dask scheduler at {scheduler!r}: {err}") from None
        else:
            cluster = stack.enter_context(
                LocalCluster(
                    n_workers=int(workers or 1),
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    silence_logs=logging.ERROR,
                )
            )
            client = stack.enter_context(Client(cluster))
        yield Dask(client)


def executor_of(value) -> Local | Dask:
    """An executor from what a caller passed: None (Local), a Local/Dask, or a `dask.distributed.Client`."""
    if value is None:
        return Local()
    if isinstance(value, (Local, Dask)):
        return value
    from distributed import Client

    if isinstance(value, Client):
        return Dask(value)
    raise TypeError(
        f"executor must be None, studies.distributed.Local/Dask or a dask.distributed.Client, "
        f"got {type(value).__name__}"
    )


# ---------------------------------------------------------------------------- Monte Carlo in parts
#: Samples per task sent to a worker, at least: fewer make the transfer and the call cost dominate.
MIN_SAMPLES_PER_TASK = 16


def _monte_carlo_part(task: tuple) -> dict:
    import models

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
    import models

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
