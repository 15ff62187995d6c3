"""The "tuned LQR" and "tuned MPC" rows: weights tuned through the nonlinear loop toward the case's specs.

For a case with a state-space design, the LQR's weights Q (the integrator-augmented state) and R
(`designs.tuned_lqr`); for a case with MPC settings, the linear MPC's weights and soft-bound prices
(`designs.tuned_mpc`). Each is tuned by `designs.weight_search.poll_search` on the table's own rule:
every run is the study's run (`studies.runner.simulate_scenario`, the nonlinear plant with its
saturating actuator) judged by `studies.judging.judge_run` against the case's `models.specs.Specs`.
The runs (`tuning_runs`) are the table's step, series of steps, input disturbance and noise on the
nominal plant, then the step on the corners of the ±known_rel box, so that the Monte Carlo's samples meet the specs too.

The objective is lexicographic in one number: a point that misses a spec on some run scores
`BARRIER` plus its largest relative excess (the phase one: how far the structure is from the specs);
a point that meets them all scores its cost, the mean over the runs of ITAE and control energy, each
relative to the start's on that run, weighted 1 : `ENERGY_WEIGHT` (the start scores 1 when it is
feasible). A search that converges with a violation left gives the row the remark "infeasible for this
structure: <spec> at best X > Y".

``python -m studies.tuned_rows PLANT`` tunes and writes ``<plant>_tuned_weights.json`` (both kinds in
one record) into the user cache, or with ``--install`` beside the case files where `tuned_weights`
(the provider) reads it; a record is written only when the search converged (or with ``--force``).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

import models
import models.compile
from designs import tuned_lqr, tuned_mpc
from designs.statespace_blocks import TrackingModel
from designs.weight_search import Evaluation, poll_search, reporter
from models import specs
from mpc import linear_mpc

from . import cases, distributed, homework, judging, runner, tuner
from .case import CaseStudy
from .provider_calls import NotProvided

KINDS = ("lqr", "mpc")
LABELS = {"lqr": "tuned LQR", "mpc": "tuned MPC"}
#: Score of a point that misses a spec, before its largest relative excess is added: above any cost.
BARRIER = 1e3
#: Excess counted for a run that diverged or failed (a finite score keeps the poll's comparisons meaningful).
DIVERGED_EXCESS = 1e2
ENERGY_WEIGHT = 0.1
#: The table's scenarios judged on the nominal plant, in the order the objective runs them.
NOMINAL = ("step", "steps", "disturbance", "noise")
#: The scenario judged on each parameter row of the box: its 2^k corners, or where there are more than
#: `MAX_CORNERS`, `N_SAMPLES` uniform samples (seed `SAMPLES_SEED`).
ROBUST = ("step",)
MAX_CORNERS, N_SAMPLES, SAMPLES_SEED = 16, 8, 1
MIN_STEP, MAX_EVALUATIONS = 0.05, 400
#: The poll's sufficient decrease c: a point is taken when it lowers the score by more than c h² (h its poll
#: step; `designs.weight_search`), 1.9e-3 at the first step, 2.5e-6 at the last (scores are near 1).
DECREASE = 1e-3
#: Each weight stays within this factor of the case's own (a weight that keeps shrinking matters less and
#: less; the box ends the drift).
WEIGHT_RANGE = 1e3
#: Tuning judges the runs against the case's step specs tightened by this fraction (a 10 % overshoot bound
#: is tuned to 9.5 %), so that the Monte Carlo's fresh samples still meet the case's own; the record's
#: verdict is the case's own specs'.
MARGIN = 0.05
#: The `models.specs.Specs` fields `MARGIN` tightens.
TIGHTENED = ("max_rise_time_s", "max_settling_time_s", "max_overshoot_pct", "max_ss_error_pct")


def store_name(case: CaseStudy) -> str:
    """File name of the case's stored weights, beside the case files."""
    return f"{case.plant}_tuned_weights.json"


def has_design(case: CaseStudy, kind: str) -> bool:
    """Whether the case has the design a `kind` row tunes (a state-space design, MPC settings)."""
    return (case.statespace if kind == "lqr" else case.mpc) is not None


def start(case: CaseStudy, kind: str) -> np.ndarray:
    """θ of the case's own design: Bryson's LQR weights (`studies.homework`) or its MPC settings' weights."""
    if kind == "lqr":
        d = homework.statespace_design(case, case.known_plant())
        return tuned_lqr.log_weights(d.Q, d.R)
    return tuned_mpc.log_weights(case.mpc)


