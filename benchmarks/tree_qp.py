"""The studies' scenario-tree NMPC step in C: its QP's transformation branch by branch against DAQP's own.

    python benchmarks/tree_qp.py [--json PATH] [--steps 500] [--repeat 5] [plant ...]   (default: pendulum crane)

Per plant, the "scenario-tree NMPC" row of the studies (`studies.robust_rows.scenario_tree` on the
case's known plant, two opposite corners of the ±5 % box, robust horizon 1) is exported
(`mpc.export_nmpc`) and one closed loop on the true plant (the case's step, input disturbance and
1e-4 measurement noise, ``--steps`` samples) is replayed by two C programs built from the same
source (`mpc.export_nmpc_replay.build_replay`): one as exported, whose QP transformation (R, R⁻¹,
M = A R⁻¹) runs component by component of H, and one with ``-DDAQP_DENSE_LDP``, DAQP's own
``update_ldp`` on the whole matrices. The two programs run in turn ``--repeat`` times each; the
step's CPU time (the thread's clock, pre-emption left out) is the median over all their steps, so
the ratio is measured under the same load. The largest difference of their commands is printed
beside it (0: the same doubles).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import numpy as np
from _path import HERE as _HERE  # noqa: F401  (before our packages: drops this folder from sys.path)

import models
import studies
from models import compile as mc
from mpc.export_nmpc import export_nonlinear_mpc
from mpc.export_nmpc_replay import build_replay, run_replay
from studies import robust_rows, runner


def measure(name: str, steps: int, repeat: int, folder: Path) -> dict:
    """Median CPU time per step (ms) of both builds on `name`'s tree, their ratio, the largest command difference."""
    plant, case = models.get(name), studies.get(name)
    reference = runner.tracked_equilibrium(plant, case)[1] + case.step
    tree = robust_rows.scenario_tree(case, case.known_plant(plant))[robust_rows.LABEL]
    exported = export_nonlinear_mpc(tree, f"tree_qp_{name}", [reference])
    run = models.simulate_closed_loop(
        plant,
        exported.load(),
        reference,
        steps * tree.sample_period,
        input_disturbance=case.input_disturbance,
        noise_std=1e-4,
        seed=3,
    )
    builds = {"branchwise": [], "dense": ["-DDAQP_DENSE_LDP"]}
    programs = {
        key: build_replay(exported, run.measured, run.r[:-1], folder / f"{name}_{key}", flags=[*mc.FLAGS, *extra])
        for key, extra in builds.items()
    }
    replays: dict = {key: [] for key in builds}
    for _ in range(repeat):
        for key, program in programs.items():
            replays[key].append(run_replay(program))
    median = {key: 1e3 * float(np.median([r.cpu_seconds for r in runs])) for key, runs in replays.items()}
    commands = {key: runs[0].commands for key, runs in replays.items()}
    return {
        "steps": len(run.u),
        "repeat": repeat,
        "branchwise_step_median_ms": median["branchwise"],
        "dense_step_median_ms": median["dense"],
        "speedup": median["dense"] / median["branchwise"],
        "max_command_diff": float(np.max(np.abs(commands["branchwise"] - commands["dense"]))),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("plants", nargs="*", default=["pendulum", "crane"])
    parser.add_argument("--steps", type=int, default=500, help="closed-loop samples per run")
    parser.add_argument("--repeat", type=int, default=5, help="runs of each program, in turn")
    parser.add_argument("--json", type=Path, help="write the results here")
    args = parser.parse_args(argv)
    for option in ("steps", "repeat"):
        if getattr(args, option) < 1:
            parser.error(f"--{option} must be at least 1, got {getattr(args, option)}")
    results: dict = {"load_average_before": os.getloadavg()}
    with tempfile.TemporaryDirectory() as folder:
        for name in args.plants:
            r = results[name] = measure(name, args.steps, args.repeat, Path(folder))
            print(
                f"{name:9s} {r['steps']} steps x {r['repeat']}: branchwise {r['branchwise_step_median_ms']:.3f} ms, "
                f"DAQP's update_ldp {r['dense_step_median_ms']:.3f} ms (median CPU per step), "
                f"speedup {r['speedup']:.2f}, "
                f"largest command difference {r['max_command_diff']:.1e}",
                flush=True,
            )
    results["load_average_after"] = os.getloadavg()
    print(f"load average before {results['load_average_before']}, after {results['load_average_after']}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
