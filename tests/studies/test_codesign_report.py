"""Co-design of the case studies: every reported number re-checked on a fresh simulation or evaluation."""

import contextlib
import json
from dataclasses import replace

import numpy as np
import pytest
from case_designs import classical_controllers

import models
from designs.tuning import Cost, SolveOptions, Specs, TuningProblem
from studies import codesign_problems as cp
from studies import codesign_report as cr
from studies.cases import arm, ballbeam, crane, satellite, uuv
from studies.homework import statespace_controllers

#: The actuator-sizing cases by plant.
SIZING = {"arm": arm, "uuv": uuv, "ballbeam": ballbeam}


def _response(plant, block, scenario):
    """(t, y as a fraction of the step, u, run) of one fresh simulation, samples 1..N."""
    k = plant.state_names.index(scenario.tracked)
    run = models.simulate_closed_loop(plant, block, scenario.reference, scenario.duration, x0=scenario.x0)
    step = scenario.reference - scenario.x0[k]
    return run.t[1:], (run.x[1:, k] - scenario.x0[k]) / step, run.u, run


def _meets(plant, block, scenario, specs, slack=1e-5):
    """The step specs and the actuator limit, judged on a fresh simulation."""
    t, y, u, _ = _response(plant, block, scenario)
    ok = np.max(np.abs(u)) <= plant.input_limit[0] * (1 + 1e-9)
    if specs.max_rise_time_s is not None:
        ok &= bool(np.all(y[t >= specs.max_rise_time_s - 1e-9] >= 0.9 - slack))
    if specs.max_overshoot_pct is not None:
        ok &= bool(np.max(y) - 1 <= specs.max_overshoot_pct / 100 + slack)
    if specs.max_settling_time_s is not None:
        ok &= bool(np.all(np.abs(y[t >= specs.max_settling_time_s - 1e-9] - 1) <= specs.settling_band + slack))
    for state, (low, high) in specs.state_bounds.items():
        _, _, _, run = _response(plant, block, scenario)
        x = run.state(state)
        ok &= bool(np.min(x) >= low - 1e-6 * abs(low) and np.max(x) <= high + 1e-6 * abs(high))
    return bool(ok)


def _check_reported(result: cp.CaseResult, plant_cost=None):
    """Each design's numbers are a fresh problem's, and `feasible` is what a fresh simulation says."""
    name = {"crane1": "ell", "satellite": "k"}.get(result.plant)
    for method, design in result.designs.items():
        assert design.method == method
        fresh = TuningProblem(design.plant, design.block, result.scenario, specs=result.specs, cost=result.cost)
        value, _, violations = fresh.values(fresh.start())
        assert value == pytest.approx(design.closed_loop_cost, rel=1e-6), method
        assert (
            design.feasible == (not violations) == _meets(design.plant, design.block, result.scenario, result.specs)
        ), method
        assert design.status, method
        if name is None:  # actuator sizing: the value is the limit, and the objective
            assert design.plant.input_limit[0] == pytest.approx(design.value) == design.objective
        else:
            assert design.plant.params[name] == pytest.approx(design.value)
            assert design.plant_cost == pytest.approx(float(plant_cost({name: design.value})), rel=1e-9)
            assert design.objective == pytest.approx(design.closed_loop_cost + design.plant_cost, rel=1e-9)


def test_arm_sizing_short_run_reports_what_it_designed():
    """Few iterations: the wiring (limits, fresh re-evaluation, statuses), not the optimum."""
    result = arm.actuator_sizing(methods=("sequential", "simultaneous"), options=SolveOptions(max_iter=5))
    _check_reported(result)
    seq, sim = result.designs["sequential"], result.designs["simultaneous"]
    floor = cp.holding_limit(arm.CASE, arm.SIZING)
    # Control-blind: the plant-only objective's answer is the holding limit.
    assert seq.value == pytest.approx(floor)
    assert floor <= sim.value <= arm.SIZING.high
    assert "IPOPT" in seq.status and "IPOPT" in sim.status
    # The specs are a stated requirement, not a measured hand design.
    assert result.specs == arm.SIZING_SPECS == Specs(max_rise_time_s=0.6, max_overshoot_pct=5.0)