def controller(case: CaseStudy, kind: str, theta, known: models.Plant | None = None):
    """The `kind` controller with log-weights θ, designed on `known` (default the case's known plant)."""
    known = case.known_plant() if known is None else known
    if kind == "lqr":
        return tuned_lqr.block(known, case.tracked, theta, case.sample_period, name=LABELS[kind])
    return linear_mpc(known, tuned_mpc.settings(case.mpc, theta), tracked=case.tracked)


def tuning_runs(case: CaseStudy) -> list[tuple[str, np.ndarray | None]]:
    """(scenario name, parameter row or None for the nominal plant) of every run the objective judges."""
    names = {s.name for s in case.scenarios}
    plant = models.get(case.plant)
    rows = models.corner_params(plant, case.known_rel)
    if len(rows) > MAX_CORNERS:
        rows = models.sample_params(plant, N_SAMPLES, case.known_rel, SAMPLES_SEED)
    nominal = [(name, None) for name in NOMINAL if name in names]
    return nominal + [(name, row) for name in ROBUST if name in names for row in rows]


def excess_of(violation) -> float:
    """How far one `models.specs.Violation` misses, relative: its excess / bound, or the excess itself (in the
    spec's unit) for a zero bound, a physical limit's "leaves ... by" or a drift. Positive for every
    violation, a least value's (a margin below its minimum) included."""
    return violation.excess / violation.bound if violation.bound > 0 else violation.excess


def relative_excess(verdict) -> float:
    """The largest relative excess (`excess_of`) of a verdict's violations (0 when it meets its specs,
    `DIVERGED_EXCESS` for a run that diverged, failed or oscillates without a listed violation)."""
    if verdict.ok:
        return 0.0
    finite = [min(excess_of(v), DIVERGED_EXCESS) for v in verdict.violations if not math.isnan(v.value)]
    return max(finite) if finite else DIVERGED_EXCESS


def _worst(verdict, scenario: str, excess: float) -> dict:
    """The record of a run's worst violation: scenario, spec, value, bound, unit, relative excess."""
    if not verdict.violations:
        return {"scenario": scenario, "spec": verdict.label, "value": None, "bound": None, "unit": "", "excess": excess}
    v = max(verdict.violations, key=excess_of)
    out = {"scenario": scenario, "spec": v.spec, "value": float(v.value), "bound": float(v.bound), "unit": v.unit}
    return out | ({"minimum": True} if v.minimum else {})


def tightened(case: CaseStudy, margin: float) -> CaseStudy:
    """`case` with each scenario's `TIGHTENED` bounds multiplied by 1 − margin (`case` itself for 0)."""
    if margin == 0:
        return case
    scaled = {
        name: replace(s, **{f: (1 - margin) * getattr(s, f) for f in TIGHTENED if getattr(s, f) is not None})
        for name, s in case.specs.items()
    }
    return replace(case, specs=scaled)


