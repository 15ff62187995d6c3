"""Study-scale benchmarks, each against a baseline in the same process.

Measurements (one function each, registered in `MEASUREMENTS`; ``--only`` picks some):

- ``mc``: Monte Carlo throughput of `models.monte_carlo`. The pendulum on a cart
  under its pole-placement block (II.15(c), designed on the +5 % known model,
  Ts = 0.01 s), 1,000 samples of the ±5 % parameter box, 20 s each after the
  text's 2 m step, 2 RK4 sub-steps per sample (the studies' setting), 2
  threads, JIT-compiled (the C kernel of `models.mc_kernel`, ``mc_engine``):
  the studies' Monte Carlo scenario. Beside it, in the same run, the best of
  the same Monte Carlo on the JIT-compiled CasADi map (``mc_casadi_map_*``,
  the engine where there is no kernel). Timed from the
  call to having read every sample's outputs, states and commands. Baseline:
  python-control's `control.input_output_response` on the same loop (the same
  RK4 step as a discrete-time plant, the same block as a static controller,
  interconnected) on the first few samples; its trajectories are compared
  with ours. Beside it the arithmetic bound ``mc_bound_samples_per_s``: the
  operations of one closed-loop sample period x steps, per sample, against the
  threads x one core's measured flop rate (``core_flop_rate_per_s``: independent
  fused multiply-add chains in C, built with models.compile's flags, with them
  and 512-bit vectors, and with the Monte Carlo kernel's, timed inside C, the
  fastest; ``core_flop_rate_method`` says how it was measured). The operations
  of a sample period (``mc_bound_step_operations``) are those the engine runs
  every step: the kernel's own count (``mc_kernel_step_operations``; what it
  runs once per block of samples, ``mc_kernel_block_operations``, is not
  counted), or the CasADi instructions of the closed loop
  (``mc_step_operations``) on the CasADi map.

- ``quick`` and ``full``: wall time and peak memory of ``python -m studies --quick``
  and of the default ``python -m studies``, each run as a user runs it (a child
  process writing into a temporary folder, removed after). Peak memory two ways:
  ``*_peak_mb``, the largest resident set of any one process of the run
  (``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``, children included, the
  measure of the 2 GB limit), and ``*_tree_peak_mb``, the largest sum of the
  resident sets of the run's processes at once (the command and its worker
  processes), sampled every 0.2 s from /proc. Also the processor time of the run (``*_cpu_s``,
  children included) and the table's wall_s summed per controller kind (Blocks, linear MPC,
  nonlinear MPC).
- ``dask``: the studies' Monte Carlo on Dask. Every Block controller of the
  pendulum study (designed on the +5 % known model), 2,000 samples of the ±5 %
  box, 20 s each, 2 RK4 sub-steps, CasADi's virtual machine (no JIT, so no
  compiler time in either run), through `studies.distributed.monte_carlo` on
  a LocalCluster of 1 and of 2 single-threaded worker processes, timed after
  the workers have imported the packages. Each controller's states and
  commands are hashed: the 1-worker, 2-worker and in-process (`models.monte_carlo`)
  runs must agree bit for bit. Figures: seconds on 1 and 2 workers, the
  speedup, and whether the numbers are identical.

Usage: python benchmarks/studies.py [--json PATH] [--only mc quick full dask] [--samples 1000] [--repeat 3]
       [--baseline-samples 3] [--dask-samples 2000]
       python benchmarks/studies.py --only quick full --json studies.json   (the run's time and memory)
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import _path  # noqa: F401  (before our packages: drops this folder from sys.path)
import casadi as ca
import control
import numpy as np

import models
import studies
from designs.statespace_blocks import StateFeedback
from models import mc_kernel
from models.closed_loop import closed_loop_function
from models.files import write_json
from models.monte_carlo_batch import MonteCarloPlan
from models.run_setup import RunSetup
from studies import providers

PLANT, SAMPLE_PERIOD, DURATION, SUBSTEPS, THREADS, REL = "pendulum", 0.01, 20.0, 2, 2, 0.05


def pole_placement(known: models.Plant) -> StateFeedback:
    """The pendulum case's II.15(c) pole-placement block, designed from `known`."""
    return providers.statespace(studies.get(PLANT), known)["pole placement"]