TOO_LONG = pytest.mark.skip(
    reason="its full run takes about 90 minutes here, too long for CI; its committed record "
    "(docs/codesign/ballbeam.json), every method converged, is replayed by "
    "test_committed_sizing_records_hold_on_a_fresh_simulation"
)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["arm", "uuv", pytest.param("ballbeam", marks=TOO_LONG)])
def test_full_sizing_every_method_converges_and_simultaneous_is_no_worse_than_nested(name):
    result = SIZING[name].actuator_sizing()
    _check_reported(result)
    assert set(result.designs) == set(cr.METHODS)
    assert result.converged, {m: (d.converged, d.status) for m, d in result.designs.items()}
    # Control-blind sequential sizes for holding the target alone, which misses the rise time.
    assert not result.designs["sequential"].feasible
    nested = result.designs["nested"]
    sim = result.best(("simultaneous", "simultaneous from sequential"))
    assert nested.feasible and sim is not None
    assert sim.value <= nested.value * (1 + cp.SIZING_REL_TOL)
    assert result.gain is not None and result.gain == pytest.approx(
        1
        - sim.objective
        / min(d.objective for m, d in result.designs.items() if m in ("sequential", "nested") and d.feasible)
    )


def test_hand_designs_at_the_text_limit():
    turbo = models.get("uuv").with_input_limit(250.0)
    lead_lag = classical_controllers("uuv", turbo)["lead-lag (IV.11)"]
    block = uuv.SIZING.hand_design(turbo)
    for key in ("num", "den"):
        np.testing.assert_allclose(block.gains[key], lead_lag.gains[key])
    # The re-tuning start at the text's limit is the hand design itself.
    for name in ("arm", "ballbeam"):
        sizing = SIZING[name].SIZING
        known = models.get(name).with_input_limit(sizing.text_limit)
        hand, start = sizing.hand_design(known), sizing.retune_start(known)
        np.testing.assert_allclose(start.gain_vector(), hand.gain_vector())
        scenario = cp.sizing_scenario(SIZING[name].CASE, sizing)
        runs = [models.simulate_closed_loop(known, b, scenario.reference, 1.0, x0=scenario.x0) for b in (hand, start)]
        np.testing.assert_allclose(runs[0].u, runs[1].u, atol=1e-12)
    # Below the text's limit the start keeps the text's gains and saturates at the new limit.
    small = models.get("arm").with_input_limit(0.8)
    start = arm.SIZING.retune_start(small)
    assert start.output_limit == 0.8
    np.testing.assert_allclose(start.gain_vector(), arm.SIZING.hand_design(models.get("arm")).gain_vector())


def test_sizing_specs_come_from_the_text_or_a_stated_requirement():
    assert uuv.SIZING.specs == Specs(max_rise_time_s=0.9, max_settling_time_s=3.0, max_overshoot_pct=10.0)  # IV.11
    assert "IV.11" in uuv.SIZING.specs_origin
    for case in (arm, ballbeam):
        assert "stated requirement" in case.SIZING.specs_origin and case.SIZING.specs is case.SIZING_SPECS


@pytest.mark.slow
def test_satellite_stiffness_short_run_reports_what_it_designed():
    """A short run: the wiring (ranges, costs, fresh re-evaluation, statuses), not the optimum. About 70 s
    here (27 interpreted NLPs over the 24 s its 23 s settling spec needs), so with the slow tests; the crane's
    and the arm's short runs check the same wiring in the default suite."""
    result = satellite.panel_stiffness(
        methods=("sequential", "simultaneous"),
        duration=24.0,
        options=replace(satellite.STIFFNESS_SOLVE_OPTIONS, max_iter=3, jit=False),
    )
    _check_reported(result, satellite.stiffness_cost)
    low, high = satellite.STIFFNESS_RANGE
    assert result.designs["sequential"].value == pytest.approx(low, abs=1e-6)  # its price alone: the cheapest
    for design in result.designs.values():
        assert low <= design.value <= high
        assert not design.converged  # 3 iterations: reported as the cap, or as a kept start no stage converged at
        assert "Maximum_Iterations_Exceeded" in design.status or "no stage converged" in design.status


def test_crane_short_run_reports_what_it_designed():
    result = crane.cable_transfer(
        methods=("sequential", "simultaneous"),
        duration=6.0,
        options=replace(cp.CODESIGN_SOLVE_OPTIONS, max_iter=2, jit=False),
    )
    _check_reported(result, crane.hoist_cost)
    assert result.plant == "crane1" and list(result.specs.state_bounds) == ["theta"]
    assert result.designs["sequential"].value == pytest.approx(crane.CABLE_RANGE[1], abs=1e-6)
    assert not result.converged


