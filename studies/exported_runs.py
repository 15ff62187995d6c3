"""The Monte Carlo of an MPC row run by its exported C (`models.exported_loop`).

An MPC steps in Python (`models.simulate_closed_loop_many`); its C export
(`mpc.exporting.export_controller`) gives the same commands to 1e-9 without
Python in the step. Where the options allow compiled code (``Options.jit``:
True, or "auto" with a C compiler found) and the controller has an export, a
Monte Carlo row runs the samples through the C closed loop; its step times
are then the C step's. A controller the export refuses, or a library that
cannot be built, runs in Python, and the run's notes say why.
"""

from __future__ import annotations

import shutil

import numpy as np

import models
from models import Block
from models.compile import CompilationError
from models.export import UnsupportedExport, c_identifiers
from models.exported_loop import ExportedLoop, compile_loop
from models.run_setup import RunSetup
from mpc.exporting import export_controller


def wanted(jit, controller) -> bool:
    """Whether `controller`'s Monte Carlo should try its C: an MPC (a lockstep controller, not a Block)
    with compiled code allowed (`jit` True, or "auto" where a C compiler is found)."""
    if isinstance(controller, Block) or not getattr(controller, "lockstep", False):
        return False
    if jit == "auto":
        return (shutil.which("cc") or shutil.which("gcc")) is not None
    return bool(jit)


def exported_loop(
    label: str, controller, truth: models.Plant, reference, duration: float, substeps: int, notes: list
) -> ExportedLoop | None:
    """The compiled C closed loop of `controller` on `truth` for runs of `reference` (its values are the
    references the export prepares), or None with a note in `notes` saying why it runs in Python."""
    setup = RunSetup.build(truth, controller, reference, duration, substeps=substeps)
    try:
        exported = export_controller(controller, c_identifiers([f"mc {label}"])[0], np.unique(setup.r))
        return compile_loop(truth, exported, substeps)
    except (UnsupportedExport, CompilationError) as err:
        notes.append(f"{label}: Monte Carlo stepped in Python, not its C ({err})")
        return None