def python_control_loop(plant: models.Plant, block: StateFeedback) -> control.InterconnectedSystem:
    """The same closed loop in python-control: RK4 plant and saturated block, discrete at Ts."""
    step = plant.step_function(SAMPLE_PERIOD, SUBSTEPS)
    limit = float(plant.input_limit[0])
    states = list(plant.state_names)
    truth = control.nlsys(
        lambda t, x, u, params: np.asarray(step(x, u, params["p"])).ravel(),
        lambda t, x, u, params: x,
        inputs=["F"],
        outputs=states,
        states=len(states),
        dt=SAMPLE_PERIOD,
        name="plant",
        params={"p": plant.param_vector()},
    )
    controller = control.nlsys(
        None,
        lambda t, x, u, params: np.clip(block.step(np.zeros(0), u[:-1], u[-1:])[1], -limit, limit),
        inputs=[*states, "r"],
        outputs=["F"],
        dt=SAMPLE_PERIOD,
        name="controller",
    )
    return control.interconnect([truth, controller], inplist=["r"], outlist=[*states, "F"])


def _consume(batch: models.MonteCarloResult) -> float:
    """Read every sample's outputs, states and commands, as a user of the results would."""
    return float(sum(run.y[-1, 0] + run.x[-1, 0] + run.u[-1, 0] for run in batch))


def step_operations(plant, block) -> int:
    """Arithmetic operations of one closed-loop sample period (the measurement, the block's step and
    `SUBSTEPS` RK4 sub-steps), counted as the instructions of its expanded CasADi function other than
    inputs, outputs and constants (a sine counts as one): what the CasADi map runs every step."""
    fun = closed_loop_function(plant, block, 1, SUBSTEPS, False)
    fun = fun if fun.is_a("SXFunction") else fun.expand()
    skip = {ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST, ca.OP_PARAMETER}
    return sum(1 for k in range(fun.n_instructions()) if fun.instruction_id(k) not in skip)


#: Independent multiply-add chains of the flop-rate kernel: enough to fill the vector units' pipelines
#: (4 doubles per AVX2 register, two FMA units of latency 4 need 8 registers in flight).
FMA_CHAINS = 64

FMA_PROGRAM = r"""
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <time.h>
#define CHAINS %(chains)d
int main(void) {
    static double acc[CHAINS];
    const double a = 0.999999, b = 1e-6;
    struct timespec began, ended;
    double best = 1e300, seconds, sum = 0.0;
    long k, repeat = %(repeat)d;
    int j, trial;
    for (trial = 0; trial < %(trials)d; ++trial) {
        for (j = 0; j < CHAINS; ++j) acc[j] = 0.5 + 1e-3 * j;
        clock_gettime(CLOCK_MONOTONIC, &began);
        for (k = 0; k < repeat; ++k)
            for (j = 0; j < CHAINS; ++j) acc[j] = fma(acc[j], a, b);
        clock_gettime(CLOCK_MONOTONIC, &ended);
        seconds = (ended.tv_sec - began.tv_sec) + 1e-9 * (ended.tv_nsec - began.tv_nsec);
        if (seconds < best) best = seconds;
        for (j = 0; j < CHAINS; ++j) sum += acc[j];
    }
    printf("%%.17g %%.17g\n", 2.0 * CHAINS * (double) repeat / best, sum);
    return 0;
}
"""


def numpy_flop_rate(size: int = 2048, repeat: int = 2000) -> float:
    """Floating-point operations per second of NumPy's multiply-add on `size`-element arrays that stay
    in the first-level cache (two flops per element), the best of five timings: a floor of the core's
    rate (each NumPy call also pays its dispatch), used where no C compiler is found."""
    a, b, c = (np.random.default_rng(k).random(size) for k in range(3))
    out = np.empty(size)
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeat):
            np.multiply(a, b, out=out)
            np.add(out, c, out=out)
        best = min(best, time.perf_counter() - start)
    return 2.0 * size * repeat / best


#: The flags the flop-rate kernel is built with, each timed: the project's (gcc picks 256-bit vectors on
#: some AVX-512 machines), with 512-bit vectors where there are some, and the Monte Carlo kernel's.
FLOP_RATE_FLAGS = (
    models.compile.FLAGS,
    (*models.compile.FLAGS, "-mprefer-vector-width=512"),
    mc_kernel.KERNEL_FLAGS,
)


