"""The designer inside a Jupyter notebook: ``from studies.designer import notebook; notebook.show("arm", "PD")``."""

from __future__ import annotations

import bokeh.io

from .. import cases
from . import app, catalog


def show(plant: str = "arm", controller: str | None = None, *, display: bool = True):
    """The designer's page inside a Jupyter notebook: Bokeh's notebook output of the same `app.Page` that
    ``python -m studies.designer`` serves.

    Parameters
    ----------
    plant : str
        The case study's name (`studies.cases.names`), default "arm".
    controller : str or None
        The controller's label (one of `catalog`'s labels), default the case's first controller with gains.
    display : bool
        Whether to call ``bokeh.io.output_notebook`` and ``bokeh.io.show`` on the application (needs a
        running notebook kernel); False only builds it.

    Returns
    -------
    bokeh.application.Application
        The application whose every session is a page of `plant`'s `controller`.
    """
    labels, _ = catalog(plant)
    label = controller or labels[0]
    if label not in labels:
        raise ValueError(f"{plant} has no controller {label!r} with gains; choose from {', '.join(labels)}")
    application = app.application(catalog, list(cases.names()), plant, label)
    if display:
        bokeh.io.output_notebook(hide_banner=True)
        bokeh.io.show(application)
    return application
