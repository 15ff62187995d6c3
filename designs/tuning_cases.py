"""Tuned designs of the six case studies: the text's PID, tuned through the nonlinear loop.

For each plant the start is the hand design labelled "PID" by `designs.classical`
(the text's PID, or its successive loop closure with a PID outer loop),
designed from the model known to the controller (the text's +5 % error). Its
gains are tuned by `designs.tuning.tune` on the study's "disturbance" run (the
text's step with the case's input disturbance from t = 0):

* cost: ITAE of the tracked coordinate plus control energy, weighted so that
  energy makes `ENERGY_SHARE` of the hand design's cost, mean over the
  parameter rows of `tuning_samples` (the corners of the ±5 % box on the
  uncertain parameters, or random samples where there are too many corners);
* specs: overshoot no larger than the hand design's worst (at least 2 %),
  2 % settling no later than the hand design's worst when it settles, and a
  locally stable loop at the end of the run; tuning enforces them with a
  margin (`MARGIN` times the bounds) on every tuning sample, so that the
  validation samples meet the bounds themselves;
* each gain stays within a factor `GAIN_RANGE` of the hand design's, with
  its sign (a sign flip is a different design, and far outside the box the
  loop diverges, where IPOPT's derivatives are NaN);
* the actuator stays clipped at its limit inside the loop.

Tuning takes from seconds (arm) to minutes (crane), so it runs offline:
``python -m designs.tuning_cases [plant ...]`` tunes, validates the result on
`N_VALIDATION` fresh samples (seed `VALIDATION_SEED`) and stores gains, costs
and provenance in ``tuned_gains.json``. `controllers(name, known)` rebuilds the
hand design and returns it with the stored gains; it refuses when the hand
design no longer matches the one the gains were tuned from.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import models
from models import files, metrics
from designs import classical
from designs.tuning import Cost, Scenario, Specs, TuningProblem, tune

START = "PID"
LABEL = "tuned"
REL = 0.05
MAX_CORNERS, N_TUNING, TUNING_SEED = 16, 8, 1
N_VALIDATION, VALIDATION_SEED = 20, 2
ENERGY_SHARE = 0.1
MIN_OVERSHOOT = 0.02
MARGIN = 0.75
GAIN_RANGE = 100.0
SUBSTEPS = 2
PLANTS = ("arm", "pendulum", "satellite", "uuv", "ballbeam", "crane")
STORE = Path(__file__).with_name("tuned_gains.json")


def known_plant(name: str) -> models.Plant:
    """The model the studies' controllers are designed from: uncertain parameters +5 %."""
    return models.perturbed(models.get(name), REL, 1.0)


def scenario(name: str) -> Scenario:
    """The text's step from the standard equilibrium, with the case's input disturbance from t = 0."""
    plant, case = models.get(name), models.case(name)
    xe, _ = plant.equilibrium()
    r = xe[plant.state_names.index(case.tracked)] + case.step
    return Scenario(reference=r, duration=case.duration, x0=xe, input_disturbance=case.input_disturbance)


def hand_design(name: str, known: models.Plant | None = None):
    """The start: designs.classical's "PID" block designed from `known` (default `known_plant`)."""
    return classical.controllers(name, known if known is not None else known_plant(name))[START]


def samples(name: str, n: int, seed: int) -> np.ndarray:
    """(n, n_params) actual plants, uniform ±5 % on the case's uncertain parameters."""
    return models.sample_params(models.get(name), n, REL, seed)


def tuning_samples(name: str) -> tuple[np.ndarray, str]:
    """The parameter rows tuning sees, and how they were chosen.

    The 2^k corners of the ±5 % box where there are at most `MAX_CORNERS` (the
    extremes of a response that is monotone in each parameter); otherwise
    `N_TUNING` uniform samples (seed `TUNING_SEED`).
    """
    corners = models.corner_params(models.get(name), REL)
    if len(corners) <= MAX_CORNERS:
        return corners, f"the {len(corners)} corners of the ±{100 * REL:g} % box"
    return samples(name, N_TUNING, TUNING_SEED), f"{N_TUNING} uniform samples (seed {TUNING_SEED})"


def _problem(name, block, specs, cost, params) -> TuningProblem:
    return TuningProblem(models.get(name), block, scenario(name), specs=specs, cost=cost, samples=params,
                         substeps=SUBSTEPS)


def _start_itae_and_energy(name, block, params) -> tuple[float, float]:
    """Mean ITAE and mean control energy Σ u² Ts of `block` over `params` rows, one simulation each."""
    problem = _problem(name, block, None, Cost("itae"), params)
    costs, _, u = (np.asarray(v) for v in problem.evaluate(problem.start()))
    return float(np.mean(costs)), float(block.sample_period * np.sum(u**2) / len(params))


