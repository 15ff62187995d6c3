"""The executors. Local: in this process, or in a pool of processes whose results are those of this
process and which an error ends at once. Dask: a LocalCluster of two workers gives the numbers of one
process (per-sample seeds from the run's seed, never from a worker), survives a worker killed mid-run,
and when workers keep dying the command fails with a clear message and writes nothing."""

import math
import multiprocessing
import os
import signal
import threading
import time

import numpy as np
import pandas as pd
import pytest
from conftest import EXAMPLE, HERE, REPO

import models
import studies
from studies import distributed, providers


# ---------------------------------------------------------------------------- Local
def test_a_local_pool_gives_each_result_once_and_map_keeps_the_order():
    values = [4.0, 9.0, 16.0, 25.0]
    before = set(multiprocessing.active_children())
    with distributed.connect(jobs=2) as executor:
        assert isinstance(executor, distributed.Local) and executor.workers == 2 and not executor.distributed
        assert executor.map(math.sqrt, values) == [2.0, 3.0, 4.0, 5.0]
        assert sorted(executor.as_completed(math.sqrt, values)) == [2.0, 3.0, 4.0, 5.0]
        pool = set(multiprocessing.active_children()) - before
        assert 1 <= len(pool) <= 2  # the pool's processes, started as tasks came
    assert not any(process.is_alive() for process in pool)  # closed with the block
    alone = distributed.Local()
    assert alone.map(math.sqrt, values) == list(alone.as_completed(math.sqrt, values)) == [2.0, 3.0, 4.0, 5.0]


def test_a_failing_task_ends_the_pools_processes_and_its_error_propagates():
    before = set(multiprocessing.active_children())
    with distributed.connect(jobs=2) as executor:
        assert executor.map(math.sqrt, [1.0, 4.0]) == [1.0, 2.0]  # the pool is up
        pool = set(multiprocessing.active_children()) - before
        with pytest.raises(ValueError, match="math domain error"):
            list(executor.as_completed(math.sqrt, [4.0, -1.0, 9.0]))
        assert pool and not any(process.is_alive() for process in pool)
        assert executor.map(math.sqrt, [9.0]) == [3.0]  # a new pool for the next tasks


distributed_package = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def client():
    """Two single-threaded worker processes that import this checkout (and the example providers)."""
    saved = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join([str(REPO), str(HERE), saved or ""]).rstrip(os.pathsep)
    try:
        with distributed.connect(workers=2) as executor:
            yield executor.client
    finally:
        if saved is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = saved


@pytest.fixture(scope="module")
def pendulum_loop():
    case, plant = studies.get("pendulum"), models.get("pendulum")
    block = providers.statespace(case, case.known_plant())["pole placement"]
    return plant, block, case.scenarios[0].reference(case, 0.0)


def test_a_monte_carlo_on_two_workers_is_the_one_process_monte_carlo(client, pendulum_loop):
    plant, block, reference = pendulum_loop
    samples = models.sample_params(plant, 120, seed=4)
    kwargs = dict(substeps=2, seed=7, noise_std=1e-3)  # noise: each sample's draw depends on its index only
    alone = models.monte_carlo(plant, block, reference, 5.0, samples, **kwargs)
    with distributed_package.get_task_stream(client) as stream:
        spread = distributed.monte_carlo(client, plant, block, reference, 5.0, samples, **kwargs)
    assert distributed.Dask(client).workers == 2
    assert len({task["worker"] for task in stream.data}) == 2  # the parts ran on both workers
    for name in ("x", "u", "measured", "xc"):
        np.testing.assert_array_equal(getattr(spread, name), getattr(alone, name))
    np.testing.assert_array_equal(spread.diverged_at, alone.diverged_at)


def test_a_study_on_dask_writes_the_same_table(client, tmp_path):
    kwargs = dict(providers=(EXAMPLE,), scenarios=["step", "mc"], mc=40, seed=3, quick=True)
    here = studies.run("arm", **kwargs)
    there = studies.run("arm", executor=client, **kwargs)
    columns = [
        "controller",
        "scenario",
        "status",
        "verdict",
        "verdict_detail",
        "rise_time_s",
        "settling_time_s",
        "overshoot_pct",
        "ss_error",
        "iae",
        "itae",
        "peak_u",
        "energy",
        "samples",
        "iae_std",
    ]
    pd.testing.assert_frame_equal(here[columns], there[columns])


@pytest.mark.slow
def test_a_worker_killed_mid_run_is_replaced_and_the_numbers_stay_the_same(client, pendulum_loop):
    plant, block, reference = pendulum_loop
    samples = models.sample_params(plant, 400, seed=5)
    alone = models.monte_carlo(plant, block, reference, 8.0, samples, substeps=2)
    found, victims = {}, []

    def run():
        found["result"] = distributed.monte_carlo(client, plant, block, reference, 8.0, samples, substeps=2)

    worker = threading.Thread(target=run)
    worker.start()
    pids = client.run(os.getpid)
    deadline = time.monotonic() + 60
    while not victims and time.monotonic() < deadline and worker.is_alive():
        busy = [address for address, tasks in client.processing().items() if tasks]
        if busy:
            victims.append(busy[0])
            os.kill(pids[busy[0]], signal.SIGKILL)
        time.sleep(0.05)
    worker.join(timeout=300)
    assert victims, "the run ended before a worker could be killed"
    np.testing.assert_array_equal(found["result"].x, alone.x)
    np.testing.assert_array_equal(found["result"].u, alone.u)
    client.wait_for_workers(2, timeout=60)  # the nanny restarted the killed one


def test_work_that_keeps_killing_its_workers_fails_with_a_clear_message(client):
    def die(_):
        os._exit(1)

    with pytest.raises(distributed.RunFailed, match="a Dask worker died while running it"):
        distributed.Dask(client).map(die, [0], what="a task that kills its worker")
    client.wait_for_workers(2, timeout=60)


@pytest.mark.slow
def test_the_command_on_dask_writes_what_one_process_writes_and_nothing_when_workers_die(tmp_path):
    from test_cli import run_cli

    common = ["arm", "uuv", "--scenario", "step,mc", "--mc", "12", "--quick"]
    done = run_cli(*common, "--provider", EXAMPLE, "--out", str(tmp_path / "alone"), "--jobs", "1")
    assert done.returncode == 0, done.stderr[-2000:]
    done = run_cli(*common, "--provider", EXAMPLE, "--out", str(tmp_path / "dask"), "--workers", "2", timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "on Dask (2 local workers)" in done.stdout
    for plant in ("arm", "uuv"):
        columns = ["controller", "scenario", "status", "verdict", "rise_time_s", "settling_time_s", "itae", "samples"]
        pd.testing.assert_frame_equal(
            pd.read_csv(tmp_path / "alone" / plant / "table.csv")[columns],
            pd.read_csv(tmp_path / "dask" / plant / "table.csv")[columns],
        )
    out = tmp_path / "dying"
    done = run_cli(
        *common, "--provider", "example_providers:killing_the_worker", "--out", str(out), "--workers", "2", timeout=900
    )
    assert done.returncode == 1
    assert "a Dask worker died while running it" in done.stderr and "nothing was written" in done.stderr
    assert not out.exists() or not any(out.iterdir())
