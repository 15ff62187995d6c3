"""Server-side latency of the control designer: one gain change, from the value to everything the page draws.

For the arm, the UUV and the pendulum (the case's PD, or PID for the UUV), in
one process: `studies.designer.Designer.update` is called directly `--repeat`
times (default 100), each time with the first gain at another value within its
range, on the step scenario: the nonlinear run, the verdict, the loop gain
about the end of the run, its Bode data, margins, loopshaping spec checks and
root locus. The first call (which builds and caches the compiled closed loop)
is reported apart. The baseline is the same loop's margins computed by
python-control's `stability_margins` on its state space, which alone exceeds
the update's budget; the ratio is baseline / `studies.loops.LoopGain.margins`
(`designs.analysis.margins`, what the update uses).

The page's own round trip (WebSocket, BokehJS drawing) is not counted here;
the browser test checks the page updates.

Usage: python benchmarks/designer.py [--repeat 100] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
import warnings

# Run as a script, this file's folder is sys.path[0] and "import studies" would find benchmarks/studies.py
# instead of the package; drop the folder so the package is imported.
_HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:] = [entry for entry in sys.path if os.path.abspath(entry or os.curdir) != _HERE]
# As `python -m studies.designer` does, before numpy is imported: one OpenBLAS thread.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import control  # noqa: E402
import numpy as np  # noqa: E402

from studies import designer  # noqa: E402

CASES = (("arm", "PD"), ("uuv", "PID"), ("pendulum", "PD"))


def timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def bench(name: str, label: str, repeat: int) -> dict:
    session = designer.Designer.for_case(name, label)
    first = session.controls[0]
    values = np.geomspace(first.design / 2, first.design * 2, repeat)
    first_call = timed(lambda: session.update({first.key: float(values[0])}))
    times = [session.update({first.key: float(v)}).seconds for v in values]
    block = session.block_for()
    run = session.simulate(block, "step")
    loop = session.loop_gain(block, run)
    fast = [timed(loop.margins) for _ in range(20)]
    system = loop.system()
    with warnings.catch_warnings():  # python-control announces its fallback to frequency-response data
        warnings.simplefilter("ignore", UserWarning)
        slow = [timed(lambda: control.stability_margins(system)) for _ in range(5)]
    return {
        "plant": name,
        "controller": label,
        "updates": repeat,
        "first_update_ms": 1e3 * first_call,
        "median_ms": 1e3 * statistics.median(times),
        "p90_ms": 1e3 * float(np.quantile(times, 0.9)),
        "margins_ms": 1e3 * statistics.median(fast),
        "python_control_margins_ms": 1e3 * statistics.median(slow),
        "margins_ratio": statistics.median(slow) / statistics.median(fast),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=100, help="updates per plant (default 100)")
    parser.add_argument("--json", metavar="PATH", help="write the figures as one JSON object")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error(f"--repeat must be >= 1, got {args.repeat}")
    rows = [bench(name, label, args.repeat) for name, label in CASES]
    print(
        f"{'plant':10s} {'controller':10s} {'median ms':>10s} {'p90 ms':>8s} {'first ms':>9s} "
        f"{'margins ms':>11s} {'python-control ms':>18s} {'ratio':>7s}"
    )
    for r in rows:
        print(
            f"{r['plant']:10s} {r['controller']:10s} {r['median_ms']:10.1f} {r['p90_ms']:8.1f} "
            f"{r['first_update_ms']:9.0f} {r['margins_ms']:11.2f} {r['python_control_margins_ms']:18.1f} "
            f"{r['margins_ratio']:6.0f}x"
        )
    figures = {
        "repeat": args.repeat,
        "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "load_average": os.getloadavg(),
        "cases": rows,
    }
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(figures, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
