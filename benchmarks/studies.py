"""Study-scale benchmarks, each against a baseline in the same process.

Measurements (one function each, registered in `MEASUREMENTS`; ``--only`` picks some):

- ``mc``: Monte Carlo throughput of `models.monte_carlo`. The pendulum on a cart
  under its pole-placement block (II.15(c), designed on the +5 % known model,
  Ts = 0.01 s), 1,000 samples of the ±5 % parameter box, 20 s each after the
  text's 2 m step, 2 RK4 sub-steps per sample (the studies' setting), 2
  threads, JIT-compiled: the studies' Monte Carlo scenario. Timed from the
  call to having read every sample's outputs, states and commands. Baseline:
  python-control's `control.input_output_response` on the same loop (the same
  RK4 step as a discrete-time plant, the same block as a static controller,
  interconnected) on the first few samples; its trajectories are compared
  with ours.

Room is left for the measurements of `python -m studies` (wall time and peak
memory of ``--quick`` and of the default run) and of a Dask Monte Carlo on 1
versus 2 workers: add a function of the parsed arguments returning a dict of
figures, and register it in `MEASUREMENTS`.

Usage: python benchmarks/studies.py [--json PATH] [--only mc] [--samples 1000] [--repeat 3]
       [--baseline-samples 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

# Run as a script, this file's folder is sys.path[0] and "import studies" would find this
# file instead of the package; drop the folder so the package is imported.
_HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:] = [entry for entry in sys.path if os.path.abspath(entry or os.curdir) != _HERE]

import control  # noqa: E402
import numpy as np  # noqa: E402

import models  # noqa: E402
import studies  # noqa: E402
from designs.statespace_blocks import StateFeedback  # noqa: E402
from models.files import write_json  # noqa: E402
from studies import providers  # noqa: E402

PLANT, SAMPLE_PERIOD, DURATION, SUBSTEPS, THREADS, REL = "pendulum", 0.01, 20.0, 2, 2, 0.05


def pole_placement(known: models.Plant) -> StateFeedback:
    """The pendulum case's II.15(c) pole-placement block, designed from `known`."""
    return providers.statespace(PLANT, known)["pole placement"]


def python_control_loop(plant: models.Plant, block: StateFeedback) -> control.InterconnectedSystem:
    """The same closed loop in python-control: RK4 plant and saturated block, discrete at Ts."""
    step = plant.step_function(SAMPLE_PERIOD, SUBSTEPS)
    limit = float(plant.input_limit[0])
    states = list(plant.state_names)
    truth = control.nlsys(lambda t, x, u, params: np.asarray(step(x, u, params["p"])).ravel(),
                          lambda t, x, u, params: x, inputs=["F"], outputs=states, states=len(states),
                          dt=SAMPLE_PERIOD, name="plant", params={"p": plant.param_vector()})
    controller = control.nlsys(None, lambda t, x, u, params: np.clip(block.step(np.zeros(0), u[:-1], u[-1:])[1],
                                                                      -limit, limit),
                               inputs=[*states, "r"], outputs=["F"], dt=SAMPLE_PERIOD, name="controller")
    return control.interconnect([truth, controller], inplist=["r"], outlist=[*states, "F"])


def _consume(batch: models.MonteCarloResult) -> float:
    """Read every sample's outputs, states and commands, as a user of the results would."""
    return float(sum(run.y[-1, 0] + run.x[-1, 0] + run.u[-1, 0] for run in batch))


def _timed_monte_carlo(plant, block, reference, samples, jit: bool) -> tuple[float, models.MonteCarloResult]:
    start = time.perf_counter()
    batch = models.monte_carlo(plant, block, reference, DURATION, samples, substeps=SUBSTEPS, threads=THREADS,
                               jit=jit)
    _consume(batch)
    return time.perf_counter() - start, batch


def monte_carlo_throughput(samples: int = 1000, repeat: int = 3, baseline_samples: int = 3) -> dict:
    """Samples per second of `models.monte_carlo` and of python-control on the studies' Monte Carlo."""
    plant = models.get(PLANT)
    case = studies.get(PLANT)
    known = case.known_plant(plant)
    block = pole_placement(known)
    reference = models.signals.step(case.step, 0.0, plant.equilibrium()[0][0])
    params = models.sample_params(plant, samples, rel=REL, seed=0)

    start = time.perf_counter()
    models.monte_carlo(plant, block, reference, DURATION, params[:2], substeps=SUBSTEPS, jit=True)
    compile_s = time.perf_counter() - start
    first_s, batch = _timed_monte_carlo(plant, block, reference, params, jit=True)
    times = [_timed_monte_carlo(plant, block, reference, params, jit=True)[0] for _ in range(repeat)]
    vm_s, _ = _timed_monte_carlo(plant, block, reference, params, jit=False)

    loop = python_control_loop(plant, block)
    t = SAMPLE_PERIOD * np.arange(int(round(DURATION / SAMPLE_PERIOD)) + 1)
    diff, baseline_s = 0.0, 0.0
    for i in range(baseline_samples):
        start = time.perf_counter()
        response = control.input_output_response(loop, t, reference(t), X0=batch.x[i, 0],
                                                 params={"p": params[i]})
        baseline_s += time.perf_counter() - start
        diff = max(diff, float(np.max(np.abs(response.states.T - batch.x[i]))),
                   float(np.max(np.abs(response.outputs[-1, :-1] - batch.u[i, :, 0]))))
    per_s = samples / statistics.median(times)
    baseline_per_s = baseline_samples / baseline_s
    return {
        "mc_samples_per_s": per_s,
        "mc_first_call_samples_per_s": samples / first_s,
        "mc_vm_samples_per_s": samples / vm_s,
        "mc_compile_s": compile_s,
        "python_control_samples_per_s": baseline_per_s,
        "mc_ratio_vs_python_control": per_s / baseline_per_s,
        "mc_max_diff_vs_python_control": diff,
        "mc_diverged_samples": int(np.sum(~np.isnan(batch.diverged_at))),
        "mc_samples": samples, "mc_baseline_samples": baseline_samples, "mc_substeps": SUBSTEPS,
        "mc_threads": THREADS, "mc_duration_s": DURATION,
    }


def _measure_mc(args) -> dict:
    return monte_carlo_throughput(args.samples, args.repeat, args.baseline_samples)


#: name -> function(parsed arguments) -> {figure: value}
MEASUREMENTS = {"mc": _measure_mc}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", metavar="PATH", help="write every figure as one JSON object")
    parser.add_argument("--only", nargs="*", choices=list(MEASUREMENTS), default=list(MEASUREMENTS))
    parser.add_argument("--samples", type=int, default=1000, help="Monte Carlo samples (mc)")
    parser.add_argument("--repeat", type=int, default=3, help="timed repeats of the Monte Carlo (mc)")
    parser.add_argument("--baseline-samples", type=int, default=3, help="python-control samples (mc)")
    args = parser.parse_args(argv)
    for name in ("samples", "repeat", "baseline_samples"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1")
    if args.baseline_samples > args.samples:
        parser.error("--baseline-samples must not exceed --samples")
    # The machine is shared: the load before the run says how much the timings can be trusted.
    results = {"load_average_1min": os.getloadavg()[0], "cpus": os.cpu_count()}
    for name in args.only:
        results |= MEASUREMENTS[name](args)
    width = max(len(k) for k in results)
    for key, value in results.items():
        print(f"{key:{width}s}  {value:.4g}" if isinstance(value, float) else f"{key:{width}s}  {value}")
    if args.json:
        write_json(args.json, results)
    return results


if __name__ == "__main__":
    main()
