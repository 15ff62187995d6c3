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


def test_the_documentation_site_builds_with_warnings_as_errors(tmp_path):
    # The same command as .ci/run: the pages, the notebooks (executed once) and the API reference.
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
    assert (tmp_path / "html" / "notebooks" / "arm.html").is_file()
