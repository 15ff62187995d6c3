"""The one way a simulated run becomes a table row: its metrics, its status and its verdict.

`judge_run` is what the study's nominal scenarios, its Monte Carlo samples,
the sweep and the designer call on each closed-loop run: the metrics of
`models.metrics.run_metrics` on the tracked coordinate, the status of
`run_status` ("ok", "degraded: ...", "diverged at t = ... s") and the verdict
of `models.specs.judge` against the case's specs for that scenario on the
plant with the run's parameters: the physical limits of the case
(`CaseStudy.state_limits`) on every run, and the frequency specs
(`models.specs.FREQUENCY_SPECS`) where the row has a linear loop (a
`models.Block`, linearized at the run's final rest point, `studies.loops`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from designs.analysis.robustness import frequency_measures
from models import Block, metrics, specs

from . import loops
from .case import CaseStudy


def solver_counts(records) -> tuple[int, int, int]:
    """(steps, steps whose solver did not succeed, steps that fell back) of per-step solver records.

    A record says success with "success" (bool) or, without it, with a "status" text naming success
    (solved, optimal, succeeded); a fallback with "fallback" (bool). A run's steps share few distinct
    record objects (`models.exported_loop.step_records`): each is read once.
    """
    steps = failed = fallback = 0
    read: dict[int, tuple[int, int, int]] = {}  # id -> its counts; `records` keeps every id alive
    for record in records or ():
        counts = read.get(id(record))
        if counts is None:
            counts = read[id(record)] = _record_counts(record)
        steps, failed, fallback = steps + counts[0], failed + counts[1], fallback + counts[2]
    return steps, failed, fallback


def _record_counts(record) -> tuple[int, int, int]:
    """(1, failed, fell back) of one step's record; (0, 0, 0) for what is not a record (a Mapping)."""
    if not isinstance(record, Mapping):
        return 0, 0, 0
    if "success" in record:
        failed = not bool(record["success"])
    elif "status" in record:
        text = str(record["status"]).lower().replace(" ", "_")
        failed = not any(word in text for word in ("solved", "optimal", "succeeded", "success"))
    else:
        failed = False
    return 1, int(failed), int(bool(record.get("fallback", False)))


def degraded_status(steps: int, failed: int, fallback: int, what: str = "steps") -> str | None:
    """'degraded: solver failed on 3 of 500 steps, fallback on 2' (None when nothing failed)."""
    if not failed and not fallback:
        return None
    parts = [f"solver failed on {failed} of {steps} {what}"] if failed else []
    parts += [f"fallback on {fallback}" + ("" if failed else f" of {steps} {what}")] if fallback else []
    return "degraded: " + ", ".join(parts)


def run_status(result) -> str:
    """A run's status as the study tables write it: "diverged at t = ... s", "degraded: ..." or "ok"."""
    if result.diverged_at is not None:
        return f"diverged at t = {result.diverged_at:.3g} s"
    return degraded_status(*solver_counts(result.status)) or "ok"


def solver_issues(result) -> float:
    """Steps whose solver record does not report success (NaN when there are no records)."""
    if not result.status:
        return math.nan
    return float(solver_counts(result.status)[1])


def verdict_columns(verdict: specs.Verdict) -> dict:
    """The table's verdict columns of a `models.specs.Verdict`: its label and what it found."""
    return {"verdict": verdict.label, "verdict_detail": verdict.detail}


def remarked(detail, remark: str) -> str:
    """A row's verdict detail with its controller's remark first (``controller.remark``, a text every row
    of that controller carries, such as a tuned design's certificate that its structure cannot meet the
    case's specs): "infeasible for this structure: overshoot at best 19 % > 10 %; this run: overshoot
    25.8 % > 10 %". The detail alone when there is no remark."""
    detail = "" if detail is None or (isinstance(detail, float) and math.isnan(detail)) else str(detail)
    if not remark:
        return detail
    return f"{remark}; this run: {detail}" if detail else remark