def test_plant_costs_in_their_units():
    # Lifting the 500 kg load by 1 m costs 2e-4 m s²/J × 500 kg × 9.81 m/s² × 1 m of ITAE.
    assert crane.hoist_cost({"ell": 19.0}) == pytest.approx(crane.HOIST_PRICE * 500 * 9.81)
    assert crane.hoist_cost({"ell": crane.CABLE_RANGE[1]}) == 0
    assert satellite.stiffness_cost({"k": 0.15}) == pytest.approx(0.15 * satellite.STIFFNESS_PRICE)


@pytest.mark.slow
def test_satellite_full_run_every_method_converges_to_one_stiffness():
    """All four methods (about 9 minutes here, most of it compiling): converged, and the three that see the
    controller reach one stiffness, the nested to Brent's resolution (1e-3 of the range)."""
    result = satellite.panel_stiffness()
    _check_reported(result, satellite.stiffness_cost)
    assert result.converged, {m: (d.converged, d.status) for m, d in result.designs.items()}
    low, high = satellite.STIFFNESS_RANGE
    values = [result.designs[m].value for m in ("nested", "simultaneous", "simultaneous from sequential")]
    assert max(values) - min(values) <= 1e-3 * (high - low)
    assert result.gain is not None and abs(result.gain) <= 1e-6


@pytest.mark.skip(
    reason="its full run takes about 45 minutes here, too long for CI; its committed record "
    "(docs/codesign/crane.json) is replayed by test_committed_plant_parameter_records_hold_on_a_fresh_simulation"
)
def test_crane_full_run_every_method_converges():
    result = crane.cable_transfer()
    _check_reported(result, crane.hoist_cost)
    assert result.converged, {m: (d.converged, d.status) for m, d in result.designs.items()}


def _fake_result(key="fake"):
    plant = models.get("arm")
    block = arm.SIZING.hand_design(plant)
    base = dict(
        method="sequential",
        value=1.0,
        objective=1.0,
        closed_loop_cost=0.1,
        plant_cost=1.0,
        feasible=True,
        violations=[],
        measured={"rise_time_s": 0.5, "overshoot": 0.01, "peak_input": 1.0},
        wall_time=0.5,
        message="ok",
        gains={},
        plant=plant,
        block=block,
        converged=True,
        status="IPOPT: Solve_Succeeded",
    )
    designs = {
        "sequential": cp.Design(**base),
        "nested": cp.Design(**base | {"method": "nested", "value": 0.9, "objective": 0.9, "wall_time": 10.0}),
        "simultaneous": cp.Design(
            **base | {"method": "simultaneous", "value": 0.8, "objective": 0.8, "feasible": False}
        ),
        "simultaneous from sequential": cp.Design(
            **base | {"method": "simultaneous from sequential", "value": 0.85, "objective": 0.85}
        ),
    }
    return cp.CaseResult(
        key=key,
        problem=f"problem {key}",
        plant="arm",
        parameter="torque limit",
        unit="N m",
        text_value=1.0,
        objective="smallest limit",
        scenario=cp.sizing_scenario(arm.CASE, arm.SIZING),
        specs=Specs(max_rise_time_s=0.5),
        cost=Cost(),
        designs=designs,
        notes=["a note"],
    )


def test_a_problem_is_converged_only_when_every_method_answered_and_converged():
    result = _fake_result()
    assert result.converged
    del result.designs["nested"]  # a run cut short: its row must not read "all converged"
    assert not result.converged
    assert "| problem fake | torque limit (N m) | 1 |" in cr.table([result]) and "| no |" in cr.table([result])


def test_gain_compares_the_best_feasible_answers():
    result = _fake_result()
    # The infeasible 0.8 does not count: 1 − 0.85 / 0.9.
    assert result.gain == pytest.approx(1 - 0.85 / 0.9)
    result.designs["nested"].feasible = result.designs["sequential"].feasible = False
    assert result.gain is None