def core_flop_rate(repeat: int = 200_000, trials: int = 200) -> tuple[float, str]:
    """(flops per second of one core, how it was measured): `FMA_CHAINS` independent fused
    multiply-add chains in C, compiled with each of `FLOP_RATE_FLAGS`, the best of `trials` timings inside C
    (short bursts, about 0.5 ms each: on a shared machine the best is one no other job interrupted), the
    faster build; NumPy's multiply-add (`numpy_flop_rate`) where no compiler is found."""
    compiler = models.compile.compiler()
    if compiler is None:
        return numpy_flop_rate(), "numpy multiply-add (no C compiler)"
    rates = {}
    with tempfile.TemporaryDirectory(prefix="flop-rate-") as folder:
        source = Path(folder) / "fma.c"
        source.write_text(FMA_PROGRAM % {"chains": FMA_CHAINS, "repeat": repeat, "trials": trials})
        program = str(Path(folder) / "fma")
        for flags in FLOP_RATE_FLAGS:
            subprocess.run([*compiler, *flags, "-o", program, str(source), "-lm"], check=True)
            printed = subprocess.run([program], check=True, capture_output=True, text=True).stdout
            rates[" ".join(flags)] = float(printed.split()[0])
    flags = max(rates, key=rates.__getitem__)
    return rates[flags], f"C, {FMA_CHAINS} independent fma chains, best of {trials} bursts, {flags}"


def _timed_monte_carlo(plant, block, reference, samples, jit: bool) -> tuple[float, models.MonteCarloResult]:
    start = time.perf_counter()
    batch = models.monte_carlo(plant, block, reference, DURATION, samples, substeps=SUBSTEPS, threads=THREADS, jit=jit)
    _consume(batch)
    return time.perf_counter() - start, batch


def _timed_casadi_map(plant, block, reference, samples) -> float:
    """Seconds of the same Monte Carlo on the JIT-compiled CasADi map (the engine without the C kernel),
    its results read as `_consume` reads them."""
    setup = RunSetup.build(plant, block, reference, DURATION, substeps=SUBSTEPS)
    plan = MonteCarloPlan.build(plant, block, setup, samples, threads=THREADS, jit=True)
    plan = dataclasses.replace(plan, kernel=None, engine="CasADi map")
    plan = dataclasses.replace(plan, chunk=MonteCarloPlan.build(plant, block, setup, samples, threads=THREADS).chunk)
    start = time.perf_counter()
    out = plan.allocate(len(samples))
    for first, last in plan.chunks():
        plan.run_chunk(first, last, tuple(None if a is None else a[first:last] for a in out))
    _consume(plan.result(out, 0, len(samples)))
    return time.perf_counter() - start


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
    _timed_casadi_map(plant, block, reference, params[:2])  # compiled once, outside the timing
    casadi_map_s = min(_timed_casadi_map(plant, block, reference, params) for _ in range(repeat))
    best_kernel_s = min(times)

    loop = python_control_loop(plant, block)
    t = SAMPLE_PERIOD * np.arange(int(round(DURATION / SAMPLE_PERIOD)) + 1)
    diff, baseline_s = 0.0, 0.0
    for i in range(baseline_samples):
        start = time.perf_counter()
        response = control.input_output_response(loop, t, reference(t), X0=batch.x[i, 0], params={"p": params[i]})
        baseline_s += time.perf_counter() - start
        diff = max(
            diff,
            float(np.max(np.abs(response.states.T - batch.x[i]))),
            float(np.max(np.abs(response.outputs[-1, :-1] - batch.u[i, :, 0]))),
        )
    per_s = samples / statistics.median(times)
    setup = RunSetup.build(plant, block, reference, DURATION, substeps=SUBSTEPS)
    plan = MonteCarloPlan.build(plant, block, setup, params[:1], jit=True)
    operations = step_operations(plant, block)
    counted = operations if plan.kernel is None else plan.kernel.step_operations
    flop_rate, flop_method = core_flop_rate()
    steps = int(round(DURATION / SAMPLE_PERIOD))
    bound_per_s = THREADS * flop_rate / (counted * steps)
    baseline_per_s = baseline_samples / baseline_s
    return {
        "mc_samples_per_s": per_s,
        "mc_best_samples_per_s": samples / best_kernel_s,
        "mc_casadi_map_best_samples_per_s": samples / casadi_map_s,
        "mc_ratio_best_vs_casadi_map": casadi_map_s / best_kernel_s,
        "mc_engine": plan.engine,
        "mc_first_call_samples_per_s": samples / first_s,
        "mc_vm_samples_per_s": samples / vm_s,
        "mc_bound_samples_per_s": bound_per_s,
        "mc_ratio_bound_vs_measured": bound_per_s / per_s,
        "mc_step_operations": operations,
        "mc_kernel_step_operations": None if plan.kernel is None else plan.kernel.step_operations,
        "mc_kernel_block_operations": None if plan.kernel is None else plan.kernel.block_operations,
        "mc_bound_step_operations": counted,
        "core_flop_rate_per_s": flop_rate,
        "core_flop_rate_method": flop_method,
        "mc_compile_s": compile_s,
        "python_control_samples_per_s": baseline_per_s,
        "mc_ratio_vs_python_control": per_s / baseline_per_s,
        "mc_max_diff_vs_python_control": diff,
        "mc_diverged_samples": int(np.sum(~np.isnan(batch.diverged_at))),
        "mc_samples": samples,
        "mc_baseline_samples": baseline_samples,
        "mc_substeps": SUBSTEPS,
        "mc_threads": THREADS,
        "mc_duration_s": DURATION,
    }


