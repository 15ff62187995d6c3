"""Every notebook in notebooks/ (jupytext percent files, kept without outputs) runs on a fresh kernel and
its assert cells, which compare the numbers against independent derivations, pass; each in at most 60 s."""

import os
import time
from pathlib import Path

import pytest

jupytext = pytest.importorskip("jupytext")
nbclient = pytest.importorskip("nbclient")

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.py"))
#: The longest (11-18 s each on a fresh kernel at load 3.4-4.8; the others 6-11 s): with the slow tests only.
SLOW = {"ballbeam", "codesign", "crane", "pendulum"}
#: The longest a notebook may take on a fresh kernel, s.
TIMEOUT = 60


def test_there_are_notebooks():
    assert NOTEBOOKS


@pytest.mark.parametrize(
    "path", [pytest.param(p, marks=pytest.mark.slow) if p.stem in SLOW else p for p in NOTEBOOKS], ids=lambda p: p.stem
)
def test_the_notebook_runs_on_a_fresh_kernel(path, tmp_path, monkeypatch):
    notebook = jupytext.read(path)
    assert all(not cell.get("outputs") for cell in notebook.cells if cell.cell_type == "code")
    # The kernel imports this tree's packages and writes nothing into it.
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    client = nbclient.NotebookClient(
        notebook, timeout=TIMEOUT, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    start = time.perf_counter()
    client.execute()
    assert time.perf_counter() - start <= TIMEOUT


def test_the_designer_builds_its_notebook_application():
    pytest.importorskip("bokeh")
    from bokeh.application import Application

    from studies.designer import notebook

    assert isinstance(notebook.show("arm", "PD", display=False), Application)
    with pytest.raises(ValueError, match="no controller"):
        notebook.show("arm", "no such controller", display=False)
