"""The offline tuner of the case studies' stored gains: each case's PID, tuned through the nonlinear loop.

For each case the start is its classical design's "PID" (the text's PID, or
its successive loop closure with a PID outer loop), designed from the model
known to the controller (the case's known parameter error, +5 %). Its
gains are tuned by `designs.tuning.tune` on two of the study's runs at once,
so that neither is traded for the other (`SCENARIOS`): the text's step, and
the same step with the case's input disturbance from t = 0:

* cost: per scenario, ITAE of the tracked coordinate plus control energy,
  weighted so that energy makes `ENERGY_SHARE` of the hand design's cost; the
  two scenarios weigh the same; mean over the parameter rows of
  `tuning_samples` (the corners of the ±known_rel box on the uncertain
  parameters, or random samples where there are too many corners);
* specs, per scenario: overshoot no larger than the hand design's worst on
  that scenario (or `OVERSHOOT_FLOOR`, 0.1 % of the step, where it has none),
  2 % settling no later than the hand design's worst when it settles, and a
  locally stable loop at the end of the run; tuning enforces them with a
  margin (`MARGIN` times the bounds; no overshoot at all where the bound is
  the floor) on every tuning sample, so that fresh samples meet the hand
  design's own figures;
* each gain stays within a factor `GAIN_RANGE` of the hand design's, with
  its sign (a sign flip is a different design, and far outside the box the
  loop diverges, where IPOPT's derivatives are NaN);
* the actuator stays clipped at its limit inside the loop; `tune`'s
  smoothing continuation makes the gradient survive it, and tuning stops
  when IPOPT converges (its status is stored; an iteration-limit stop is a
  failure the tests catch).

Tuning takes from seconds (arm) to an hour (crane), so it runs offline:
``python -m studies.tuner [case ...]`` tunes, validates the result on
`N_VALIDATION` fresh samples (seed `VALIDATION_SEED`) and stores gains, costs,
statuses and provenance in ``studies/cases/<case>_tuned_gains.json`` (package
data, read with `importlib.resources`). `controllers(case, known)` rebuilds
the hand design and returns it with the stored gains; it refuses when the
hand design no longer matches the one the gains were tuned from. A case
without stored gains has no "tuned" row.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from importlib import resources
from pathlib import Path

import numpy as np

import models
import models.compile
from designs.tuning import (
    CONVERGED,
    HESSIANS,
    MAX_ITER,
    PATHS,
    WIDTHS,
    Cost,
    Scenario,
    SolveOptions,
    TuningProblem,
    TuningSetup,
    check_widths,
    tune,
)
from models import files, metrics
from models import specs as specs_module
from models.specs import Specs

from . import cases, judging, runner
from .case import CaseStudy
from .homework import classical_design

START = "PID"
LABEL = "tuned"
#: The study's scenarios the tuned design is tuned on (and must not be worse on), equal weights.
SCENARIOS = ("step", "disturbance")
MAX_CORNERS, N_TUNING, TUNING_SEED = 16, 8, 1
N_VALIDATION, VALIDATION_SEED = 20, 2
ENERGY_SHARE = 0.1
MARGIN = 0.75
#: Overshoot (fraction of the step) below which a response counts as not overshooting, on fresh samples: a
#: hand design that never passes the reference gives a bound of exactly 0, which no margin can tighten, and a
#: design tuned to overshoot nowhere on its tuning samples may pass it by a hair on fresh ones. Tuning itself
#: enforces no overshoot there (`with_margin`), which converges where the floor as a bound does not
#: (docs/notes/tuning.md).
OVERSHOOT_FLOOR = 1e-3
GAIN_RANGE = 100.0
SUBSTEPS = 2
#: How the stored gains are tuned: compiled (each case's problem is solved for seconds to an hour).
TUNE_OPTIONS = SolveOptions(jit=True)
#: Folder of the stored gains when writing them (beside the case files).
STORE_DIR = Path(cases.__file__).resolve().parent


def store_name(case: CaseStudy) -> str:
    """File name of the case's stored gains, beside the case files."""
    return f"{case.plant}_tuned_gains.json"


