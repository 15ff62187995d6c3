"""python -m studies: for every plant, the equilibrium, linearization and transfer functions."""

from __future__ import annotations

import argparse
import sys

import numpy as np

import models
from models.linear import tf_string


def describe(name: str) -> str:
    plant = models.get(name)
    xe, ue = plant.equilibrium()
    lin = plant.linearize(xe, ue)
    lines = [f"## {plant.title}", "",
             f"parameters: " + ", ".join(f"{p.name} = {plant.params[p.name]:g} {p.unit}" for p in plant.param_info),
             f"actuator limit: |{plant.input_names[0]}| <= {plant.input_limit[0]:g}",
             f".5 equilibrium: x_e = {np.array2string(xe, precision=4)}, u_e = {np.array2string(ue, precision=4)}",
             ".7 state space (x = " + ", ".join(plant.state_names) + "):",
             "A =\n" + np.array2string(lin.A, precision=4, suppress_small=True),
             "B =\n" + np.array2string(lin.B, precision=6, suppress_small=True),
             "C =\n" + np.array2string(lin.C, precision=4, suppress_small=True),
             ".6 transfer functions:"]
    for out in plant.output_names:
        lines.append(f"{out}/{plant.input_names[0]} = {tf_string(lin.tf(out, plant.input_names[0]))}")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies", description=__doc__)
    parser.add_argument("plants", nargs="*", help=f"plants to describe (default: all of {', '.join(models.names())})")
    args = parser.parse_args(argv)
    unknown = [p for p in args.plants if p not in models.names()]
    if unknown:
        parser.error(f"unknown plant {unknown[0]!r}; valid plants: {', '.join(models.names())}")
    for name in args.plants or models.names():
        print(describe(name))
    return 0


if __name__ == "__main__":
    sys.exit(main())