def _digest(batch: models.MonteCarloResult) -> str:
    import hashlib

    return hashlib.sha256(
        np.ascontiguousarray(batch.x).tobytes()
        + np.ascontiguousarray(batch.u).tobytes()
        + np.nan_to_num(batch.diverged_at, nan=-1.0).tobytes()
    ).hexdigest()


def dask_monte_carlo(samples: int = 2000, workers=(1, 2)) -> dict:
    """Seconds of every pendulum Block's Monte Carlo on Dask LocalClusters of `workers` processes, and identity."""
    import studies
    from studies import distributed, runner

    case = studies.get(PLANT)
    plant = models.get(PLANT)
    designed, _ = runner.design_controllers(case, case.known_plant(plant))
    blocks = {label: c for label, c in designed.items() if isinstance(c, models.Block)}
    _, base = runner.tracked_equilibrium(plant, case)
    reference = case.scenarios[0].reference(case, base)
    params = models.sample_params(plant, samples, rel=REL, seed=0)
    kwargs = dict(substeps=case.substeps, jit=False)
    digests, seconds = {}, {}
    start = time.perf_counter()
    digests["in-process"] = [
        _digest(models.monte_carlo(plant, block, reference, DURATION, params, threads=THREADS, **kwargs))
        for block in blocks.values()
    ]
    seconds["in-process"] = time.perf_counter() - start
    for count in workers:
        with distributed.connect(workers=count) as executor:
            distributed.monte_carlo(
                executor,
                plant,
                next(iter(blocks.values())),
                reference,
                1.0,  # warm-up
                params[: 4 * count * distributed.MIN_SAMPLES_PER_TASK],
                **kwargs,
            )
            start = time.perf_counter()
            digests[count] = [
                _digest(distributed.monte_carlo(executor, plant, block, reference, DURATION, params, **kwargs))
                for block in blocks.values()
            ]
            seconds[count] = time.perf_counter() - start
    first, last = workers[0], workers[-1]
    return {
        "dask_mc_samples": samples,
        "dask_mc_controllers": len(blocks),
        "dask_mc_duration_s": DURATION,
        "dask_in_process_s": seconds["in-process"],
        "dask_in_process_threads": THREADS,
        **{f"dask_{count}_workers_s": seconds[count] for count in workers},
        f"dask_speedup_{last}_vs_{first}_workers": seconds[first] / seconds[last],
        "dask_samples_per_s": samples * len(blocks) / seconds[last],
        "dask_identical": all(digests[count] == digests["in-process"] for count in workers),
    }


def _measure_mc(args) -> dict:
    return monte_carlo_throughput(args.samples, args.repeat, args.baseline_samples)