def scenario(case: CaseStudy, name: str = "disturbance", **fields) -> Scenario:
    """The text's step from the standard equilibrium; "disturbance" adds the case's input disturbance from t = 0."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown tuning scenario {name!r}; choose from {', '.join(SCENARIOS)}")
    plant = models.get(case.plant)
    xe, _ = plant.equilibrium()
    r = xe[plant.state_names.index(case.tracked)] + case.step
    disturbance = case.input_disturbance if name == "disturbance" else 0.0
    return Scenario(
        reference=r,
        duration=case.duration,
        x0=xe,
        input_disturbance=disturbance,
        tracked=case.tracked,
        name=name,
        **fields,
    )


def scenarios(case: CaseStudy, specs: dict | None = None, costs: dict | None = None) -> list[Scenario]:
    """The `SCENARIOS`, each with its own specs and cost when given (dicts scenario name -> Specs / Cost)."""
    return [scenario(case, name, specs=(specs or {}).get(name), cost=(costs or {}).get(name)) for name in SCENARIOS]


def hand_design(case: CaseStudy, known: models.Plant | None = None):
    """The start: the case's classical "PID" block designed from `known` (default the case's known plant)."""
    return classical_design(case, known if known is not None else case.known_plant()).controllers[START]


def samples(case: CaseStudy, n: int, seed: int) -> np.ndarray:
    """(n, n_params) actual plants, uniform ±known_rel on the case's uncertain parameters."""
    return models.sample_params(models.get(case.plant), n, case.known_rel, seed)


def tuning_samples(case: CaseStudy) -> tuple[np.ndarray, str]:
    """The parameter rows tuning sees, and how they were chosen.

    The 2^k corners of the ±known_rel box where there are at most `MAX_CORNERS` (the
    extremes of a response that is monotone in each parameter); otherwise
    `N_TUNING` uniform samples (seed `TUNING_SEED`).
    """
    corners = models.corner_params(models.get(case.plant), case.known_rel)
    if len(corners) <= MAX_CORNERS:
        return corners, f"the {len(corners)} corners of the ±{100 * case.known_rel:g} % box"
    return samples(case, N_TUNING, TUNING_SEED), f"{N_TUNING} uniform samples (seed {TUNING_SEED})"


def _problem(case, block, specs: dict | None, cost: Cost, params) -> TuningProblem:
    """The tuner's problem: `block` on the case's plant over the `SCENARIOS` and the parameter rows `params`."""
    return TuningProblem(
        models.get(case.plant), block, scenarios(case, specs), cost=cost, samples=params, substeps=SUBSTEPS
    )


def _start_itae_and_energy(case, block, params) -> tuple[float, float]:
    """Mean ITAE and mean control energy Σ u² Ts of `block` over `params` rows and the scenarios."""
    problem = _problem(case, block, None, Cost("itae"), params)
    costs, _, u, _ = (np.asarray(v) for v in problem.evaluate(problem.start()))
    return float(np.mean(costs)), float(block.sample_period * np.sum(u**2) / len(params))


def worst_step(case: CaseStudy, block, params, name: str = "disturbance") -> dict:
    """Worst overshoot (fraction) and 2 % settling time (s) of `block` on scenario `name` over `params` rows."""
    plant, sc = models.get(case.plant), scenario(case, name)
    k = plant.state_names.index(case.tracked)
    # `scenario` starts at the equilibrium and steps to one constant reference.
    x0, target = sc.x0, sc.reference
    assert x0 is not None and isinstance(target, float), "scenario() gives an x0 and a constant reference"
    worst = {"overshoot": 0.0, "settling_time_s": 0.0}
    for p in params:
        run = models.simulate_closed_loop(
            plant,
            block,
            sc.reference,
            sc.duration,
            x0=sc.x0,
            params=p,
            input_disturbance=sc.input_disturbance,
            substeps=SUBSTEPS,
        )
        m = metrics.step_metrics(run.t, run.x[:, k], initial=x0[k], target=target)
        worst["overshoot"] = max(worst["overshoot"], m["overshoot_pct"] / 100)
        worst["settling_time_s"] = max(worst["settling_time_s"], m["settling_time_s"])
    return worst


