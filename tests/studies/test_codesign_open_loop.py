"""Open-loop co-design problems: simultaneous against nested, each against an independent answer.

- spring-mass: the semi-analytic one-switch bang-bang (formula derived in tests/mpc/test_ocp_codesign.py),
  here re-derived by simulating that bang-bang with SciPy: its end speed is zero and it reaches s*(k);
- crane cable: the envelope derivative dT*/dℓ (the cost of a longer cable) against central differences
  of T*(ℓ), and T*(ℓ) increasing over the range, so the answer is the shortest cable;
- UUV roll: the answer beats the sweep's fixed values on both sides, and obeys the holding constraint.

Quick meshes: a few seconds per problem.
"""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import models
from studies import codesign_open_loop as col
from studies import codesign_problems as cp
from studies.cases import crane as crane_case
from studies.cases import uuv as uuv_case


@pytest.fixture(scope="module")
def results():
    cache = {}

    def get(key):
        if key not in cache:
            problem = {p.key: p for p in col.problems()}[key]
            cache[key] = col.solve(problem, quick=True)
        return cache[key]

    return get


def test_the_problems_come_from_the_module_and_the_case_files():
    assert [p.key for p in col.problems()] == ["spring_mass", "spring_transfer", "uuv_roll", "crane_cable"]


@pytest.mark.parametrize("key", ["spring_mass", "uuv_roll", "crane_cable"])
def test_simultaneous_and_nested_both_converge_and_agree(key, results):
    """On these problems the global layer finds one local optimum, the plain answers' own."""
    result = results(key)
    s, n = result.simultaneous, result.nested
    for method, found in result.global_answers.items():
        assert found.converged and len(found.optima) == 1
        assert result.global_gap(method)[1] < 1e-5
    assert s.success and n.success, (s.status, n.status)
    assert s.parameter == pytest.approx(n.parameter, rel=1e-5)
    assert s.objective == pytest.approx(n.objective, rel=1e-6)  # IPOPT tol 1e-8 (simultaneous), 1e-10 (nested)
    assert s.defect < 1e-6 and n.defect < 1e-6  # verify(): CVODES against the transcription, per interval
    # Neither beats the problem at any fixed parameter of the sweep (each is a maximum or a minimum).
    for row in result.sweep:
        assert row["success"]
        better = row["objective"] > s.objective if result.problem.maximized else row["objective"] < s.objective
        assert not better or abs(row["objective"] - s.objective) < 1e-7, row


def test_the_spring_mass_is_the_catalogs_and_not_registered():
    """models.catalog.spring_mass against m s'' = −k s + u by hand, at a few states, stiffnesses and forces."""
    plant = cp.spring_mass_plant()
    assert plant.declaration is models.catalog.spring_mass
    assert plant.params == {"m": cp.SPRING_MASS, "k": 0.5} and list(plant.input_limit) == [1.0]
    assert "spring_mass" not in models.names()  # the registry lists the case studies' plants only
    for s, v, u, k in ((0.3, -0.2, 0.7, 0.5), (-1.0, 0.5, -1.0, 1.7)):
        xdot = plant.with_params(k=k).f([s, v], [u])
        np.testing.assert_allclose(xdot, [v, (u - k * s) / cp.SPRING_MASS], rtol=1e-14)


def spring_mass_bang_bang(k, switch):
    """s(T), s'(T) of m s'' = −k s + u, u = +1 then −1 after `switch`, by SciPy (independent of the formula)."""
    rhs = lambda t, y: [y[1], ((1.0 if t < switch else -1.0) - k * y[0]) / cp.SPRING_MASS]
    first = solve_ivp(rhs, (0, switch), [0, 0], rtol=1e-12, atol=1e-12)
    second = solve_ivp(rhs, (switch, cp.SPRING_TIME), first.y[:, -1], rtol=1e-12, atol=1e-12)
    return second.y[:, -1]


def test_spring_mass_matches_the_semi_analytic_answer(results):
    result = results("spring_mass")
    reference = result.reference
    k = reference["parameter"]
    omega = math.sqrt(k / cp.SPRING_MASS)
    switch = cp.SPRING_TIME - math.asin(math.sin(omega * cp.SPRING_TIME) / 2) / omega
    s_end, v_end = spring_mass_bang_bang(k, switch)
    assert v_end == pytest.approx(0.0, abs=1e-9)
    assert s_end == pytest.approx(reference["objective"], rel=1e-9)
    # The transcription (40 intervals here) within its held input's accuracy; k to 2 % (s*(k) is flat at the top).
    assert result.simultaneous.objective == pytest.approx(reference["objective"], rel=1e-3)
    assert result.simultaneous.objective <= reference["objective"] + 1e-9
    assert result.simultaneous.parameter == pytest.approx(k, rel=0.02)


