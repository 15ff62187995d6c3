"""Compilation without a shell (models.compile): no command is built from a path, nothing
depends on the working directory, libraries are cached by content, and when compiling is
impossible the virtual machine runs instead with one warning.

Subprocesses run the closed loop of a small PD block on the arm, compiled and in CasADi's
virtual machine, and report the largest difference and the compile counters as JSON."""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import models
from models import compile as mc

REPO = Path(models.__file__).resolve().parent.parent
HOSTILE = "a b;touch X;"

SCRIPT = """
import json, os, sys, warnings
import casadi as ca
import numpy as np
import models
from models import compile as mc

class PD(models.Block):
    def __init__(self):
        super().__init__(sample_period=0.01, n_state=1, n_measured=1, n_reference=1, n_input=1,
                         gains={"kp": 4.0, "kd": 0.2})
    def expr(self, xc, y, r, gains):
        error = r[0] - y[0]
        u = 0.735 * ca.cos(y[0]) + gains["kp"] * error + gains["kd"] * (error - xc[0]) / 0.01
        return ca.vertcat(error), models.saturate(u, 1.0)

caught = []
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    plant = models.get("arm")
    runs = [models.simulate_closed_loop(plant, PD(), 0.3, 2.0, jit=jit, substeps=4) for jit in (False, True)]
    # The plant's RK4 step alone, compiled.
    again = mc.jit(plant.step_function(0.01, 4))
    x, u = np.array([0.1, 0.2]), np.array([0.3])
    step_difference = float(np.max(np.abs(np.asarray(again(x, u, plant.param_vector()))
                                          - np.asarray(plant.step_function(0.01, 4)(x, u, plant.param_vector())))))
print(json.dumps({
    "difference": float(max(np.max(np.abs(runs[0].u - runs[1].u)), np.max(np.abs(runs[0].x - runs[1].x)))),
    "step_difference": step_difference,
    "moved": float(np.max(np.abs(runs[0].x[:, 0]))),
    "cwd_writable": os.access(".", os.W_OK),
    "warnings": [str(w.message) for w in caught if issubclass(w.category, mc.CompilationUnavailable)],
    "compiled": mc.STATS.compiled, "cache_hits": mc.STATS.cache_hits, "fallbacks": mc.STATS.fallbacks,
}))
"""


def run_script(cwd: Path, env_changes: dict, prefix: tuple = ()) -> dict:
    """Run SCRIPT with `cwd` as working directory (the command after `prefix`); its JSON report."""
    script = Path(tempfile.mkdtemp(prefix="compile-script-")) / "script.py"
    script.write_text(SCRIPT)
    os.chmod(script.parent, 0o755)
    os.chmod(script, 0o644)
    env = {key: value for key, value in os.environ.items() if key not in ("CC", "CODESIGN_CONTROL_CACHE")}
    env |= {"PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1"} | env_changes
    env = {key: value for key, value in env.items() if value is not None}
    try:
        done = subprocess.run(
            [*prefix, sys.executable, str(script)], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
        )
    finally:
        script.unlink()
        script.parent.rmdir()
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.fixture
def world_readable_tmp():
    """A temporary folder any user can enter (pytest's own is private to its user)."""
    path = Path(tempfile.mkdtemp(prefix="compile-test-"))
    os.chmod(path, 0o755)
    yield path
    for root, dirs, _ in os.walk(path):
        for name in dirs:
            os.chmod(os.path.join(root, name), 0o755)
    subprocess.run(["rm", "-rf", "--", str(path)], check=True)


def entries(cache: Path) -> int:
    """The number of cache entries (a folder with its library and record each); AssertionError when the
    cache holds anything else (a build folder left over)."""
    found = sorted(cache.iterdir())
    assert all(sorted(p.name for p in e.iterdir()) == [mc.RECORD_NAME, mc.LIBRARY_NAME] for e in found), found
    return len(found)


def listing(path: Path) -> list[str]:
    return sorted(str(p.relative_to(path)) for p in path.rglob("*"))


def test_jit_from_a_hostile_working_directory_runs_no_shell_and_matches_the_virtual_machine(world_readable_tmp):
    cwd = world_readable_tmp / HOSTILE
    cwd.mkdir()
    cache = world_readable_tmp / "cache dir;touch Y;"
    before = listing(world_readable_tmp)
    report = run_script(cwd, {"CODESIGN_CONTROL_CACHE": str(cache)})
    # Nothing was run from the path's text, nothing was written into the working directory.
    assert listing(cwd) == []
    created = sorted(set(listing(world_readable_tmp)) - set(before))
    assert not any(Path(name).name in ("X", "Y") for name in created), created
    assert all(name.startswith(cache.name) for name in created), created
    # The compiled closed loop gives the virtual machine's numbers (and the loop did move).
    assert report["moved"] > 0.2
    assert report["difference"] <= 1e-12 and report["step_difference"] <= 1e-14
    assert report["compiled"] == 2 and report["fallbacks"] == 0 and report["warnings"] == []
    # The cache holds the two libraries and no build folder.
    assert entries(cache) == 2
    assert stat.S_IMODE(cache.stat().st_mode) == 0o700