def measured_specs(case: CaseStudy, block, params) -> tuple[dict, dict]:
    """Per scenario, the specs the tuned design must meet: the hand design's own worst response on `params`
    (its overshoot floored at `OVERSHOOT_FLOOR`).

    Returns ({scenario: Specs}, {scenario: worst_step}).
    """
    specs, worst = {}, {}
    for name in SCENARIOS:
        worst[name] = w = worst_step(case, block, params, name)
        settling = w["settling_time_s"]
        specs[name] = Specs(
            max_overshoot_pct=100 * max(w["overshoot"], OVERSHOOT_FLOOR),
            max_settling_time_s=settling if np.isfinite(settling) else None,
            max_spectral_abscissa=0.0,
        )
    return specs, worst


def gain_bounds(block) -> dict:
    """Each gain within a factor `GAIN_RANGE` of the hand design's, keeping its sign (zero gains: ±1)."""
    bounds = {}
    for key, g in block.gains.items():
        g = np.asarray(g, dtype=float)
        low = np.where(g > 0, g / GAIN_RANGE, g * GAIN_RANGE)
        high = np.where(g > 0, g * GAIN_RANGE, g / GAIN_RANGE)
        bounds[key] = (np.where(g == 0, -1.0, low), np.where(g == 0, 1.0, high))
    return bounds


def with_margin(specs: Specs) -> Specs:
    """The specs tuning enforces on its few samples: tighter, so that fresh samples still meet `specs`
    (no overshoot where `specs` allows only the floor's)."""
    overshoot = specs.max_overshoot_pct
    assert overshoot is not None, "measured_specs always sets max_overshoot_pct"
    settling = specs.max_settling_time_s
    return Specs(
        max_overshoot_pct=MARGIN * overshoot if overshoot > 100 * OVERSHOOT_FLOOR else 0.0,
        settling_band_pct=specs.settling_band_pct,
        max_settling_time_s=None if settling is None else MARGIN * settling,
        max_spectral_abscissa=specs.max_spectral_abscissa,
    )


def _spec_record(specs: Specs) -> dict:
    """The stored form of a scenario's specs: overshoot and settling band as fractions of the step."""
    overshoot = specs.max_overshoot_pct
    return {
        "max_overshoot": None if overshoot is None else overshoot / 100,
        "settling_time_s": specs.max_settling_time_s,
        "settling_band": specs.settling_band,
        "max_spectral_abscissa": specs.max_spectral_abscissa,
    }


def specs_from_record(record: dict) -> dict:
    """{scenario: Specs} of a stored record (without the spectral check, which needs the solution)."""
    return {
        name: Specs(
            max_overshoot_pct=None if s["max_overshoot"] is None else 100 * s["max_overshoot"],
            max_settling_time_s=s["settling_time_s"],
            settling_band_pct=100 * s["settling_band"],
        )
        for name, s in record["specs"].items()
    }


