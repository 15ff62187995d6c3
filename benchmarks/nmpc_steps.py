"""Nonlinear MPC CPU time per step on every plant, this tree's real-time iteration against another revision's.

Each plant's case NMPC (`studies.get(name).mpc` on the case's known plant) runs the
case's reference step with its input disturbance for ``--steps`` samples. Two
controllers are built: one with this tree's `mpc.rti` and one with the
real-time iteration of ``--against`` (a git revision, default HEAD): its
`mpc/rti.py` and the modules that build it (`RTI_MODULES`, those the revision
has), loaded from ``git show`` as the package ``mpc_baseline``, whose other
modules are this tree's. The closed loop is driven by this tree's controller; at every
sample the baseline steps on the same controller state, measurement and
reference (from its own warm start: the same problems, to rounding), each step
timed with ``time.process_time()`` and the order of the two alternating, so
both see the same machine load. Printed per plant: median and mean CPU ms per
step of both and their ratio, the preparation and feedback medians (wall
clock, as `step_info` reports them), the largest feedback time, and the
largest difference between the two first moves (relative to the input limit).

Run: ``PYTHONPATH=$PWD python benchmarks/nmpc_steps.py [--steps 300] [--against REV] [--no-soft] [plant ...]``
"""

from __future__ import annotations

import argparse
import importlib
import json
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

import _path  # noqa: F401  (drops this folder from sys.path)
import numpy as np

import models
import mpc
import mpc.nonlinear
import studies

ROOT = Path(__file__).resolve().parent.parent
PLANTS = ("crane", "pendulum", "satellite", "ballbeam", "arm", "uuv")


#: The modules of the real-time iteration a baseline revision's copy is taken of (when it has them).
RTI_MODULES = ("rti", "rti_linearization", "condensed_qp", "rti_feedback", "slack_first", "condensing")


def baseline_rti(revision: str):
    """The `RealTimeIteration` class of `revision`: its RTI_MODULES imported as the package
    ``mpc_baseline``, in which every other module of mpc is this tree's (the same objects)."""
    listed = subprocess.run(
        ["git", "ls-tree", "--name-only", revision, "mpc/"], cwd=ROOT, check=True, capture_output=True, text=True
    ).stdout.split()
    present = [name for name in RTI_MODULES if f"mpc/{name}.py" in listed]
    folder = Path(tempfile.mkdtemp(prefix="rti_baseline_"))
    for name in present:
        source = subprocess.run(
            ["git", "show", f"{revision}:mpc/{name}.py"], cwd=ROOT, check=True, capture_output=True, text=True
        ).stdout
        (folder / f"{name}.py").write_text(source)
    package = types.ModuleType("mpc_baseline")
    package.__path__ = [str(folder)]
    sys.modules["mpc_baseline"] = package
    for name, module in list(sys.modules.items()):
        if name.startswith("mpc.") and name.split(".")[1] not in present:
            sys.modules["mpc_baseline." + name.split(".", 1)[1]] = module
    return importlib.import_module("mpc_baseline.rti").RealTimeIteration


def controllers(name: str, baseline_class, overrides: dict):
    """(plant, case, this tree's NMPC, the baseline's NMPC) of the case `name`, settings `overrides`."""
    plant, case = models.get(name), studies.get(name)
    known = case.known_plant(plant)
    current = mpc.nonlinear_mpc(known, case.mpc, tracked=case.tracked, **overrides)
    original = mpc.nonlinear.RealTimeIteration
    mpc.nonlinear.RealTimeIteration = baseline_class
    try:
        baseline = mpc.nonlinear_mpc(known, case.mpc, tracked=case.tracked, **overrides)
    finally:
        mpc.nonlinear.RealTimeIteration = original
    return plant, case, current, baseline