@dataclass(frozen=True)
class WeightObjective:
    """f(θ) of the module docstring for one case and kind (picklable with a registered case's name).

    case : a CaseStudy or a registered case's name (what a worker receives: it rebuilds the case)
    runs : `tuning_runs`;  reference : per run, the start's (ITAE, energy), or None to measure raw values
    margin : the runs are judged against the case's specs tightened by this fraction (`tightened`)
    """

    case: CaseStudy | str
    kind: str
    runs: tuple
    reference: tuple | None = None
    margin: float = 0.0

    def study(self) -> CaseStudy:
        """The case (the registered one of that name when `case` is a name)."""
        return cases.get(self.case) if isinstance(self.case, str) else self.case

    def run(self, case: CaseStudy, control, scenario: str, row) -> judging.Judgement:
        """One of the study's runs of `scenario` with the plant's parameters `row` (None: nominal), judged."""
        plant = models.get(case.plant)
        chosen = {s.name: s for s in case.scenarios}[scenario]
        _, base = runner.tracked_equilibrium(plant, case)
        result = runner.simulate_scenario(plant, control, chosen, case, runner.Options(), base, case.substeps, row)
        judged = tightened(case, self.margin)
        if row is None:  # as the table judges its nominal rows (with the loop's frequency specs, if any)
            return judging.judge_run(judged, scenario, result, plant.params, controller=control, plant=plant)
        return judging.judge_run(judged, scenario, result, dict(zip(plant.params, row)))

    def measure(self, theta) -> list[tuple[float, float]]:
        """(ITAE, energy) of every run with θ (the `reference` of a search that starts there)."""
        case = self.study()
        control = controller(case, self.kind, theta)
        out = []
        for scenario, row in self.runs:
            m = self.run(case, control, scenario, row).metrics
            out.append((float(m["itae"]), float(m["energy"])))
        return out

    def __call__(self, theta, bound: float = math.inf) -> Evaluation:
        """f(θ), stopping early (complete=False) once its lower bound reaches `bound`."""
        assert self.reference is not None, "measure the start first (with_reference)"
        case = self.study()
        try:
            control = controller(case, self.kind, theta)
        except ValueError as err:  # a weight the design refuses (a gain that is unstable when sampled)
            return Evaluation(BARRIER + DIVERGED_EXCESS, info={"worst": {"spec": str(err)}}, runs=0)
        worst, excess, total = None, 0.0, 0.0
        for k, ((scenario, row), (itae0, energy0)) in enumerate(zip(self.runs, self.reference)):
            judged = self.run(case, control, scenario, row)
            e = relative_excess(judged.verdict)
            if e > excess:
                excess, worst = e, _worst(judged.verdict, scenario, e)
            itae, energy = judged.metrics["itae"], judged.metrics["energy"]
            term = itae / itae0 + ENERGY_WEIGHT * (energy / energy0 if energy0 > 0 else 0.0)
            total += term / (1 + ENERGY_WEIGHT) if math.isfinite(term) else BARRIER
            lower = BARRIER + excess if excess > 0 else total / len(self.runs)
            if lower >= bound and k + 1 < len(self.runs):
                return Evaluation(lower, complete=False, runs=k + 1)
        value = BARRIER + excess if excess > 0 else total / len(self.runs)
        return Evaluation(value, runs=len(self.runs), info={"worst": worst, "excess": excess})

    def with_reference(self, theta) -> WeightObjective:
        """This objective normalized by the runs of θ (the start)."""
        return WeightObjective(self.case, self.kind, self.runs, tuple(self.measure(theta)), self.margin)


def objective(case: CaseStudy, kind: str, runs: Sequence | None = None, margin: float = 0.0) -> WeightObjective:
    """The normalized objective of `kind` on `case` over `runs` (default `tuning_runs`), from its start,
    judging against the case's specs tightened by `margin` (`tightened`)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    if not has_design(case, kind):
        raise ValueError(f"the {case.plant} case has no {'state-space design' if kind == 'lqr' else 'MPC settings'}")
    chosen = tuple(tuning_runs(case) if runs is None else runs)
    registered = case.plant in cases.names() and cases.get(case.plant) is case
    return WeightObjective(case.plant if registered else case, kind, chosen, margin=margin).with_reference(
        start(case, kind)
    )


def infeasible_text(worst: dict | None) -> str | None:
    """'infeasible for this structure: overshoot at best 14 % > 10 %' of a record's worst violation."""
    if not worst:
        return None
    if worst.get("value") is None:
        return f"infeasible for this structure: {worst['spec']}"
    unit = f" {worst['unit']}" if worst.get("unit") else ""
    if worst["bound"] == 0:  # a physical limit's or a bound's excess: "leaves swing angle 1 by 0.012 rad"
        value = f"{worst['value']:.3g}{unit}"
        return f"infeasible for this structure: {worst['spec']} {value} at best ({worst['scenario']})"
    side = "<" if worst.get("minimum") else ">"
    return (
        f"infeasible for this structure: {worst['spec']} at best {worst['value']:.3g}{unit} {side} "
        f"{worst['bound']:.3g}{unit} ({worst['scenario']})"
    )


def search(
    f: WeightObjective, theta0, max_evaluations: int = MAX_EVALUATIONS, mapper=None, progress=None, decrease=DECREASE
):
    """`designs.weight_search.poll_search` of `f` from θ0 as the rows run it: poll steps down to `MIN_STEP`,
    every weight within `WEIGHT_RANGE` of θ0's, a point taken on a decrease of more than `decrease` h².
    Returns its `SearchResult`."""
    box = math.log(WEIGHT_RANGE)
    return poll_search(
        f,
        theta0,
        min_step=MIN_STEP,
        max_evaluations=max_evaluations,
        mapper=mapper,
        progress=progress,
        bounds=(np.asarray(theta0) - box, np.asarray(theta0) + box),
        decrease=decrease,
    )


