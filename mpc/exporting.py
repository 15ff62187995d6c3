"""One entry to the C exports of the controllers the studies compare: `export_controller`."""

from __future__ import annotations

import numpy as np

from models.block import Block
from models.export import ExportedC, UnsupportedExport, export_block

from .controller import LinearMPC, NonlinearMPC
from .export import export_linear_mpc
from .export_nmpc import export_nonlinear_mpc
from .tube_mpc import TubeMPC


def export_controller(controller, name: str, references=()) -> ExportedC:
    """`controller` as C by its exporter: a `models.Block` (`models.export.export_block`), a linear or
    tube MPC (`mpc.export.export_linear_mpc`), a nonlinear MPC or scenario tree
    (`mpc.export_nmpc.export_nonlinear_mpc`, its targets computed for `references`, the absolute
    reference values the C will be given).

    Raises
    ------
    UnsupportedExport
        Naming the controller and what its exporter cannot write.
    """
    if isinstance(controller, Block):
        return export_block(controller, name)
    if isinstance(controller, NonlinearMPC):
        return export_nonlinear_mpc(controller, name, np.unique(np.asarray(references, dtype=float)))
    if isinstance(controller, (LinearMPC, TubeMPC)):
        return export_linear_mpc(controller, name)
    kind = type(controller).__name__
    raise UnsupportedExport(f"{getattr(controller, 'name', kind)}: no C export for a {kind}")
