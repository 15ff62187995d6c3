"""Sphinx configuration of the documentation site: the docs/ pages (MyST Markdown), the notebooks
(jupytext percent files, executed once at build time by myst-nb) and the API reference (autodoc, numpydoc).

Build: ``sphinx-build -W -b html docs <out>`` (`.ci/run` does, outside the source tree)."""

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")

project = "codesign-control"
extensions = ["myst_nb", "sphinx.ext.autodoc", "numpydoc"]
exclude_patterns = [
    "conf.py",
    "_build",
    "notes",
    "codesign/*.json",
    "**.ipynb_checkpoints",
    "notebooks/README*",
    "overview_picture.py",
]
nb_custom_formats = {".py": ["jupytext.reads", {"fmt": "py:percent"}]}
nb_execution_mode = "force"
nb_execution_timeout = 120
nb_execution_raise_on_error = True
myst_heading_anchors = 3
numpydoc_show_class_members = False
numpydoc_validation_checks: set = set()
autodoc_member_order = "bysource"
suppress_warnings = ["myst.header", "myst.xref_missing"]
html_theme = "alabaster"