def tune(case: CaseStudy, kind: str, executor=None, max_evaluations: int = MAX_EVALUATIONS, progress=None) -> dict:
    """Tune the `kind` row of `case`; the record its stored-weights file keeps under `kind`.

    executor : None (one point at a time, first improvement) or a `studies.distributed` executor whose
        ``map`` runs each poll at once
    progress : `designs.weight_search.poll_search`'s progress callback
    """
    started = time.perf_counter()
    f = objective(case, kind, margin=MARGIN)
    theta0 = start(case, kind)
    mapper = None if executor is None else executor.map
    found = search(f, theta0, max_evaluations, mapper, progress)
    own = WeightObjective(f.case, kind, f.runs, f.reference)(found.x)
    feasible = own.value < BARRIER
    record = {
        "plant": case.plant,
        "kind": kind,
        "label": LABELS[kind],
        "start_log_weights": theta0.tolist(),
        "log_weights": found.x.tolist(),
        "weights": np.exp(found.x).tolist(),
        "runs": [[name, None if row is None else np.asarray(row).tolist()] for name, row in f.runs],
        "objective": {
            "barrier": BARRIER,
            "energy_weight": ENERGY_WEIGHT,
            "margin": MARGIN,
            "value": found.value,
            "value_at_the_case_specs": own.value,
        },
        "feasible": bool(feasible),
        "worst": None if feasible else own.info.get("worst"),
        "search": {
            "method": "designs.weight_search.poll_search",
            "status": found.status,
            "converged": found.converged,
            "evaluations": found.evaluations,
            "runs": found.runs,
            "final_step": found.step,
            "min_step": MIN_STEP,
            "decrease": DECREASE,
            "weight_range": WEIGHT_RANGE,
            "improvements": len(found.history) - 1,
            "start_value": found.history[0][2],
            "wall_time_s": time.perf_counter() - started,
        },
    }
    if kind == "lqr":
        model = TrackingModel.from_plant(case.known_plant(), case.tracked)
        record["K_augmented"] = tuned_lqr.gains(model, found.x)[2].tolist()
    return record


def stored(case: CaseStudy, kind: str) -> dict | None:
    """The stored record of `kind` for the case (package data beside the case files), or None."""
    record = tuner.stored(case, store_name(case))
    return None if record is None else record.get(kind)


def tuned_weights(case: CaseStudy | str, known: models.Plant | None = None) -> dict:
    """Provider of the "tuned LQR" and "tuned MPC" rows from the stored weights, designed on `known`.

    A row whose stored search ended with a violation carries it as its remark ("infeasible for this
    structure: ...", the runner's ``controller.remark``).
    NotProvided when the case has neither design with stored weights; ValueError when
    the case's own design (the search's start) has changed since the weights were stored.
    """
    case = cases.get(case) if isinstance(case, str) else case
    out = {}
    for kind in KINDS:
        record = stored(case, kind) if has_design(case, kind) else None
        if record is None:
            continue
        if not np.allclose(record["start_log_weights"], start(case, kind), rtol=1e-9, atol=1e-12):
            raise ValueError(
                f"{case.plant}: the stored {LABELS[kind]} weights start from a different design; "
                f"rerun `python -m studies.tuned_rows {case.plant}`"
            )
        row = controller(case, kind, np.asarray(record["log_weights"]), known)
        row.remark = None if record["feasible"] else infeasible_text(record["worst"])
        out[LABELS[kind]] = row
    if not out:
        raise NotProvided(f"no tuned weights stored for {case.plant}; `python -m studies.tuned_rows {case.plant}`")
    return out


def monte_carlo_check(case: CaseStudy, kind: str, theta, samples: int = 200, seed: int = 0) -> list:
    """The judged runs (`studies.judging.Judgement`) of the `kind` row with log-weights θ on the table's
    Monte Carlo, one per sample.

    Its scenario (the step on parameters uniform within ±rel, `studies.case.parameter_monte_carlo`), `samples`
    rows drawn as the table draws them (`models.sample_params`, `seed`), each run by the study's
    `studies.runner.simulate_scenario` and judged by `studies.judging.judge_run` against the case's own
    specs, its physical limits included: fresh points the search never judged (it ran the box's corners).
    """
    plant = models.get(case.plant)
    scenario = next(s for s in case.scenarios if s.monte_carlo)
    rows = models.sample_params(plant, samples, rel=scenario.rel, seed=seed)
    judge, control = WeightObjective(case, kind, ()), controller(case, kind, theta)
    return [judge.run(case, control, scenario.name, row) for row in rows]