def test_table_and_cli_write_the_document_atomically(tmp_path, monkeypatch, capsys):
    result = _fake_result()
    text = cr.table([result])
    lines = text.strip().splitlines()
    assert len(lines) == 3 and all(line.count("|") == len(cr.COLUMNS) + 1 for line in lines)
    assert (
        "| problem fake | torque limit (N m) | 1 | 1 → 1 | 0.9 → 0.9 | 0.8 → 0.8 (infeasible) | 0.85 → 0.85 | "
        "5.6 % | 0 / 10 / 0 / 0 | yes |"
    ) in text
    monkeypatch.setattr(cr, "problems", lambda: {"fake": lambda: result})
    out = tmp_path / "sub" / "codesign.md"
    assert cr.main(["--out", str(out)]) == 0
    doc = out.read_text()
    assert doc.startswith("# Co-design") and "`python -m studies.codesign_report`" in doc and "a note" in doc
    assert cr.table([result]) in doc and "status: IPOPT: Solve_Succeeded" in doc
    # The document and its records beside it, no temporary file left.
    assert sorted(p.name for p in out.parent.iterdir()) == ["codesign", "codesign.md"]
    assert [p.name for p in (out.parent / "codesign").iterdir()] == ["fake.json"]
    printed = capsys.readouterr().out
    assert "[1/1] fake ..." in printed and f"wrote {out}" in printed
    # A section appended by another report lands after the notes.
    extra = cr.report([result], "cmd", cr.SECTIONS + (lambda results, command: "\n## Open-loop co-design\n",))
    assert extra.endswith("## Open-loop co-design\n") and extra.startswith(cr.report([result], "cmd"))


def test_by_default_the_report_goes_to_stdout_and_nothing_is_written(tmp_path, monkeypatch, capsys):
    result = _fake_result()
    monkeypatch.setattr(cr, "problems", lambda: {"fake": lambda: result})
    before = {p: p.stat().st_mtime_ns for p in [cr.DOC, *cr.DOC.with_suffix("").iterdir()]}
    assert cr.main([]) == 0
    printed = capsys.readouterr().out
    assert "# Co-design" in printed and "## Local optima: the global layer" in printed
    assert {p: p.stat().st_mtime_ns for p in [cr.DOC, *cr.DOC.with_suffix("").iterdir()]} == before
    assert not (cr.DOC.with_suffix("") / "fake.json").exists()


def test_records_rebuild_the_document_without_solving(tmp_path, monkeypatch):
    result = _fake_result()
    result.designs["simultaneous"].measured["rise_time_s"] = float("inf")  # never rose: kept through JSON
    result.designs["nested"].converged = False
    monkeypatch.setattr(cr, "problems", lambda: {"fake": lambda: result, "other": lambda: _fake_result("other")})
    out, records = tmp_path / "codesign.md", tmp_path / "saved"
    assert cr.main(["--out", str(out), "--records", str(records), "--only", "fake"]) == 1  # nested unconverged
    saved = json.loads((records / "fake.json").read_text())
    assert {d["run"]["command"] for d in saved["designs"].values()} == {"python -m studies.codesign_report --only fake"}

    def unsolvable():
        raise AssertionError("a problem with a record is read, not solved, with --reuse")

    monkeypatch.setattr(cr, "problems", lambda: {"fake": unsolvable, "other": lambda: _fake_result("other")})
    assert cr.main(["--out", str(out), "--records", str(records), "--reuse"]) == 1
    doc = out.read_text()
    read = cr.from_record(saved)
    assert read.designs["simultaneous"].measured["rise_time_s"] == float("inf") and not read.converged
    for name in cr.RECORDED:
        assert [getattr(d, name) for d in read.designs.values()] == [getattr(d, name) for d in result.designs.values()]
    # Both problems in the document, the read one with the same table row as when it was solved.
    assert cr.table([result]).splitlines()[2] in doc and "| problem other |" in doc
    date = saved["designs"]["nested"]["run"]["date"]
    assert "--reuse" in doc and f"run by `python -m studies.codesign_report --only fake` on {date}" in doc
    assert (records / "other.json").exists()