def _tree_rss_bytes(root: int) -> int:
    """Resident memory of process `root` and all its descendants now, from /proc (0 once it ended)."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
                parents[int(entry.name)] = int(stat[stat.rindex(")") + 2 :].split()[1])
            except (OSError, ValueError):
                continue
    tree, grew = {root}, True
    while grew:
        found = {pid for pid, parent in parents.items() if parent in tree} - tree
        tree |= found
        grew = bool(found)
    total = 0
    for pid in tree:
        try:
            for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1]) * 1024
        except OSError:
            continue
    return total


#: Runs a command and prints its children's peak resident set (KiB): a fresh process per command, so
#: RUSAGE_CHILDREN covers that command's processes only.
_PEAK_OF_CHILDREN = (
    "import resource, subprocess, sys; code = subprocess.call(sys.argv[1:]); "
    "usage = resource.getrusage(resource.RUSAGE_CHILDREN); "
    "print(usage.ru_utime + usage.ru_stime, usage.ru_maxrss); sys.exit(code)"
)

#: The MPC rows of the table, each summed on its own; every other controller is a Block.
_MPC_KINDS = ("linear MPC", "nonlinear MPC")


def _wall_by_kind(results: Path) -> dict:
    """Seconds of the run's rows (timings.csv's wall_s, summed over plants) per controller kind, and of
    their Monte Carlo rows alone."""
    import pandas as pd

    tables = [pd.read_csv(path) for path in sorted(results.glob("*/timings.csv"))]
    if not tables:
        return {}
    table = pd.concat(tables, ignore_index=True)
    table = table[table["sample"].isna()]  # the rows' totals (per-sample lines have a sample number)
    kind = table["controller"].where(table["controller"].isin(_MPC_KINDS), "blocks").str.replace(" ", "_")
    out = {f"rows_{k}_s": float(v) for k, v in table["wall_s"].groupby(kind).sum().items()}
    mc = table["scenario"] == "mc"
    for name, seconds in table["wall_s"][mc].groupby(kind[mc]).sum().items():
        out[f"mc_rows_{name}_s"] = float(seconds)
    return out


def run_studies_command(*arguments: str) -> dict:
    """Wall time and peak memory of ``python -m studies ARGUMENTS --quiet --out <temporary>``.

    Returns
    -------
    dict: wall_s; cpu_s, the processor time of the command and its worker processes (user + system:
    on a shared machine the wall time grows with the load, this much less); peak_mb, the largest
    resident set of any one process of the command (ru_maxrss of RUSAGE_CHILDREN, children
    included); tree_peak_mb, the largest sum over its processes at once; rows_<kind>_s, the rows'
    wall_s (timings.csv) summed per kind (blocks, linear_MPC, nonlinear_MPC; their Monte Carlo rows
    also alone, mc_rows_<kind>_s)
    """
    repo = Path(__file__).resolve().parent.parent
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join(filter(None, [str(repo), os.environ.get("PYTHONPATH")])),
        MPLBACKEND="Agg",
    )
    workdir = Path(tempfile.mkdtemp(prefix="studies-benchmark-"))
    tree_peak = [0]
    try:
        start = time.perf_counter()
        process = subprocess.Popen(
            [
                sys.executable,
                "-c",
                _PEAK_OF_CHILDREN,
                sys.executable,
                "-m",
                "studies",
                *arguments,
                "--quiet",
                "--out",
                str(workdir / "results"),
            ],
            cwd=workdir,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        done = threading.Event()

        def sample():
            while not done.wait(0.2):
                tree_peak[0] = max(tree_peak[0], _tree_rss_bytes(process.pid))

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        out, err = process.communicate()
        wall = time.perf_counter() - start
        done.set()
        sampler.join()
        try:  # a secondary figure: never lose the run's time and memory over it
            rows = _wall_by_kind(workdir / "results") if process.returncode == 0 else {}
        except (OSError, ValueError, KeyError) as err:
            rows = {"rows_unavailable": f"{type(err).__name__}: {err}"}
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    if process.returncode != 0:
        raise RuntimeError(f"python -m studies {' '.join(arguments)} exited {process.returncode}: {err[-2000:]}")
    cpu, peak = out.split()[-2:]
    return {
        "wall_s": wall,
        "cpu_s": float(cpu),
        "peak_mb": int(peak) / 1024,
        "tree_peak_mb": tree_peak[0] / 2**20,
        **rows,
    }


def _measure_command(name: str, arguments: tuple) -> dict:
    figures = run_studies_command(*arguments)
    return {f"{name}_{key}": value for key, value in figures.items()}


def _measure_dask(args) -> dict:
    return dask_monte_carlo(args.dask_samples)


#: name -> function(parsed arguments) -> {figure: value}
MEASUREMENTS = {
    "mc": _measure_mc,
    "quick": lambda args: _measure_command("quick", ("--quick",)),
    "full": lambda args: _measure_command("full", ()),
    "dask": _measure_dask,
}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", metavar="PATH", help="write every figure as one JSON object")
    parser.add_argument(
        "--only",
        nargs="*",
        choices=list(MEASUREMENTS),
        default=["mc", "quick"],
        help="measurements to run (default mc and quick; full, the default run of python -m "
        "studies, takes minutes: ask for it)",
    )
    parser.add_argument("--samples", type=int, default=1000, help="Monte Carlo samples (mc)")
    parser.add_argument("--repeat", type=int, default=3, help="timed repeats of the Monte Carlo (mc)")
    parser.add_argument("--baseline-samples", type=int, default=3, help="python-control samples (mc)")
    parser.add_argument("--dask-samples", type=int, default=2000, help="Monte Carlo samples per controller (dask)")
    args = parser.parse_args(argv)
    for name in ("samples", "repeat", "baseline_samples", "dask_samples"):
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
    # Run as a script, this folder comes first on sys.path, and this file's name would hide the studies package.
    import sys

    if sys.path and os.path.realpath(sys.path[0]) == os.path.dirname(os.path.realpath(__file__)):
        sys.path.pop(0)
    main()
