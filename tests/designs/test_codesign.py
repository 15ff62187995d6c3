"""Co-design: simultaneous never worse than sequential; actuator sizing checked by simulation."""

import numpy as np
import pytest

import models
from designs.codesign import codesign, size_actuator
from designs.tuning import Cost, Scenario, Specs, TuningProblem


class RollPD(models.Block):
    """τ = kp (r − φ) − kd φ', saturated at the plant's limit; reads the state."""

    def __init__(self, limit, kp=60.0, kd=40.0):
        self.limit = limit
        super().__init__(sample_period=0.01, n_state=0, n_measured=2, n_reference=1, n_input=1,
                         gains={"kp": kp, "kd": kd}, measures="state")

    def expr(self, xc, y, r, g):
        return xc, models.saturate(g["kp"] * (r[0] - y[0]) - g["kd"] * y[1], self.limit)


def test_simultaneous_is_never_worse_than_sequential():
    """UUV roll: the centre-of-buoyancy offset L (its ballast costs 200 per metre) with a PD."""
    uuv = models.get("uuv")
    results = codesign(uuv, RollPD(uuv.input_limit[0]),
                       Scenario(reference=np.deg2rad(30), duration=5.0, tracked="phi"),
                       {"L": (0.01, 0.2)}, plant_cost=lambda p: 200 * p["L"] * 1e-3,
                       cost=Cost("itae"), specs=Specs(max_overshoot=0.05),
                       bounds={"kp": (0, 500), "kd": (0, 500)}, max_iter=100)
    seq, sim = results["sequential"], results["simultaneous"]
    assert seq.feasible and sim.feasible, (seq.message, sim.message)
    assert sim.objective <= seq.objective * (1 + 1e-9)
    # Both objectives are what they claim: re-evaluate each design on its plant independently.
    for res in (seq, sim):
        problem = TuningProblem(res.plant, res.block,
                                Scenario(reference=np.deg2rad(30), duration=5.0, tracked="phi"),
                                cost=Cost("itae"), specs=Specs(max_overshoot=0.05))
        value, _, violations = problem.values(problem.start())
        assert value == pytest.approx(res.closed_loop_cost, rel=1e-9) and not violations
        assert res.plant_cost == pytest.approx(0.2 * res.params["L"], rel=1e-12)
        assert 0.01 <= res.params["L"] <= 0.2


def _arm_saturation_pd(plant):
    """I.8 by hand: kp uses the torque left after the largest gravity torque, ζ = 0.9."""
    p = plant.params
    inertia = p["m"] * p["ell"] ** 2 / 3
    spare = plant.input_limit[0] - p["m"] * p["g"] * p["ell"] / 2
    kp = spare / np.deg2rad(50)
    wn = np.sqrt(kp / inertia)
    kd = 2 * 0.9 * wn * inertia - p["b"]
    from tests.designs.test_tuning import ArmPD
    return ArmPD(plant, kp=kp, kd=kd)


def test_actuator_sizing_finds_the_edge_of_the_rise_time_spec():
    arm = models.get("arm")
    scenario = Scenario(reference=np.deg2rad(50), duration=3.0, tracked="theta")
    specs = Specs(rise_time=0.8, max_overshoot=0.05)
    sized = size_actuator(arm, _arm_saturation_pd, scenario, specs, low=0.8, high=3.0, retune=False,
                          rel_tol=0.01)
    limit = sized["limit"]

    def meets(value):
        plant = arm.with_input_limit(value)
        res = models.simulate_closed_loop(plant, _arm_saturation_pd(plant), np.deg2rad(50), 3.0)
        assert np.max(np.abs(res.u)) <= value
        theta = res.state("theta")
        risen = np.flatnonzero(res.t >= 0.8)
        return np.all(theta[risen] >= 0.9 * np.deg2rad(50)) and np.max(theta) <= 1.05 * np.deg2rad(50)

    assert meets(limit) and not meets(limit / 1.02)
    retuned = size_actuator(arm, _arm_saturation_pd, scenario, specs, low=0.8, high=3.0, retune=True,
                            rel_tol=0.01, tune_options={"bounds": {"kp": (0, 5), "kd": (0, 1)}, "max_iter": 60})
    assert retuned["limit"] <= limit * 1.01


def test_codesign_bad_input():
    uuv = models.get("uuv")
    block = RollPD(50.0)
    scenario = Scenario(reference=0.5, duration=1.0, tracked="phi")
    with pytest.raises(ValueError, match="uuv has no parameter 'Lx'"):
        codesign(uuv, block, scenario, {"Lx": (0, 1)})
    with pytest.raises(ValueError, match="starts outside its range"):
        codesign(uuv, block, scenario, {"L": (0.1, 0.2)})
    with pytest.raises(ValueError, match="design_params is empty"):
        codesign(uuv, block, scenario, {})
    with pytest.raises(ValueError, match="even the largest limit 1 misses the specs"):
        size_actuator(uuv, lambda p: RollPD(p.input_limit[0]), scenario, Specs(rise_time=0.1), low=0.5,
                      high=1.0, retune=False)