def test_methods_solved_again_replace_only_theirs_in_the_record(tmp_path, monkeypatch):
    first = _fake_result()
    monkeypatch.setattr(cr, "problems", lambda: {"fake": lambda **options: first})
    out, records = tmp_path / "codesign.md", tmp_path / "saved"
    cr.main(["--out", str(out), "--records", str(records)])
    again = _fake_result()
    again.designs = {"simultaneous": again.designs["simultaneous"]}
    again.designs["simultaneous"].value = again.designs["simultaneous"].objective = 0.7
    asked = []

    def solve(**options):
        asked.append(options)
        return again

    monkeypatch.setattr(cr, "problems", lambda: {"fake": solve})
    cr.main(["--out", str(out), "--records", str(records), "--methods", "simultaneous"])
    assert asked == [{"methods": ("simultaneous",)}]
    read = cr.from_record(json.loads((records / "fake.json").read_text()))
    assert list(read.designs) == list(cr.METHODS)
    assert [d.value for d in read.designs.values()] == [1.0, 0.9, 0.7, 0.85]
    again_run = "simultaneous: run by `python -m studies.codesign_report --only fake --methods simultaneous`"
    assert any(n.startswith(again_run) for n in read.notes)
    assert any(n.startswith("sequential, nested, simultaneous from sequential: run by") for n in read.notes)
    assert "0.7 → 0.7" in out.read_text()


def test_sizing_methods_checked_before_solving():
    with pytest.raises(ValueError, match="needs 'sequential'"):
        cp.actuator_sizing(arm.CASE, arm.SIZING, methods=("simultaneous from sequential",))
    with pytest.raises(ValueError, match="unknown co-design method"):
        cp.actuator_sizing(arm.CASE, arm.SIZING, methods=("bisection",))


@pytest.mark.parametrize(
    ("method", "above_floor", "settled"),
    [("simultaneous", None, True), ("simultaneous", 2.0, False), ("sequential", None, False)],
)
def test_a_simultaneous_sizing_is_settled_within_the_bisections_resolution_of_the_holding_limit(
    monkeypatch, method, above_floor, settled
):
    """An unconverged simultaneous answer counts as settled only when a fresh run meets the specs at a
    limit less than rel_tol above the holding limit (no smaller limit holds the target): the nested
    bisection's test. The ball on beam's recorded gains: its simultaneous answer (feasible, 0.07 % above
    the holding limit), the same at 2 rel_tol above it, and its sequential answer (infeasible)."""
    saved = json.loads((cr.DOC.with_suffix("") / "ballbeam.json").read_text())["designs"][method]
    floor = cp.holding_limit(ballbeam.CASE, ballbeam.SIZING)
    limit = saved["value"] if above_floor is None else floor * (1 + above_floor * cp.SIZING_REL_TOL)
    sized = models.get("ballbeam").with_input_limit(limit)
    block = ballbeam.SIZING.retune_start(sized).with_gains(**{k: np.asarray(v) for k, v in saved["gains"].items()})
    answer = {"limit": limit, "block": block, "converged": False, "status": "IPOPT: Infeasible_Problem_Detected"}
    monkeypatch.setattr(cp, "size_actuator_simultaneous", lambda *a, **k: answer | {"message": "stub"})
    design = cp.actuator_sizing(ballbeam.CASE, ballbeam.SIZING, methods=("simultaneous",)).designs["simultaneous"]
    assert design.feasible == (method == "simultaneous")
    assert design.converged == settled
    assert ("settled: feasible within rel_tol" in design.status) == settled


@pytest.mark.parametrize("name", ["arm", "uuv", "ballbeam"])
def test_committed_sizing_records_hold_on_a_fresh_simulation(name):
    """The document's sizing answers, rebuilt from their recorded limits and gains: the limit holds the
    input, the specs hold, and the recorded peak input and overshoot are what a fresh run gives."""
    record = json.loads((cr.DOC.with_suffix("") / f"{name}.json").read_text())
    case = SIZING[name]
    plant, scenario = models.get(name), cp.sizing_scenario(case.CASE, case.SIZING)
    for method, saved in record["designs"].items():
        sized = plant.with_input_limit(saved["value"])
        block = case.SIZING.retune_start(sized).with_gains(**{k: np.asarray(v) for k, v in saved["gains"].items()})
        t, y, u, _ = _response(sized, block, scenario)
        assert _meets(sized, block, scenario, case.SIZING.specs) == saved["feasible"], method
        assert np.max(np.abs(u)) == pytest.approx(saved["measured"]["peak_input"], rel=1e-9), method
        assert np.max(y) - 1 == pytest.approx(saved["measured"]["overshoot"], rel=1e-6, abs=1e-9), method
    # Every method converged, the ball on beam's from the sequential answer on a proof that the specs are out of
    # reach from there (its recorded answer misses them, checked above).
    assert all(d["converged"] for d in record["designs"].values())