def worst_step(name: str, block, params) -> dict:
    """Worst overshoot (fraction) and 2 % settling time (s) of `block` on the scenario over `params` rows."""
    plant, sc = models.get(name), scenario(name)
    k = plant.state_names.index(models.case(name).tracked)
    worst = {"overshoot": 0.0, "settling_time_s": 0.0}
    for p in params:
        run = models.simulate_closed_loop(plant, block, sc.reference, sc.duration, x0=sc.x0, params=p,
                                          input_disturbance=sc.input_disturbance, substeps=SUBSTEPS)
        m = metrics.step_metrics(run.t, run.x[:, k], initial=sc.x0[k], target=sc.reference)
        worst["overshoot"] = max(worst["overshoot"], m["overshoot_pct"] / 100)
        worst["settling_time_s"] = max(worst["settling_time_s"], m["settling_time_s"])
    return worst


def _measured_specs(name: str, block, params) -> tuple[Specs, dict]:
    """Specs the tuned design must meet: the hand design's own worst response on `params`."""
    worst = worst_step(name, block, params)
    settling = worst["settling_time_s"]
    specs = Specs(max_overshoot=max(worst["overshoot"], MIN_OVERSHOOT),
                  settling_time=settling if np.isfinite(settling) else None, max_spectral_abscissa=0.0)
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


def _with_margin(specs: Specs) -> Specs:
    """The specs tuning enforces on its few samples: tighter, so that fresh samples still meet `specs`."""
    return replace(specs, max_overshoot=MARGIN * specs.max_overshoot,
                   settling_time=None if specs.settling_time is None else MARGIN * specs.settling_time)


def tune_case(name: str, max_iter: int = 100, jit: bool = True, progress=None) -> dict:
    """Tune plant `name`'s hand design, validate on fresh samples; the record `tuned_gains.json` keeps."""
    started = time.perf_counter()
    block = hand_design(name)
    train, chosen = tuning_samples(name)
    specs, hand_measured = _measured_specs(name, block, train)
    itae, energy = _start_itae_and_energy(name, block, train)
    weight = ENERGY_SHARE / (1 - ENERGY_SHARE) * itae / energy if energy > 0 else 0.0
    cost = Cost("itae", energy_weight=weight)
    result = tune(models.get(name), block, scenario(name), specs=_with_margin(specs), cost=cost, samples=train,
                  bounds=gain_bounds(block), substeps=SUBSTEPS, max_iter=max_iter, jit=jit, progress=progress)
    record = {
        "plant": name, "start": START, "start_gains": _listed(block.gains), "gains": _listed(result.gains),
        "known": f"uncertain parameters +{100 * REL:g} % (models.perturbed)",
        "scenario": "the text's step with the case's input disturbance from t = 0",
        "cost": {"kind": "itae", "energy_weight": weight, "energy_share_at_start": ENERGY_SHARE},
        "tuning_margin": MARGIN, "gain_range": GAIN_RANGE,
        "specs": {"max_overshoot": specs.max_overshoot, "settling_time_s": specs.settling_time,
                  "settling_band": specs.settling_band, "max_spectral_abscissa": 0.0},
        "hand_measured": hand_measured,
        "tuning": {"samples": len(train), "chosen": chosen, "seed": TUNING_SEED, "rel": REL, "initial_cost": result.initial_cost,
                   "cost": result.cost, "improvement": result.improvement, "feasible": result.feasible,
                   "message": result.message, "iterations": result.iterations, "jit": jit,
                   "wall_time_s": time.perf_counter() - started},
    }
    return record | {"validation": validate(name, record)}


def validate(name: str, record: dict) -> dict:
    """Hand and tuned designs of `record` on `N_VALIDATION` fresh samples: costs, worst steps, violations."""
    block = hand_design(name)
    tuned = block.with_gains(**{k: np.asarray(v) for k, v in record["gains"].items()})
    spec = record["specs"]
    specs = Specs(max_overshoot=spec["max_overshoot"], settling_time=spec["settling_time_s"],
                  settling_band=spec["settling_band"])
    fresh = samples(name, N_VALIDATION, VALIDATION_SEED)
    check = _problem(name, block, specs, Cost("itae", energy_weight=record["cost"]["energy_weight"]), fresh)
    _, hand_costs, hand_violations = check.values(check.start())
    _, tuned_costs, tuned_violations = check.values(tuned.gain_vector()[check.free_index])
    return {"samples": N_VALIDATION, "seed": VALIDATION_SEED,
            "hand_mean": float(np.mean(hand_costs)), "tuned_mean": float(np.mean(tuned_costs)),
            "hand_worst": float(np.max(hand_costs)), "tuned_worst": float(np.max(tuned_costs)),
            "improvement_mean": float(1 - np.mean(tuned_costs) / np.mean(hand_costs)),
            "tuned_better_on": int(np.sum(tuned_costs < hand_costs)),
            "hand_step": worst_step(name, block, fresh), "tuned_step": worst_step(name, tuned, fresh),
            "tuned_violations": tuned_violations, "hand_violations": hand_violations}