def test_a_second_run_and_two_concurrent_runs_compile_once(world_readable_tmp):
    cache = world_readable_tmp / "cache"
    env = {"CODESIGN_CONTROL_CACHE": str(cache)}
    script = world_readable_tmp / "script.py"
    script.write_text(SCRIPT)
    full_env = (
        {k: v for k, v in os.environ.items() if k != "CC"}
        | {"PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1"}
        | env
    )
    # Two processes compiling the same sources at once: both succeed, one library each in the cache.
    processes = [
        subprocess.Popen(
            [sys.executable, str(script)],
            cwd=world_readable_tmp,
            env=full_env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(2)
    ]
    reports = []
    for process in processes:
        out, err = process.communicate(timeout=300)
        assert process.returncode == 0, err[-3000:]
        reports.append(json.loads(out.strip().splitlines()[-1]))
    assert all(r["difference"] <= 1e-12 and r["fallbacks"] == 0 for r in reports)
    assert entries(cache) == 2  # no build folders left
    # A later run loads both from the cache: the compiler is not invoked.
    later = run_script(world_readable_tmp, env)
    assert later["compiled"] == 0 and later["cache_hits"] == 2
    assert later["difference"] <= 1e-12


def test_jit_from_a_read_only_working_directory(world_readable_tmp):
    cwd = world_readable_tmp / "read-only"
    cwd.mkdir()
    os.chmod(cwd, 0o555)
    prefix = ()
    if os.geteuid() == 0:
        # root writes anywhere; without the capability to override file permissions it cannot.
        if shutil.which("setpriv") is None:
            pytest.skip("running as root and setpriv (util-linux) is missing: cannot drop the permission override")
        prefix = ("setpriv", "--bounding-set=-dac_override,-dac_read_search")
    report = run_script(cwd, {"CODESIGN_CONTROL_CACHE": str(world_readable_tmp / "cache")}, prefix)
    assert not report["cwd_writable"] and listing(cwd) == []
    assert report["compiled"] == 2 and report["fallbacks"] == 0 and report["difference"] <= 1e-12


@pytest.mark.parametrize("missing", ["CC names no program", "PATH without a compiler"])
def test_without_a_compiler_the_virtual_machine_runs_with_one_warning(world_readable_tmp, missing):
    env = {"CODESIGN_CONTROL_CACHE": str(world_readable_tmp / "cache")}
    env |= {"CC": "/nonexistent/cc"} if missing.startswith("CC") else {"PATH": str(world_readable_tmp)}
    report = run_script(world_readable_tmp, env)
    assert report["compiled"] == 0 and report["fallbacks"] == 2
    assert len(report["warnings"]) == 1 and "no C compiler" in report["warnings"][0]
    assert report["difference"] == 0.0 and report["step_difference"] == 0.0
    assert not (world_readable_tmp / "cache").exists() or not any((world_readable_tmp / "cache").iterdir())


# ---------------------------------------------------------------------------- in this process
@pytest.fixture
def private_cache(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(cache))
    return cache


def square_plus_sine() -> ca.Function:
    x = ca.SX.sym("x", 3)
    return ca.Function("square_plus_sine", [x], [x**2 + ca.sin(x)], ["x"], ["y"])


def test_second_compilation_of_the_same_source_is_a_cache_hit(private_cache):
    fun = square_plus_sine()
    before = (mc.STATS.compiled, mc.STATS.cache_hits)
    first, second = mc.jit(fun), mc.jit(square_plus_sine())
    assert (mc.STATS.compiled - before[0], mc.STATS.cache_hits - before[1]) == (1, 1)
    x = np.array([0.3, -1.2, 2.5])
    np.testing.assert_array_equal(np.asarray(first(x)), np.asarray(second(x)))
    np.testing.assert_allclose(np.asarray(first(x)).ravel(), x**2 + np.sin(x), rtol=1e-15)
    # Other flags are another library.
    mc.jit(fun, flags=("-O1",))
    assert mc.STATS.compiled - before[0] == 2


def test_jit_nlpsol_solves_like_the_virtual_machine(private_cache):
    x, p = ca.MX.sym("x", 2), ca.MX.sym("p")
    problem = {"x": x, "p": p, "f": (x[0] - p) ** 2 + 10 * (x[1] - x[0] ** 2) ** 2, "g": x[0] + x[1]}
    options = {"ipopt": {"print_level": 0, "sb": "yes", "tol": 1e-12}, "print_time": False}
    before = mc.STATS.compiled
    compiled = mc.jit_nlpsol("rosenbrock", "ipopt", problem, options)
    assert mc.STATS.compiled == before + 1
    plain = ca.nlpsol("rosenbrock", "ipopt", problem, options)
    args = dict(x0=[0.0, 0.0], p=0.7, lbg=-np.inf, ubg=1.0)
    np.testing.assert_allclose(np.asarray(compiled(**args)["x"]), np.asarray(plain(**args)["x"]), atol=1e-10)
    # The constrained optimum x0 + x1 = 1 with x1 = x0^2 (the Rosenbrock valley), checked by hand.
    x_opt = np.asarray(compiled(**args)["x"]).ravel()
    assert compiled.stats()["success"] and x_opt.sum() <= 1 + 1e-8


def test_solvers_that_differ_in_options_share_one_generated_library(private_cache, monkeypatch):
    """`jit_nlpsols`: the code is generated once (a large problem's takes minutes), every solver loads
    it with its own options, and each solves like its virtual-machine twin."""
    x, p = ca.MX.sym("x", 2), ca.MX.sym("p")
    problem = {"x": x, "p": p, "f": (x[0] - p) ** 2 + 10 * (x[1] - x[0] ** 2) ** 2, "g": x[0] + x[1]}
    options = {
        name: {"ipopt": {"print_level": 0, "sb": "yes", "tol": tol}, "print_time": False}
        for name, tol in (("tight", 1e-12), ("loose", 1e-3))
    }
    generated = []
    real = mc._generated
    monkeypatch.setattr(mc, "_generated", lambda functions, prefix: generated.append(prefix) or real(functions, prefix))
    solvers = mc.jit_nlpsols("ipopt", problem, options)
    assert list(solvers) == ["tight", "loose"] and len(generated) == 1
    args = dict(x0=[0.0, 0.0], p=0.7, lbg=-np.inf, ubg=1.0)
    for name, solver in solvers.items():
        plain = ca.nlpsol(name, "ipopt", problem, options[name])
        np.testing.assert_allclose(np.asarray(solver(**args)["x"]), np.asarray(plain(**args)["x"]), atol=1e-10)
        assert solver.stats()["iter_count"] == plain.stats()["iter_count"]
    assert solvers["loose"].stats()["iter_count"] < solvers["tight"].stats()["iter_count"]


def test_an_interrupted_compilation_leaves_no_build_folder(private_cache, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(mc.subprocess, "run", interrupted)
    monkeypatch.setattr(mc, "_compiler_identity", lambda command: "a compiler")
    with pytest.raises(KeyboardInterrupt):
        mc.build_library({"a.c": "int f(void) { return 1; }"})
    assert list(private_cache.iterdir()) == []


@pytest.mark.parametrize(
    "make_cache, reason",
    [
        (lambda tmp: "relative/cache", "not an absolute path"),
        (lambda tmp: tmp / "shared", "writable by other users"),
        (lambda tmp: tmp / "file", "cannot create the cache directory"),
    ],
)
def test_a_cache_that_is_not_private_refuses_to_build(tmp_path, monkeypatch, make_cache, reason):
    cache = make_cache(tmp_path)
    if cache == tmp_path / "shared":
        cache.mkdir(mode=0o777)
        os.chmod(cache, 0o777)
    elif cache == tmp_path / "file":
        cache.write_text("not a folder")
        cache = cache / "cache"
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(cache))
    with pytest.raises(mc.CompilationError, match=reason):
        mc.build_library({"a.c": "int f(void) { return 1; }"}, fallback=False)


def test_compiler_errors_are_reported_or_fall_back(private_cache, monkeypatch):
    broken = {"broken.c": "int f(void) { return undeclared_name; }"}
    with pytest.raises(mc.CompilationError, match="undeclared_name"):
        mc.build_library(broken, fallback=False)
    monkeypatch.setattr(mc, "_WARNED", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert mc.build_library(broken) is None
        assert mc.build_library(broken) is None
    assert [issubclass(w.category, mc.CompilationUnavailable) for w in caught] == [True]
    assert [p for p in private_cache.iterdir()] == []


@pytest.mark.parametrize(
    "files, match",
    [
        ({"../escape.c": "int f;"}, "plain file name"),
        ({"sub/a.c": "int f;"}, "plain file name"),
        ({"only.h": "int f;"}, "at least one .c file"),
    ],
)
def test_bad_file_sets_are_refused(files, match):
    with pytest.raises(ValueError, match=match):
        mc.build_library(files)
