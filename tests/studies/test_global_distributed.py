"""The global layer on a real Dask cluster: a LocalCluster of two worker processes (one thread each, through
`studies.distributed.connect`) gives the one-process answer bit for bit, on the spring's minimum-energy
transfer (three local optima; the problem travels by name, `studies.codesign_problems.spring_transfer_ocp`)."""

from __future__ import annotations

import numpy as np
import pytest

import mpc
from mpc import global_search
from studies import codesign_problems, distributed

TRANSCRIPTION = mpc.Collocation(intervals=40)


@pytest.mark.slow
def test_the_dask_run_on_two_processes_equals_the_one_process_run_bit_for_bit():
    """Every sweep point and every refinement starts from the same start in a fresh solver, so neither the
    process nor the order changes a bit: the sweep, the listed optima and the best answer's decision vector."""
    problem = codesign_problems.spring_transfer_ocp
    here = global_search.codesign(problem, TRANSCRIPTION, samples=8)
    with distributed.connect(workers=2) as executor:
        assert isinstance(executor, distributed.Dask) and executor.workers == 2
        there = global_search.codesign(problem, TRANSCRIPTION, samples=8, map=executor.map)
    assert len(here.optima) >= 2  # a landscape with several optima, or the test proves little
    assert here.sweep == there.sweep
    assert here.optima == there.optima
    assert np.array_equal(here.answer.decision, there.answer.decision)