@dataclass(frozen=True)
class Judgement:
    """One run judged: `metrics` (the columns of `models.metrics.run_metrics`), `status` (`run_status`),
    `verdict` (a `models.specs.Verdict`), and the run's divergence time (s, None) and solver issues."""

    metrics: dict
    status: str
    verdict: specs.Verdict
    diverged_at: float | None
    solver_issues: float

    def row(self) -> dict:
        """The table row's columns: metrics, status, diverged_at_s, samples (1), solver_issues, verdict."""
        return (
            self.metrics
            | {
                "status": self.status,
                "diverged_at_s": self.diverged_at,
                "samples": 1,
                "solver_issues": self.solver_issues,
            }
            | verdict_columns(self.verdict)
        )


def units(case: CaseStudy) -> dict:
    """{tracked state: its unit, "input": the input's unit} of a case, for the verdict's detail."""
    return {case.tracked: case.tracked_unit, "input": case.input_unit}


def check_specs(case: CaseStudy, plant) -> None:
    """Refuse, before any work, a case whose specs its scenarios or its plant (a `models.Plant`) cannot
    meet or judge (`models.specs.Specs.validate`): a step spec on a scenario without a step, a time spec
    after a scenario's end, a bound, final value or limit on a state the plant does not have, a tracked
    coordinate's bound that excludes a commanded level. ValueError naming the scenario, the field and
    its value."""
    xe, _ = plant.equilibrium()
    if case.tracked not in plant.state_names:
        raise ValueError(f"{case.name}: tracked = {case.tracked!r}, and {plant.name} has no such state")
    base = float(xe[list(plant.state_names).index(case.tracked)])
    for scenario in case.scenarios:
        judged = case.specs_for(scenario.name, plant.params)
        targets = [base, *(base + level * case.step for level in scenario.levels)]
        judged.validate(
            plant.state_names,
            tracked=case.tracked,
            targets=targets,
            duration=scenario.duration(case),
            where=f" {scenario.name!r} of {case.name}",
        )


def linear_loop_measures(plant, controller, result) -> dict | None:
    """The frequency measures (`designs.analysis.robustness.FrequencyMeasures.as_dict`) of `controller`'s loop
    on `plant` (a `models.Plant`), broken at the plant input and linearized at the run's final rest point
    (`studies.loops`); None when the row has no linear loop (a controller that is not a `models.Block`, or
    a run that diverged)."""
    if not isinstance(controller, Block) or plant is None or result.diverged_at is not None:
        return None
    point = loops.final_point(plant, controller, result)
    return frequency_measures(loops.loop(plant, controller, point)).as_dict()


def judge_run(
    case: CaseStudy, scenario: str, result, params: Mapping[str, float], *, controller=None, plant=None
) -> Judgement:
    """Judge one closed-loop run (a `models.ClosedLoopResult`) of `scenario` on the plant with `params`
    (name -> value, SI units) against the case's specs for that scenario (`CaseStudy.specs_for`).

    `controller` and `plant` (the `models.Plant` simulated): where the specs have frequency fields and the
    controller is a `models.Block`, its linearized loop is measured (`linear_loop_measures`) and judged;
    without them, or for a controller without a linear loop, the frequency specs are not judged.
    """
    judged = case.specs_for(scenario, params)
    measured = metrics.run_metrics(result, case.tracked, judged.state_bounds, band=judged.settling_band)
    status = run_status(result)
    frequency = linear_loop_measures(plant, controller, result) if judged.frequency_specs else None
    verdict = specs.judge(
        judged, result, case.tracked, case.step, status, measured=measured, units=units(case), frequency=frequency
    )
    return Judgement(measured, status, verdict, result.diverged_at, solver_issues(result))


def meets_everywhere(table):
    """controller -> whether its every row of a study table (a pandas DataFrame with controller, verdict and,
    if any, status) is "ok" and meets its specs (`models.specs.MEETS`), as a boolean Series. What "best"
    asks of a controller (console, summary, heat map): one that violates its specs in any scenario is
    never the best of one."""
    good = table.verdict == specs.MEETS
    if "status" in table:
        good &= table.status == "ok"
    return good.groupby(table.controller).all()
