"""The nonlinear MPC's build, estimated before it starts: a horizon whose build would exceed the time or
memory limits is refused naming it, before any of the problem is built; the estimate grows with the horizon
as measured builds do; and every phase of a build is reported as it ends."""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import pytest

import models
import mpc
from models import checks
from mpc import nonlinear


def problem(horizon: int, **kwargs):
    """The arm's NMPC problem (Q = I, R = 1, 10 ms samples) with `horizon` intervals."""
    arm = models.get("arm")
    return nonlinear.NonlinearMPCProblem(arm, 0.01, horizon, np.ones(arm.nx), 1.0, **kwargs)


@pytest.fixture
def nothing_built(monkeypatch):
    """Any construction of the problem fails the test: the refusal must come before the work."""

    def never(*args, **kwargs):
        raise AssertionError("the problem was built")

    monkeypatch.setattr(nonlinear, "mpc_problem", never)


def test_a_horizon_of_5000_is_refused_on_memory_naming_the_horizon(nothing_built):
    """N = 5000 on the arm: its condensed QP's dense matrices alone, 4 x 8 bytes x (N nu) x (N (nx + nu)),
    are 2.4 GB by hand, above the 1 GiB limit."""
    assert nonlinear.build_estimate(models.get("arm"), 5000).nbytes == 8 * 4 * 5000 * 15000
    with pytest.raises(checks.ResourceLimitError, match=r"a nonlinear MPC on arm with horizon = 5000 needs about"):
        problem(5000)


def test_a_horizon_estimated_beyond_the_time_limit_is_refused_naming_it(nothing_built):
    """N = 2000 (within memory): (2000 x 3)² x BUILD_S_QUADRATIC, above 600 s; refused through the
    controller's constructor too, which uses the default limit."""
    with pytest.raises(checks.ResourceLimitError, match=r"horizon = 2000 is estimated to build in \d+ s, above"):
        problem(2000)
    arm = models.get("arm")
    with pytest.raises(checks.ResourceLimitError, match="horizon = 2000"):
        mpc.NonlinearMPC(
            arm, sample_period=0.01, horizon=2000, state_weight=np.ones(2), input_weight=1.0, tracked="theta"
        )


def test_the_limit_is_read_at_each_call_and_overridden_per_problem(monkeypatch):
    """With the module's limit below a 5-interval build's estimate it is refused; `build_time_limit`
    math.inf accepts it, and it builds."""
    estimate = nonlinear.build_estimate(models.get("arm"), 5)
    monkeypatch.setattr(nonlinear, "BUILD_TIME_LIMIT_S", estimate.seconds / 2)
    with pytest.raises(checks.ResourceLimitError, match="horizon = 5"):
        problem(5)
    assert problem(5, build_time_limit=math.inf).horizon == 5


def test_each_phase_is_reported_in_order_and_logged(caplog):
    """The callback gets every phase with the seconds since the build began (non-decreasing), the estimate
    first and "built" last; each is also an INFO line of mpc.nonlinear naming the plant and the horizon."""
    seen = []
    with caplog.at_level(logging.INFO, logger="mpc.nonlinear"):
        problem(6, progress=lambda text, seconds: seen.append((text, seconds)))
    texts = [text for text, _ in seen]
    assert texts[0].startswith("building, estimated ") and texts[-1] == "built"
    assert "linearized and condensed; compiling" in texts
    assert [s for _, s in seen] == sorted(s for _, s in seen)
    lines = [r.getMessage() for r in caplog.records if r.name == "mpc.nonlinear"]
    assert len(lines) == len(seen) and all(line.startswith("nonlinear MPC on arm, horizon 6: ") for line in lines)


def _build_seconds(horizon: int) -> float:
    started = time.perf_counter()
    problem(horizon)
    return time.perf_counter() - started


def test_the_estimate_scales_as_measured_builds(tmp_path, monkeypatch):
    """Builds at N = 20 and 60 in an empty compile cache: the estimate's ratio of the two is within a
    factor 2 of the measured ratio (whatever the machine's load, which scales both)."""
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path / "cache"))
    _build_seconds(3)  # the condensing library and the first compilation's start-up
    measured = {n: _build_seconds(n) for n in (20, 60)}
    arm = models.get("arm")
    estimated = {n: nonlinear.build_estimate(arm, n).seconds for n in (20, 60)}
    ratio = (estimated[60] / estimated[20]) / (measured[60] / measured[20])
    assert 0.5 <= ratio <= 2.0, (estimated, measured)