def _listed(gains: dict) -> dict:
    return {k: np.asarray(v, dtype=float).tolist() for k, v in gains.items()}


def stored() -> dict:
    """The records in tuned_gains.json, by plant ({} when there is none)."""
    if not STORE.exists():
        return {}
    return json.loads(STORE.read_text())


def controllers(name: str, known: models.Plant | None = None) -> dict:
    """{"tuned": block}: the hand design built from `known` with the stored tuned gains.

    Raises ValueError when no gains are stored for `name`, or when the hand design
    built from `known` differs from the one the gains were tuned from (rerun
    ``python -m designs.tuning_cases NAME`` after changing a design).
    """
    record = stored().get(name)
    if record is None:
        raise ValueError(f"no tuned gains stored for {name!r}; run `python -m designs.tuning_cases {name}`")
    block = hand_design(name, known)
    for key, value in record["start_gains"].items():
        now = np.asarray(block.gains[key], dtype=float)
        if now.shape != np.shape(value) or not np.allclose(now, value, rtol=1e-9, atol=1e-12):
            raise ValueError(f"{name}: the stored tuned gains start from a different {START!r} design "
                             f"(gain {key} is now {now.tolist()}, was {value}); "
                             f"rerun `python -m designs.tuning_cases {name}`")
    return {LABEL: block.with_gains(**{k: np.asarray(v) for k, v in record["gains"].items()})}


def _report_every(n: int):
    def report(iteration, objective, seconds):
        if iteration % n == 0:
            print(f"    iteration {iteration:3d}: cost {objective:.6g} ({seconds:.0f} s)", flush=True)
    return report


def _write(name: str, record: dict) -> None:
    """Store `record` under `name`, keeping the other plants' records as they are on disk now."""
    files.write_json(STORE, stored() | {name: record})


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m designs.tuning_cases", description=__doc__.split("\n")[0])
    parser.add_argument("plants", nargs="*", default=list(PLANTS),
                        help="plants to tune (default all six)")
    parser.add_argument("--max-iter", type=int, default=100, help="IPOPT iterations (default 100)")
    parser.add_argument("--validate", action="store_true",
                        help="re-validate the stored gains on the fresh samples, without tuning")
    parser.add_argument("--no-jit", action="store_true", help="evaluate with CasADi's virtual machine")
    args = parser.parse_args(argv)
    unknown = [p for p in args.plants if p not in PLANTS]
    if unknown:
        parser.error(f"unknown plant {unknown}; valid: {', '.join(PLANTS)}")
    records = stored()
    for name in args.plants:
        if args.validate:
            if name not in records:
                parser.error(f"no tuned gains stored for {name!r} to validate")
            print(f"validating {name} ...", flush=True)
            record = records[name] | {"validation": validate(name, records[name])}
        else:
            print(f"tuning {name} ...", flush=True)
            record = tune_case(name, args.max_iter, not args.no_jit, progress=_report_every(10))
        records[name] = record
        _write(name, record)
        t, v = record["tuning"], record["validation"]
        print(f"  {t['message']}; {t['iterations']} iterations, {t['wall_time_s']:.1f} s; "
              f"cost {t['initial_cost']:.4g} -> {t['cost']:.4g} ({100 * t['improvement']:.1f} % better); "
              f"fresh samples: mean {v['hand_mean']:.4g} -> {v['tuned_mean']:.4g} "
              f"({100 * v['improvement_mean']:.1f} %), better on {v['tuned_better_on']}/{v['samples']}, "
              f"violations {v['tuned_violations'] or 'none'}; worst overshoot "
              f"{100 * v['hand_step']['overshoot']:.2f} -> {100 * v['tuned_step']['overshoot']:.2f} %, "
              f"worst settling {v['hand_step']['settling_time_s']:.3g} -> {v['tuned_step']['settling_time_s']:.3g} s",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