def tune_case(case: CaseStudy, options: SolveOptions = TUNE_OPTIONS, paths: str = "pointwise") -> dict:
    """Tune the case's hand design, validate on fresh samples; the record its stored-gains file keeps.

    options : how the tuning is solved (default `TUNE_OPTIONS`); its tol, widths, Hessian and jit are stored
        in the record
    paths : the specs' form on the smoothed stages (`designs.tuning.TuningSetup`), stored in the record
    """
    started = time.perf_counter()
    block = hand_design(case)
    train, chosen = tuning_samples(case)
    specs, hand_measured = measured_specs(case, block, train)
    itae, energy = _start_itae_and_energy(case, block, train)
    weight = ENERGY_SHARE / (1 - ENERGY_SHARE) * itae / energy if energy > 0 else 0.0
    cost = Cost("itae", energy_weight=weight)
    tuned_specs = {name: with_margin(s) for name, s in specs.items()}
    setup = TuningSetup(
        models.get(case.plant),
        block,
        scenarios(case, tuned_specs),
        cost=cost,
        samples=train,
        bounds=gain_bounds(block),
        substeps=SUBSTEPS,
        paths=paths,
    )
    result = tune(setup, options)
    record = {
        "plant": case.plant,
        "start": START,
        "start_gains": _listed(block.gains),
        "gains": _listed(result.gains),
        "known": f"uncertain parameters +{100 * case.known_rel:g} % (models.perturbed)",
        "scenarios": {name: _scenario_text(name) for name in SCENARIOS},
        "cost": {
            "kind": "itae",
            "energy_weight": weight,
            "energy_share_at_start": ENERGY_SHARE,
            "scenario_weights": {name: 1.0 for name in SCENARIOS},
        },
        "tuning_margin": MARGIN,
        "gain_range": GAIN_RANGE,
        "specs": {name: _spec_record(s) for name, s in specs.items()},
        "hand_measured": hand_measured,
        "tuning": {
            "samples": len(train),
            "chosen": chosen,
            "seed": TUNING_SEED,
            "rel": case.known_rel,
            "initial_cost": result.initial_cost,
            "cost": result.cost,
            "improvement": result.improvement,
            "feasible": result.feasible,
            "status": result.status,
            "tol": options.tol,
            "widths": [float(w) for w in options.widths],
            "paths": paths,
            "hessian": options.hessian,
            "converged": result.converged,
            "method": result.method,
            "stages": result.stages,
            "smoothing_gap": result.smoothing_gap,
            "message": result.message,
            "iterations": result.iterations,
            "jit": options.jit,
            "wall_time_s": time.perf_counter() - started,
        },
    }
    return record | {"validation": validate(case, record)}


def _scenario_text(name: str) -> str:
    return (
        "the text's step from the standard equilibrium"
        if name == "step"
        else "the text's step with the case's input disturbance from t = 0"
    )


def validate(case: CaseStudy, record: dict) -> dict:
    """Hand and tuned designs of `record` on `N_VALIDATION` fresh samples: costs, worst steps, violations."""
    block = hand_design(case)
    tuned = block.with_gains(**{k: np.asarray(v) for k, v in record["gains"].items()})
    fresh = samples(case, N_VALIDATION, VALIDATION_SEED)
    check = _problem(
        case, block, specs_from_record(record), Cost("itae", energy_weight=record["cost"]["energy_weight"]), fresh
    )
    _, hand_costs, hand_violations = check.values(check.start())
    _, tuned_costs, tuned_violations = check.values(tuned.gain_vector()[check.free_index])
    return {
        "samples": N_VALIDATION,
        "seed": VALIDATION_SEED,
        "hand_mean": float(np.mean(hand_costs)),
        "tuned_mean": float(np.mean(tuned_costs)),
        "hand_worst": float(np.max(hand_costs)),
        "tuned_worst": float(np.max(tuned_costs)),
        "improvement_mean": float(1 - np.mean(tuned_costs) / np.mean(hand_costs)),
        "tuned_better_on": int(np.sum(tuned_costs < hand_costs)),
        "hand_step": {name: worst_step(case, block, fresh, name) for name in SCENARIOS},
        "tuned_step": {name: worst_step(case, tuned, fresh, name) for name in SCENARIOS},
        "tuned_violations": tuned_violations,
        "hand_violations": hand_violations,
        "tuned_table_verdicts": table_verdicts(case, tuned, fresh),
    }