PLANT_PARAMETER = {
    "satellite": (satellite, "k", satellite.stiffness_cost, satellite.STIFFNESS_SPECS, {}),
    "crane": (crane, "ell", crane.hoist_cost, Specs(state_bounds={"theta": crane.SWING_BOUND}), "one load"),
}


@pytest.mark.parametrize("key", list(PLANT_PARAMETER))
def test_committed_plant_parameter_records_hold_on_a_fresh_simulation(key):
    """The document's plant-parameter answers, rebuilt from their recorded values and gains: the
    objective, summed by hand from a fresh simulation (ITAE as Ts Σ t_k sqrt(e_k² + δ²), δ = 1e-4 of
    the step, plus the plant's price), is the recorded one, and so is the specs' verdict."""
    case, name, price, specs, choices = PLANT_PARAMETER[key]
    record = json.loads((cr.DOC.with_suffix("") / f"{key}.json").read_text())
    base = models.get(record["plant"])
    args = (crane.STATESPACE_ONE_LOAD,) if choices else ()
    block = statespace_controllers(case.CASE, base, *args)["pole placement"]
    duration = {"satellite": satellite.STIFFNESS_DURATION, "crane": crane.TRANSFER_DURATION}[key]
    scenario = cp.step_scenario(base, case.CASE.tracked, case.CASE.step, duration)
    k = base.state_names.index(scenario.tracked)
    step = scenario.reference - scenario.x0[k]
    for method, saved in record["designs"].items():
        plant = base.with_params(**{name: saved["value"]})
        tuned = block.with_gains(**{g: np.asarray(v) for g, v in saved["gains"].items()})
        run = models.simulate_closed_loop(plant, tuned, scenario.reference, duration, x0=scenario.x0)
        error = scenario.reference - run.x[:-1, k]
        itae = np.diff(run.t)[0] * np.sum(run.t[:-1] * np.sqrt(error**2 + (1e-4 * step) ** 2))
        assert itae == pytest.approx(saved["closed_loop_cost"], rel=1e-6), method
        assert itae + price({name: saved["value"]}) == pytest.approx(saved["objective"], rel=1e-6), method
        assert _meets(plant, tuned, scenario, specs) == saved["feasible"], method


def test_committed_document_lists_every_problem_converged():
    doc = cr.DOC.read_text()
    for problem in (
        "actuator sizing: arm",
        "actuator sizing: uuv",
        "actuator sizing: ballbeam",
        "crane transfer (crane1)",
        "satellite panel",
    ):
        row = next(line for line in doc.splitlines() if line.startswith(f"| {problem} |"))
        assert row.rstrip().endswith("| yes |"), row
    assert "Maximum_Iterations_Exceeded" not in doc


# ----------------------------------------------------------------- the global layer in the report
def _layer(best_value=0.85, best_objective=0.85):
    """A global layer's record (as `codesign_problems.global_summary` writes it) with two local optima."""
    return {
        "method": "simultaneous",
        "design": "grid of 4 points, ends included",
        "sweep": [[0.5, 1.2, True], [0.7, 0.9, True], [0.9, 0.95, True], [1.1, 0.87, True]],
        "optima": [
            {"value": best_value, "objective": best_objective, "success": True, "status": "ok", "start": 1.1},
            {"value": 0.7, "objective": 0.88, "success": True, "status": "ok", "start": 0.7},
        ],
        "best": {"value": best_value, "objective": best_objective},
        "converged": True,
        "how": "least objective",
        "wall_time": 12.0,
    }


def test_the_global_table_states_the_optima_and_each_methods_gap_to_the_best():
    """Gaps by hand against the best objective 0.85: sequential 1.0 is 17.6 % above, nested 0.9 5.9 %, the
    start from (1) at 0.85 is the best itself, the infeasible simultaneous answer is not compared; a sizing
    problem has no row, a problem without a layer says so."""
    result = _fake_result()
    result.parameter, result.global_layer = "stiffness", _layer()
    text = cr.global_table([result])
    row = next(line for line in text.splitlines() if line.startswith(f"| {result.problem} (stiffness"))
    assert "| 2: 0.85 → 0.85; 0.7 → 0.88 |" in row and "| 0.85 → 0.85 |" in row
    assert "sequential: 17.6 % above; nested: 5.9 % above; simultaneous: infeasible;" in row
    assert "simultaneous from sequential: already global" in row
    assert cr.gap_text(0.85 * (1 + 1e-7), 0.85) == "already global"
    sizing, bare = _fake_result("a"), _fake_result("b")
    sizing.parameter, bare.parameter = "torque limit", "cable length"
    assert cr.global_table([sizing]) == "(none)"
    assert "not run under the global layer" in cr.global_table([bare])


