"""The studies' scenario-tree NMPC step in C: its QP's transformation branch by branch against DAQP's own.

    python benchmarks/tree_qp.py [--json PATH] [--seconds 5] [plant ...]   (default: pendulum crane)

Per plant, the "scenario-tree NMPC" row of the studies (`studies.robust_rows.scenario_tree` on the
case's known plant, two opposite corners of the ±5 % box, robust horizon 1) is exported
(`mpc.export_nmpc`) and one closed loop on the true plant (the case's step, input disturbance and
1e-4 measurement noise) is replayed by two C programs built from the same source
(`mpc.export_nmpc_replay.replay`): one as exported, whose QP transformation (R, R⁻¹, M = A R⁻¹)
runs component by component of H, and one with ``-DDAQP_DENSE_LDP``, DAQP's own ``update_ldp`` on
the whole matrices. The two replays run back to back in one process, so the ratio of their median
step times is measured under the same load; the largest difference of their commands is printed
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
from mpc.export_nmpc_replay import replay
from studies import robust_rows


def measure(name: str, seconds: float, folder: Path) -> dict:
    """Median step (ms) of both builds on `name`'s tree, their ratio, and the largest command difference."""
    plant, case = models.get(name), studies.get(name)
    reference = float(plant.equilibrium()[0][plant.state_names.index(case.tracked)] + case.step)
    tree = robust_rows.scenario_tree(case, case.known_plant(plant))[robust_rows.LABEL]
    exported = export_nonlinear_mpc(tree, f"tree_qp_{name}", [reference])
    run = models.simulate_closed_loop(
        plant, exported.load(), reference, seconds, input_disturbance=case.input_disturbance, noise_std=1e-4, seed=3
    )
    builds = {"branchwise": [], "dense": ["-DDAQP_DENSE_LDP"]}
    replays = {
        key: replay(exported, run.measured, run.r[:-1], folder / f"{name}_{key}", flags=[*mc.FLAGS, *extra])
        for key, extra in builds.items()
    }
    median = {key: 1e3 * float(np.median(r.step_seconds)) for key, r in replays.items()}
    return {
        "steps": len(run.u),
        "branchwise_step_median_ms": median["branchwise"],
        "dense_step_median_ms": median["dense"],
        "speedup": median["dense"] / median["branchwise"],
        "max_command_diff": float(np.max(np.abs(replays["branchwise"].commands - replays["dense"].commands))),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("plants", nargs="*", default=["pendulum", "crane"])
    parser.add_argument("--seconds", type=float, default=5.0, help="closed-loop run length (s)")
    parser.add_argument("--json", type=Path, help="write the results here")
    args = parser.parse_args(argv)
    results: dict = {"load_average_before": os.getloadavg()}
    with tempfile.TemporaryDirectory() as folder:
        for name in args.plants:
            r = results[name] = measure(name, args.seconds, Path(folder))
            print(
                f"{name:9s} {r['steps']} steps: branchwise {r['branchwise_step_median_ms']:.3f} ms, "
                f"DAQP's update_ldp {r['dense_step_median_ms']:.3f} ms (median), speedup {r['speedup']:.2f}, "
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
