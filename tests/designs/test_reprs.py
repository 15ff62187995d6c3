"""Every controller block prints its kind and its numbers, read back from its own attributes."""

import numpy as np
import pytest

import models
from designs import statespace as ss
from designs.analysis import tf
from designs.filters import TransferFunctionBlock
from designs.loops import FilteredBlock
from designs.pid import PID
from designs.statespace_blocks import ObserverFeedback, StateFeedback, TrackingModel

TS, SIGMA = 0.01, 0.05


def _g(value) -> str:
    return f"{float(np.ravel(value)[0]):.4g}"


@pytest.fixture(scope="module")
def arm():
    return models.get("arm")


@pytest.fixture(scope="module")
def blocks(arm):
    pid = PID(arm, "theta", kp=4.2, ki=1.1, kd=0.31, output_limit=1.0, sample_period=TS, sigma=SIGMA)
    pd = PID(arm, "theta", kp=0.3, kd=0.08, sample_period=TS, sigma=SIGMA)
    model = TrackingModel.from_plant(arm, "theta")
    A, B = model.linear.A, model.linear.B
    K = ss.place(A, B, [-3.0, -4.0])
    kr = ss.reference_gain(A, B, K, model.C_r)[0]
    feedback = StateFeedback(model, K, kr, sample_period=TS)
    disc = model.discrete(TS)
    M = ss.place(disc.A.T, (disc.C[:1] @ disc.A).T, [0.5, 0.6]).T
    observer = ObserverFeedback(model, K, kr, M, sample_period=TS, measured_outputs=[model.linear.output_names[0]])
    tf_block = TransferFunctionBlock(arm, "theta", tf([2.0, 1.0], [0.1, 1.0]), sample_period=TS, output_limit=1.0)
    filtered = FilteredBlock(pd, tf([1.0], [0.2, 1.0]))
    return {"pid": pid, "pd": pd, "feedback": feedback, "observer": observer, "tf": tf_block, "filtered": filtered}


def test_pid_repr_shows_kind_gains_sigma_period_and_limit(blocks):
    pid, pd = blocks["pid"], blocks["pd"]
    text = repr(pid)
    assert text.startswith("PID(")
    for key in ("kp", "ki", "kd"):
        assert f"{key}={_g(pid.gains[key])}" in text
    assert f"sigma={_g(pid.sigma)}" in text and f"Ts={_g(pid.sample_period)}" in text
    assert f"limit={_g(pid.output_limit)}" in text
    assert repr(pd).startswith("PD(") and "ki=" not in repr(pd) and "limit=None" in repr(pd)


def test_state_space_reprs_show_the_gain_rows(blocks):
    for key in ("feedback", "observer"):
        block = blocks[key]
        text = repr(block)
        assert text.startswith(type(block).__name__ + "(")
        row = "[" + ", ".join(_g(v) for v in np.ravel(block.gains["K"])) + "]"
        assert f"K={row}" in text and f"kr={_g(block.gains['kr'])}" in text
    observer = blocks["observer"]
    assert "observer_gain=[" + ", ".join(_g(v) for v in np.ravel(observer.M)) + "]" in repr(observer)


def test_filter_reprs_show_the_coefficients(blocks):
    text = repr(blocks["tf"])
    num = "[" + ", ".join(_g(v) for v in blocks["tf"].gains["num"]) + "]"
    assert text.startswith("TransferFunctionBlock(") and f"num={num}" in text
    assert repr(blocks["filtered"]).startswith("FilteredBlock(PD(")


def test_no_repr_is_the_default_object_repr(blocks):
    for block in blocks.values():
        assert " object at 0x" not in repr(block)
