"""One sample period and one σ per case: every block a case designs runs at its `sample_period` (an MPC at a
whole multiple of it, an observer problem at its `observer_sample_period`), and every PID part has its σ."""

import math

import pytest
from case_designs import classical_controllers, statespace_controllers

import models
import studies
from studies import homework

CASES = studies.names()


def _parts(block):
    """The block and the blocks it is built of (a cascade's outer and inner, a filter's block)."""
    yield block
    for name in ("outer", "inner", "block"):
        part = getattr(block, name, None)
        if isinstance(part, models.Block):
            yield from _parts(part)


@pytest.mark.parametrize("name", CASES)
def test_classical_blocks_run_at_the_case_sample_period_with_its_sigma(name):
    case = studies.get(name)
    blocks = classical_controllers(name)
    assert set(homework.LABELS) <= set(blocks)
    for label, block in blocks.items():
        for part in _parts(block):
            assert part.sample_period == case.sample_period, (label, part.name)
            if hasattr(part, "sigma"):
                assert part.sigma == case.derivative_time_constant, (label, part.name)


@pytest.mark.parametrize("name", CASES)
def test_statespace_blocks_and_mpc_settings_follow_the_case_sample_period(name):
    case = studies.get(name)
    for label, block in statespace_controllers(name).items():
        expected = case.observer_sample_period if label == "observer-based" else case.sample_period
        assert block.sample_period == expected, label
    samples = case.mpc.sample_period / case.sample_period
    assert samples >= 1 and math.isclose(samples, round(samples), rel_tol=0, abs_tol=1e-12)