def table_verdicts(case: CaseStudy, block, params: np.ndarray) -> dict:
    """{scenario: verdict text} of `block` on the rows of `params` (n, n_params) in each of the `SCENARIOS`:
    the study table's own rule against the case's specs (`studies.judging.judge_run` on the study's run of
    that scenario), the samples combined as the table's Monte Carlo combines them (`models.specs.combine`)."""
    plant = models.get(case.plant)
    _, base = runner.tracked_equilibrium(plant, case)
    chosen = {s.name: s for s in case.scenarios}
    out = {}
    for name in SCENARIOS:
        verdicts = [
            judging.judge_run(
                case,
                name,
                runner.simulate_scenario(plant, block, chosen[name], case, runner.Options(), base, case.substeps, row),
                dict(zip(plant.params, row)),
            ).verdict
            for row in params
        ]
        out[name] = str(specs_module.combine(verdicts))
    return out


def _listed(gains: dict) -> dict:
    return {k: np.asarray(v, dtype=float).tolist() for k, v in gains.items()}


def stored(case: CaseStudy, name: str | None = None, folder: Path | None = None) -> dict | None:
    """The case's stored tuning record (package data beside the case files, or file `name` (default
    `store_name`) in `folder`), or None when there is none."""
    name = store_name(case) if name is None else name
    data = resources.files(cases.__name__).joinpath(name) if folder is None else Path(folder) / name
    if not data.is_file():
        return None
    return json.loads(data.read_text(encoding="utf-8"))


def controllers(case: CaseStudy, known: models.Plant | None = None) -> dict:
    """{"tuned": block}: the hand design built from `known` with the stored tuned gains.

    Raises ValueError when no gains are stored for the case, or when the hand design
    built from `known` differs from the one the gains were tuned from (rerun
    ``python -m studies.tuner NAME`` after changing a design).
    """
    record = stored(case)
    if record is None:
        raise ValueError(f"no tuned gains stored for {case.plant!r}; run `python -m studies.tuner {case.plant}`")
    block = hand_design(case, known)
    for key, value in record["start_gains"].items():
        now = np.asarray(block.gains[key], dtype=float)
        if now.shape != np.shape(value) or not np.allclose(now, value, rtol=1e-9, atol=1e-12):
            raise ValueError(
                f"{case.plant}: the stored tuned gains start from a different {START!r} design "
                f"(gain {key} is now {now.tolist()}, was {value}); "
                f"rerun `python -m studies.tuner {case.plant}`"
            )
    return {LABEL: block.with_gains(**{k: np.asarray(v) for k, v in record["gains"].items()})}


def _report_every(n: int):
    def report(iteration, objective, seconds):
        if iteration % n == 0:
            print(f"    iteration {iteration:3d}: cost {objective:.6g} ({seconds:.0f} s)", flush=True)

    return report


def write(case: CaseStudy, record: dict, folder: Path = STORE_DIR, name: str | None = None) -> Path:
    """Store `record` as the case's tuned gains (file `name`, default `store_name`) in `folder` (default
    beside the case files)."""
    return files.write_json(Path(folder) / (store_name(case) if name is None else name), record)


def _widths(text: str) -> tuple[float, ...]:
    """--widths: comma-separated numbers > 0, strictly decreasing (`designs.tuning.check_widths`)."""
    try:
        return check_widths([float(part) for part in text.split(",")])
    except ValueError as err:  # a part that is not a number, or `check_widths`' refusal
        raise argparse.ArgumentTypeError(
            f"widths must be comma-separated numbers > 0, strictly decreasing, got {text!r} ({err})"
        ) from None


