"""docs/export.md's example runs as written: its Python exports the files, its C program compiles
against them and prints the commands the Python controllers give for the same measurements."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import models
from models import compile as mc
from mpc.export import daqp_include_directory, daqp_library
from studies import providers

REPO = Path(models.__file__).resolve().parent.parent
DOC = REPO / "docs" / "export.md"


def blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", DOC.read_text(), flags=re.S)


def test_the_documented_example_exports_compiles_and_agrees_with_python(tmp_path):
    python, c_program = blocks("python"), blocks("c")
    assert len(python) == 2 and len(c_program) == 1
    script = tmp_path / "example.py"
    script.write_text(python[0] + "\n" + python[1] + "\nprint(run.diverged_at is None and run.u.shape)\n")
    env = dict(os.environ, PYTHONPATH=str(REPO), CODESIGN_CONTROL_CACHE=str(tmp_path / "cache"))
    done = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip().splitlines()[-1] == "(1000, 1)"
    generated = tmp_path / "generated"
    assert sorted(p.name for p in generated.iterdir()) == ["arm_mpc.c", "arm_mpc.h", "arm_pid.c", "arm_pid.h"]
    (generated / "main.c").write_text(c_program[0])
    command = [*mc.compiler(), "-std=c99", "-O2", f"-I{daqp_include_directory()}", "-o", "main"]  # as the doc says
    subprocess.run(
        [*command, "main.c", "arm_pid.c", "arm_mpc.c", daqp_library(), "-lm"],
        cwd=generated,
        check=True,
        capture_output=True,
    )
    printed = subprocess.run([str(generated / "main")], check=True, capture_output=True, text=True).stdout
    rows = [line.split() for line in printed.strip().splitlines()]
    # The same three samples through the Python controllers.
    pid = providers.classical("arm")["PID"]
    linear = providers.mpc("arm")["linear MPC"]
    r = np.array([0.5])
    states = [pid.initial_state([0.0], r), linear.initial_state([0.0], r)]
    for k, row in enumerate(rows):
        y = np.array([0.01 * k])
        commands = []
        for i, controller in enumerate((pid, linear)):
            states[i], u = controller.step(states[i], y, r)
            commands.append(u[0])
        np.testing.assert_allclose([float(row[0]), float(row[1])], commands, atol=1e-9, rtol=0)
        assert row[2] == "0"
    assert len(rows) == 3


@pytest.mark.slow
def test_the_documentation_site_builds_with_warnings_as_errors(tmp_path):
    # The same command as .ci/run: the pages, the notebooks (executed once, minutes) and the API reference.
    pytest.importorskip("sphinx")
    pytest.importorskip("myst_nb")
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")])))
    command = [sys.executable, "-m", "sphinx", "-W", "-q", "-b", "html", "-d", str(tmp_path / "doctrees")]
    done = subprocess.run(
        [*command, str(root / "docs"), str(tmp_path / "html")], env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]
    api = (tmp_path / "html" / "api.html").read_text(encoding="utf-8")
    assert "simulate_closed_loop" in api and "NonlinearMPC" in api
    for notebook in sorted((root / "notebooks").glob("*.py")):
        assert (tmp_path / "html" / "notebooks" / f"{notebook.stem}.html").is_file(), notebook.stem
    assert (tmp_path / "html" / "_images" / "overview.png").is_file()


def test_the_overview_picture_sets_the_figures_side_by_side_at_one_height(tmp_path):
    """docs/overview_picture.py's layout: two figures of aspect 2:1 and 1:2 at one height h make a picture
    of aspect (2 + 0.5):1, each figure's colour where its share of the width puts it."""
    import importlib.util

    import matplotlib.image as mpimg

    spec = importlib.util.spec_from_file_location("overview_picture", REPO / "docs" / "overview_picture.py")
    picture = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(picture)
    red, blue = np.zeros((100, 200, 3)), np.zeros((200, 100, 3))
    red[..., 0], blue[..., 2] = 1.0, 1.0
    for name, image in zip(picture.FIGURES, (red, blue)):
        mpimg.imsave(tmp_path / name, image)
    picture.draw(tmp_path, tmp_path / "out.png", height_in=2.0, dpi=50)
    out = mpimg.imread(tmp_path / "out.png")
    assert out.shape[0] == 100 and abs(out.shape[1] - 250) <= 1, out.shape
    left, right = out[50, 40], out[50, 230]
    assert left[0] > 0.9 > left[2] and right[2] > 0.9 > right[0]
