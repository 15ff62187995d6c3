"""An MPC row's runs by its exported C (`models.exported_loop`).

An MPC steps in Python (`models.simulate_closed_loop`, and the lockstep
`models.simulate_closed_loop_many` for a Monte Carlo); its C export
(`mpc.exporting.export_controller`) gives the same commands to 1e-9 without
Python in the step. Where the options allow compiled code (``Options.jit``:
True, or "auto" with a C compiler found) and the controller has an export,
every run of its rows (each scenario and the Monte Carlo's samples) goes
through the one C closed loop compiled for it, and the rows' step times are
the C step's. A controller the export refuses, or a library that cannot be
built, runs in Python, and the run's notes say why.
"""

from __future__ import annotations

import numpy as np

import models
from models import Block
from models.compile import CompilationError, compiler
from models.export import UnsupportedExport, c_identifiers
from models.exported_loop import ExportedLoop, compile_loop
from models.run_setup import RunSetup
from mpc.exporting import export_controller


def wanted(jit, controller) -> bool:
    """Whether `controller`'s Monte Carlo should try its C: an MPC (a lockstep controller, not a Block)
    with compiled code allowed (`jit` True, or "auto" where `models.compile.compiler` finds a C compiler)."""
    if isinstance(controller, Block) or not getattr(controller, "lockstep", False):
        return False
    if jit == "auto":
        return compiler() is not None
    return bool(jit)


def exported_loop(label: str, controller, truth: models.Plant, runs, substeps: int, notes: list) -> ExportedLoop | None:
    """The compiled C closed loop of `controller` on `truth`, or None with a note in `notes` saying why it
    runs in Python.

    runs : (reference, duration) of every run it will make; the values their references take are the
        references the export prepares (a nonlinear MPC's targets)
    """
    values = [RunSetup.build(truth, controller, r, d, substeps=substeps).r for r, d in runs]
    try:
        exported = export_controller(controller, c_identifiers([f"mc {label}"])[0], np.unique(np.concatenate(values)))
        return compile_loop(truth, exported, substeps)
    except (UnsupportedExport, CompilationError) as err:
        notes.append(f"{label}: stepped in Python, not its C ({err})")
        return None