def main(argv=None) -> int:
    """``python -m studies.tuner``: tune (or re-validate) each case's gains and write its record when the tuning
    converged (or with ``--force``) into ``--out`` (default the user cache's tuned/; ``--install`` writes into
    studies/cases, the records the study reads); 1 if one did not converge."""
    names = [n for n in cases.names() if cases.get(n).classical is not None]
    parser = argparse.ArgumentParser(prog="python -m studies.tuner", description=__doc__.split("\n")[0])
    parser.add_argument("plants", nargs="*", default=names, help=f"cases to tune (default all: {', '.join(names)})")
    parser.add_argument(
        "--max-iter",
        type=int,
        default=MAX_ITER,
        help=f"IPOPT iteration cap per solve (default {MAX_ITER}; a stop there is reported)",
    )
    parser.add_argument(
        "--validate", action="store_true", help="re-validate the stored gains on the fresh samples, without tuning"
    )
    parser.add_argument("--no-jit", action="store_true", help="evaluate with CasADi's virtual machine")
    parser.add_argument(
        "--widths",
        type=_widths,
        default=WIDTHS,
        help="the smoothing continuation's widths, comma-separated, strictly decreasing (default "
        f"{','.join(f'{w:g}' for w in WIDTHS)}; a start far from the answer may need 0.1 first)",
    )
    parser.add_argument(
        "--paths",
        choices=PATHS,
        default="pointwise",
        help="each spec as one inequality per sample (default) or, on the smoothed stages, one soft maximum per "
        "run (for many parameter samples and long runs)",
    )
    parser.add_argument(
        "--hessian",
        choices=HESSIANS,
        default="limited-memory",
        help="IPOPT's Hessian: L-BFGS (default) or CasADi's exact second derivatives (few gains, hard problems)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="folder for the records (default: tuned/ in the user cache, models.compile.cache_directory())",
    )
    parser.add_argument("--install", action="store_true", help=f"write the records into {STORE_DIR} instead")
    parser.add_argument("--force", action="store_true", help="write a record also when its tuning did not converge")
    args = parser.parse_args(argv)
    folder = STORE_DIR if args.install else (args.out or models.compile.cache_directory() / "tuned")
    unknown = [p for p in args.plants if p not in names]
    if unknown:
        parser.error(f"unknown plant {unknown}; valid: {', '.join(names)}")
    if args.max_iter < 1:
        parser.error(f"--max-iter must be >= 1, got {args.max_iter}")
    failed = []
    for name in args.plants:
        case = cases.get(name)
        if args.validate:
            record = stored(case)
            if record is None:
                parser.error(f"no tuned gains stored for {name!r} to validate")
            print(f"validating {name} ...", flush=True)
            record = record | {"validation": validate(case, record)}
        else:
            print(f"tuning {name} ...", flush=True)
            options = SolveOptions(
                max_iter=args.max_iter,
                jit=not args.no_jit,
                progress=_report_every(10),
                widths=args.widths,
                hessian=args.hessian,
            )
            record = tune_case(case, options, paths=args.paths)
        t, v = record["tuning"], record["validation"]
        converged = t["status"] in CONVERGED and t["converged"]
        if not converged:
            failed.append(name)
        if converged or args.force:
            print(f"  record written: {write(case, record, folder)}", flush=True)
        else:
            print("  not converged: no record written (--force writes it)", flush=True)
        steps = "; ".join(
            f"{s}: worst overshoot {100 * v['hand_step'][s]['overshoot']:.2f} -> "
            f"{100 * v['tuned_step'][s]['overshoot']:.2f} %, worst settling "
            f"{v['hand_step'][s]['settling_time_s']:.3g} -> {v['tuned_step'][s]['settling_time_s']:.3g} s"
            for s in SCENARIOS
        )
        print(
            f"  {t['message']}; {t['iterations']} iterations, {t['wall_time_s']:.1f} s; "
            f"cost {t['initial_cost']:.4g} -> {t['cost']:.4g} ({100 * t['improvement']:.1f} % better); "
            f"fresh samples: mean {v['hand_mean']:.4g} -> {v['tuned_mean']:.4g} "
            f"({100 * v['improvement_mean']:.1f} %), better on {v['tuned_better_on']}/{v['samples']}, "
            f"violations {v['tuned_violations'] or 'none'}; {steps}",
            flush=True,
        )
        for scenario_name, verdict in v.get("tuned_table_verdicts", {}).items():
            print(f"  table's verdict against the case's specs, {scenario_name}: {verdict}", flush=True)
    if failed:
        print(f"not converged: {', '.join(failed)}", flush=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