def test_spring_mass_sweep_is_the_closed_form_optimum_at_each_stiffness():
    """`sweep_optimum` alone, cold: J*(k) with k fixed against s*(k) = [2 √(1 − sin²θ/4) − 1 − cos θ] / k
    (θ = √(k/m) T, derived in tests/mpc/test_ocp_codesign.py), to the 40-interval held input's accuracy."""
    problem = {p.key: p for p in col.problems()}["spring_mass"]
    rows, at_text = col.sweep_optimum(problem, cp.spring_mass(True), None, -1.0)
    assert at_text is None  # the text gives no stiffness
    assert [row["parameter"] for row in rows] == list(problem.sweep)
    for row in rows:
        theta = math.sqrt(row["parameter"] / cp.SPRING_MASS) * cp.SPRING_TIME
        exact = (2 * math.sqrt(1 - math.sin(theta) ** 2 / 4) - 1 - math.cos(theta)) / row["parameter"]
        assert row["success"] and row["final_time"] == pytest.approx(cp.SPRING_TIME)
        assert row["objective"] == pytest.approx(exact, rel=1e-3) and row["objective"] <= exact + 1e-9


def test_the_transfer_has_three_optima_and_only_the_global_layer_finds_the_best(results):
    """The Gramian's scan (`spring_transfer_reference`; tests/mpc/test_global_search.py derives it again) has
    three local minima; from 20 N/m both plain methods stop on the second, the global layer lists all three."""
    result = results("spring_transfer")
    minima = result.reference["minima"]
    assert len(minima) == 3
    for decision in (result.simultaneous, result.nested):
        assert decision.success and decision.parameter == pytest.approx(minima[1][0], rel=0.01)
    for method, found in result.global_answers.items():
        assert found.converged and len(found.optima) == 3
        for optimum, (k, j) in zip(found.optima, minima):
            assert optimum.params["k"] == pytest.approx(k, rel=0.01)
            assert optimum.objective == pytest.approx(j, rel=5e-3)  # 40 intervals' held input
        assert result.global_gap(method)[1] > 5  # the plain answer costs several times the global one


def test_crane_answer_is_the_shortest_cable_and_its_cost_is_the_slope(results):
    result = results("crane_cable")
    assert result.simultaneous.parameter == pytest.approx(crane_case.CABLE_RANGE[0], abs=1e-6)
    times = [row["objective"] for row in result.sweep]
    assert np.all(np.diff(times) > 0)  # a longer cable is slower over the whole range
    assert result.at_text["objective"] > result.simultaneous.objective
    # dT*/dℓ by the envelope theorem at ℓ = 10 m against central differences of T*(ℓ).
    setup = crane_case.cable_min_time(True)
    solver = setup.problem.solver(setup.transcription, chosen_as_parameters=True, tolerance=1e-12)
    step = 1e-3
    times = [solver.solve(plant_params={"ell": 10.0 + d}).objective for d in (-step, step)]
    difference = (times[1] - times[0]) / (2 * step)
    assert result.at_text["gradient"] == pytest.approx(difference, rel=0.05)
    assert result.nested.gradient > 0


def test_uuv_roll_is_interior_and_holdable(results):
    result = results("uuv_roll")
    low, high = uuv_case.ROLL_OFFSET_RANGE
    L = result.simultaneous.parameter
    assert low < L < high
    plant = models.get("uuv")
    roll = result.simultaneous.objective
    holding = plant.params["m"] * plant.params["g"] * L * math.sin(roll)
    assert holding <= plant.input_limit[0] + 1e-6
    below = [r["objective"] for r in result.sweep if r["parameter"] < L]
    above = [r["objective"] for r in result.sweep if r["parameter"] > L]
    assert below and above and max(below + above) < roll


def test_report_states_the_numbers(results):
    found = [results(key) for key in ("spring_mass", "crane_cable")]
    text = col.report(found, "python -m studies.codesign_open_loop --quick")
    assert text.startswith("# Open-loop co-design")
    for r in found:
        assert r.problem.title in text
        assert col._number(r.simultaneous.parameter) in text and col._number(r.nested.objective) in text
    assert "lies at the lower end of the range" in text and "At the text's ell = 10 m" in text


def test_command_line_writes_the_report(tmp_path, capsys, monkeypatch):
    out = tmp_path / "codesign_open_loop.md"
    assert col.main(["--quick", "--only", "spring_mass", "--out", str(out), "--samples", "4"]) == 0
    text = out.read_text()
    assert "spring-mass" in text and "--only spring_mass" in text and "Global layer" in text
    # By default the report goes to stdout and the committed document is left alone.
    monkeypatch.setattr(col, "DOC", tmp_path / "docs" / "codesign_open_loop.md")
    capsys.readouterr()
    assert col.main(["--quick", "--only", "spring_mass", "--samples", "0"]) == 0
    assert capsys.readouterr().out.startswith("# Open-loop co-design") and not col.DOC.exists()
    with pytest.raises(SystemExit):
        col.main(["--only", "nothing"])
    assert "unknown problem 'nothing'" in capsys.readouterr().err