def check_stored(case: CaseStudy, kinds, samples: int, folder: Path | None = None) -> list[str]:
    """One line per stored `kinds` row of `case` (in `folder`, default the installed records): how many of
    `samples` Monte Carlo samples meet every spec (`monte_carlo_check`) and the worst one's verdict."""
    record = tuner.stored(case, store_name(case), folder) or {}
    out = []
    for kind in kinds:
        if kind not in record:
            out.append(f"  {LABELS[kind]}: no record stored")
            continue
        verdicts = [j.verdict for j in monte_carlo_check(case, kind, np.asarray(record[kind]["log_weights"]), samples)]
        met = sum(v.ok for v in verdicts)
        out.append(f"  {LABELS[kind]}: meets every spec on {met} of {samples} samples; {specs.combine(verdicts)}")
    return out


def summary(record: dict) -> str:
    """One line of a record: status, evaluations, score and the verdict."""
    s = record["search"]
    verdict = "meets every spec" if record["feasible"] else infeasible_text(record["worst"])
    return (
        f"  {record['label']}: {s['status']}; {s['evaluations']} evaluations ({s['runs']} runs, "
        f"{s['wall_time_s']:.1f} s); score {s['start_value']:.4g} -> {record['objective']['value']:.4g}; {verdict}"
    )


def _say(text: str) -> None:
    print(text, flush=True)


def main(argv=None) -> int:
    """``python -m studies.tuned_rows [PLANT ...]``: tune the weights of each case's LQR and linear MPC, write the
    record when every search converged (or with ``--force``); 1 if one did not converge."""
    names = cases.names()
    parser = argparse.ArgumentParser(prog="python -m studies.tuned_rows", description=__doc__.split("\n")[0])
    parser.add_argument("plants", nargs="*", default=names, help=f"cases (default all: {', '.join(names)})")
    parser.add_argument("--kind", choices=KINDS, action="append", help="tune only this row (repeatable)")
    parser.add_argument("--max-evaluations", type=int, default=MAX_EVALUATIONS, help="cap per search")
    parser.add_argument("--workers", type=int, default=None, help="poll on a Dask LocalCluster of this many workers")
    parser.add_argument("--scheduler", default=None, help="poll on the Dask scheduler at this address")
    parser.add_argument("--out", type=Path, default=None, help="folder (default: tuned/ in the user cache)")
    parser.add_argument("--install", action="store_true", help=f"write into {tuner.STORE_DIR} instead")
    parser.add_argument("--force", action="store_true", help="write also when a search did not converge")
    parser.add_argument(
        "--check",
        type=int,
        default=None,
        metavar="N",
        help="instead of tuning: judge the installed rows (or those in --out) on N Monte Carlo samples",
    )
    args = parser.parse_args(argv)
    unknown = [p for p in args.plants if p not in names]
    if unknown:
        parser.error(f"unknown plant {unknown}; valid: {', '.join(names)}")
    if (
        args.max_evaluations < 1
        or (args.workers is not None and args.workers < 1)
        or (args.check is not None and args.check < 1)
    ):
        parser.error("--max-evaluations, --workers and --check must be >= 1")
    folder = tuner.STORE_DIR if args.install else (args.out or models.compile.cache_directory() / "tuned")
    if args.check is not None:
        for name in args.plants:
            case = cases.get(name)
            print(f"{name}, {args.check} Monte Carlo samples:", flush=True)
            kinds = [k for k in (args.kind or KINDS) if has_design(case, k)]
            print("\n".join(check_stored(case, kinds, args.check, args.out)), flush=True)
        return 0
    failed = []
    distributed_run = args.workers is not None or args.scheduler is not None
    with distributed.connect(args.scheduler, args.workers) as executor:
        for name in args.plants:
            case = cases.get(name)
            kinds = [k for k in (args.kind or KINDS) if has_design(case, k)]
            print(f"tuning {name}: {', '.join(LABELS[k] for k in kinds) or 'nothing to tune'} ...", flush=True)
            chosen = executor if distributed_run else None
            records = {k: tune(case, k, chosen, args.max_evaluations, reporter(20, _say)) for k in kinds}
            for record in records.values():
                print(summary(record), flush=True)
            converged = all(r["search"]["converged"] for r in records.values())
            if not converged:
                failed.append(name)
            if records and (converged or args.force):
                kept = tuner.stored(case, store_name(case), folder) or {}
                print(f"  record written: {tuner.write(case, kept | records, folder, store_name(case))}", flush=True)
            elif records:
                print("  not converged: no record written (--force writes it)", flush=True)
    if failed:
        print(f"not converged: {', '.join(failed)}", flush=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