def compare(name: str, steps: int, baseline_class, overrides: dict) -> dict:
    plant, case, current, baseline = controllers(name, baseline_class, overrides)
    cpu: dict[str, list[float]] = {"current": [], "baseline": []}
    info: dict[str, list[dict]] = {"current": [], "baseline": []}
    first_moves = []

    class Both:
        sample_period, measures, n_reference = current.sample_period, current.measures, current.n_reference

        def initial_state(self, y0, r0):
            baseline.initial_state(y0, r0)
            return current.initial_state(y0, r0)

        def step(self, xc, y, r):
            order = ("current", "baseline") if len(cpu["current"]) % 2 == 0 else ("baseline", "current")
            out = {}
            for which in order:
                controller = current if which == "current" else baseline
                started = time.process_time()
                out[which] = controller.step(xc.copy(), y, r)
                cpu[which].append(time.process_time() - started)
                info[which].append(controller.step_info())
            first_moves.append(np.max(np.abs(out["current"][1] - out["baseline"][1])))
            return out["current"]

    xe = plant.equilibrium()[0]
    reference = xe[plant.state_names.index(case.tracked)] + case.step
    duration = steps * current.sample_period
    models.simulate_closed_loop(plant, Both(), reference, duration, input_disturbance=case.input_disturbance)
    row: dict = {"plant": name, "steps": len(cpu["current"]), "horizon": current.horizon}
    for which in cpu:
        times = 1e3 * np.array(cpu[which][1:])  # the first step solves the SQP from scratch
        fb = 1e3 * np.array([s["feedback_time"] for s in info[which][1:]])
        prep = 1e3 * np.array([s["preparation_time"] for s in info[which][1:]])
        row[f"{which}_cpu_median_ms"] = float(np.median(times))
        row[f"{which}_cpu_mean_ms"] = float(np.mean(times))
        row[f"{which}_preparation_median_ms"] = float(np.median(prep))
        row[f"{which}_feedback_median_ms"] = float(np.median(fb))
        row[f"{which}_feedback_max_ms"] = float(np.max(fb))
        row[f"{which}_failures"] = int(sum(not s["success"] for s in info[which]))
    row["ratio_mean_baseline_over_current"] = row["baseline_cpu_mean_ms"] / row["current_cpu_mean_ms"]
    row["max_first_move_diff_over_limit"] = float(np.max(first_moves) / np.min(plant.input_limit))
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("plants", nargs="*", default=list(PLANTS))
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--against", default="HEAD", help="git revision whose real-time iteration is the baseline")
    parser.add_argument("--no-soft", action="store_true", help="without the cases' soft bounds (input bounds only)")
    parser.add_argument("--json", metavar="PATH", help="write the rows as JSON")
    args = parser.parse_args(argv)
    baseline_class = baseline_rti(args.against)
    overrides = {"soft_bounds": ()} if args.no_soft else {}
    print(
        f"NMPC CPU ms per step (process time), this tree against {args.against}, {args.steps} steps, interleaved"
        f"{', without soft bounds' if args.no_soft else ''}"
    )
    print(
        f"{'plant':10s} {'N':>3s} {'base med':>9s} {'base mean':>10s} {'now med':>8s} {'now mean':>9s} "
        f"{'mean x':>7s} {'prep b/n':>13s} {'fb b/n':>13s} {'fb max b/n':>14s} {'|du0|/lim':>10s} {'fails':>6s}"
    )
    rows = []
    for name in args.plants:
        r = compare(name, args.steps, baseline_class, overrides)
        rows.append(r)
        print(
            f"{name:10s} {r['horizon']:3d} {r['baseline_cpu_median_ms']:9.3f} {r['baseline_cpu_mean_ms']:10.3f} "
            f"{r['current_cpu_median_ms']:8.3f} {r['current_cpu_mean_ms']:9.3f} "
            f"{r['ratio_mean_baseline_over_current']:7.2f} "
            f"{r['baseline_preparation_median_ms']:6.2f}/{r['current_preparation_median_ms']:<6.2f} "
            f"{r['baseline_feedback_median_ms']:6.2f}/{r['current_feedback_median_ms']:<6.2f} "
            f"{r['baseline_feedback_max_ms']:7.1f}/{r['current_feedback_max_ms']:<6.1f} "
            f"{r['max_first_move_diff_over_limit']:10.1e} "
            f"{r['baseline_failures']:2d}/{r['current_failures']:<3d}",
            flush=True,
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
