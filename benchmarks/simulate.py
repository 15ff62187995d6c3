"""Open-loop simulation speed: compiled CasADi mapaccum versus a plain-Python RK4 loop.

Each plant runs 20 s at Ts = 0.01 s with 10 RK4 sub-steps (20 000 RK4 steps)
from its standard equilibrium under the equilibrium input plus a sine. In one
process, per plant:

- python: the textbook's style, a Python loop calling the same CasADi f per stage;
- vm: the whole run as one mapaccum in CasADi's virtual machine;
- compiled: the same mapaccum JIT-compiled (compile time reported apart).

Usage: python benchmarks/simulate.py [--repeat 20] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

import models
from models.simulate import simulate

SAMPLE_PERIOD, SUBSTEPS, DURATION = 0.01, 10, 20.0


def python_rk4(plant, x0, u, p):
    """Plain-Python RK4 over the plant's CasADi f, one call per stage."""
    f = lambda x, uk: np.asarray(plant.casadi_f(x, uk, p)).ravel()
    h = SAMPLE_PERIOD / SUBSTEPS
    xs = [x0]
    x = x0
    for uk in u:
        for _ in range(SUBSTEPS):
            k1 = f(x, uk)
            k2 = f(x + h / 2 * k1, uk)
            k3 = f(x + h / 2 * k2, uk)
            k4 = f(x + h * k3, uk)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xs.append(x)
    return np.array(xs)


def median_ms(fn, repeat):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def bench(name, repeat):
    plant = models.get(name)
    n = int(round(DURATION / SAMPLE_PERIOD))
    xe, ue = plant.equilibrium()
    t = SAMPLE_PERIOD * np.arange(n)
    # A small sine keeps the unstable plants near their equilibrium for 20 s.
    u = ue + 1e-3 * plant.input_limit * np.sin(t)[:, None]
    p = plant.param_vector()
    run = lambda jit: simulate(plant, xe, u, SAMPLE_PERIOD, substeps=SUBSTEPS, jit=jit)
    start = time.perf_counter()
    compiled = run(True)
    compile_s = time.perf_counter() - start
    vm = run(False)
    start = time.perf_counter()
    reference = python_rk4(plant, xe, u, p)
    python_ms = 1e3 * (time.perf_counter() - start)
    compiled_ms = median_ms(lambda: run(True), repeat)
    vm_ms = median_ms(lambda: run(False), max(3, repeat // 4))
    return {
        "compiled_ms": compiled_ms,
        "vm_ms": vm_ms,
        "python_ms": python_ms,
        "ratio": python_ms / compiled_ms,
        "ratio_vm": python_ms / vm_ms,
        "compile_s": compile_s,
        "max_state_diff": float(max(np.max(np.abs(compiled.x - reference)), np.max(np.abs(vm.x - reference)))),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20, help="timed repeats of the compiled run")
    parser.add_argument("--json", metavar="PATH", help="write {plant: {compiled_ms, python_ms, ratio, ...}}")
    parser.add_argument("--plants", nargs="*", default=models.names(), choices=models.names())
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    results = {}
    print(
        f"{'plant':10s} {'compiled ms':>12s} {'vm ms':>8s} {'python ms':>10s} {'ratio':>8s} "
        f"{'ratio vm':>9s} {'compile s':>10s} {'max |dx|':>9s}"
    )
    for name in args.plants:
        r = results[name] = bench(name, args.repeat)
        print(
            f"{name:10s} {r['compiled_ms']:12.2f} {r['vm_ms']:8.2f} {r['python_ms']:10.0f} {r['ratio']:8.0f} "
            f"{r['ratio_vm']:9.0f} {r['compile_s']:10.2f} {r['max_state_diff']:9.1e}"
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=2)
    return results


if __name__ == "__main__":
    main()