def test_a_global_run_keeps_the_local_answers_and_a_local_run_keeps_the_layer(tmp_path, monkeypatch):
    """--methods global adds the layer to the record without touching its designs; a later --methods
    simultaneous replaces that design and keeps the layer."""
    monkeypatch.setattr(cr, "problems", lambda: {"fake": lambda **options: _fake_result()})
    out, records = tmp_path / "codesign.md", tmp_path / "saved"
    cr.main(["--out", str(out), "--records", str(records)])
    layered = _fake_result()
    layered.designs, layered.global_layer = {}, _layer()
    asked = []
    monkeypatch.setattr(cr, "problems", lambda: {"fake": lambda **options: asked.append(options) or layered})
    cr.main(["--out", str(out), "--records", str(records), "--methods", "global"])
    assert asked == [{"methods": ("global",)}]
    saved = json.loads((records / "fake.json").read_text())
    assert [d["value"] for d in saved["designs"].values()] == [1.0, 0.9, 0.8, 0.85]
    assert saved["global_layer"]["optima"] == _layer()["optima"]
    assert saved["global_layer"]["run"]["command"] == "python -m studies.codesign_report --only fake --methods global"
    assert "simultaneous from sequential: already global" in out.read_text()
    again = _fake_result()
    again.designs = {"simultaneous": again.designs["simultaneous"]}
    monkeypatch.setattr(cr, "problems", lambda: {"fake": lambda **options: again})
    cr.main(["--out", str(out), "--records", str(records), "--methods", "simultaneous"])
    assert json.loads((records / "fake.json").read_text())["global_layer"]["optima"] == _layer()["optima"]


def test_workers_send_the_layers_sweep_through_studies_distributed(tmp_path, monkeypatch):
    """--workers 2 opens `studies.distributed.connect(None, 2)` and the problem's `codesign_case` hands its
    executor's map to `codesign_globally`; without --workers no map is given."""
    opened, maps = [], []

    class Executor:
        def map(self, function, items):
            return [function(item) for item in items]

    executor = Executor()

    @contextlib.contextmanager
    def connect(scheduler=None, workers=None):
        opened.append((scheduler, workers))
        yield executor

    def globally(*args, map=None, **kwargs):
        maps.append(map)
        raise RuntimeError("stop at the layer")

    def solve(**options):
        result = _fake_result()
        with pytest.raises(RuntimeError, match="stop at the layer"):
            cp.codesign_case(result, None, "k", 0.1, 1.0, None, methods=("global",))
        return result

    monkeypatch.setattr(cr.distributed, "connect", connect)
    monkeypatch.setattr(cp, "codesign_globally", globally)
    monkeypatch.setattr(cr, "problems", lambda: {"fake": solve})
    cr.main(["--records", str(tmp_path / "saved"), "--methods", "global", "--workers", "2"])
    cr.main(["--records", str(tmp_path / "saved"), "--methods", "global"])
    assert opened == [(None, 2)] and maps == [executor.map, None]
    with pytest.raises(SystemExit):
        cr.main(["--workers", "0"])


def test_the_committed_satellite_layer_is_consistent_with_its_sweep_and_its_local_answers():
    """The committed record's global layer: its best is no worse than any converged sweep point (a refinement
    from the best of them), every sweep point is a converged tuning, and the nested and simultaneous answers
    recorded beside it are that optimum (parameter to 1e-4 of the range, objective to 1e-6)."""
    record = json.loads((cr.DOC.with_suffix("") / "satellite.json").read_text())
    layer = record["global_layer"]
    best = layer["best"]
    assert layer["converged"] and all(ok for _, _, ok in layer["sweep"])
    assert best["objective"] <= min(j for _, j, _ in layer["sweep"])
    low, high = layer["sweep"][0][0], layer["sweep"][-1][0]
    for method in ("nested", "simultaneous", "simultaneous from sequential"):
        design = record["designs"][method]
        assert abs(design["value"] - best["value"]) <= 1e-4 * (high - low), method
        assert design["objective"] == pytest.approx(best["objective"], rel=1e-6), method
    assert "satellite panel (panel stiffness k, N m/rad)" in cr.DOC.read_text()
