"""Linear MPC exported as C (mpc.export): its QP (DAQP from C, set up once and warm-started) against
the Python path's DAQP and the cvxpy reference on the instances of test_solver_paths, its fault
statuses against the Python controller's, and the errors for what cannot be exported."""

from __future__ import annotations

import ctypes
import subprocess
import sys

import numpy as np
import pytest

import models
import mpc
from models import compile as mc
from models.export import UnsupportedExport
from mpc.export import STATUS, build_flags, daqp_include_directory, daqp_library, export_linear_mpc, status_text
from mpc.linear import QPSolution
from mpc.qp_fast import condense, parameter_vector
from mpc.reference_cvxpy import CvxpySolver

from .conftest import build
from .test_solver_paths import CASES, random_instances


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path_factory.getbasetemp() / "compile-cache"))


class ExportedQP:
    """The exported C's `name_solve_qp` as a solver path: solve(QPParameters) -> QPSolution.

    The C of an arm controller whose QP is replaced by `problem`: only its QP is called here."""

    name = "exported C"

    def __init__(self, problem):
        self.problem = problem
        controller = build("linear", "arm")  # any controller: its QP is replaced below
        controller.problem = problem
        exported = export_linear_mpc(controller, "qp")
        library = mc.build_library(exported.files(), (*mc.FLAGS, *build_flags()), fallback=False)
        self._library = ctypes.CDLL(str(library))
        self._library.qp_state_size.restype = ctypes.c_ulong
        self._memory = ctypes.create_string_buffer(self._library.qp_state_size())
        self._solve = self._library.qp_solve_qp
        self._solve.argtypes = [ctypes.c_void_p] * 3
        self._solve.restype = ctypes.c_int
        self.n = condense(problem).n

    def solve(self, params):
        p = np.ascontiguousarray(parameter_vector(params))
        z = np.zeros(self.n)
        code = self._solve(ctypes.addressof(self._memory), p.ctypes.data, z.ctypes.data)
        N, nu, ns = self.problem.horizon, self.problem.nu, self.problem.n_soft
        return QPSolution(z[: N * nu].reshape(N, nu), z[N * nu :].reshape(N, ns), code == 0, status_text(code))

    def reset(self):
        pass


@pytest.mark.parametrize("case", list(CASES))
def test_exported_qp_solver_matches_daqp_and_the_cvxpy_reference(case):
    """Saturating inputs, violated soft bounds, rate limits: the same optimum as DAQP to 1e-9 of
    the input limit in the first input, and the reference's cost."""
    build, scale, _, tolerance, _ = CASES[case]
    problem = build()
    exported, daqp, reference = ExportedQP(problem), mpc.CondensedDaqpSolver(problem), CvxpySolver(problem)
    limit = float(np.max(problem.input_upper - problem.input_lower)) / 2
    active = 0
    for params in random_instances(problem, scale, 12, seed=len(case) + 7):
        ours, theirs, ref = exported.solve(params), daqp.solve(params), reference.solve(params)
        assert ours.success and theirs.success and ref.success, (ours.status, theirs.status)
        np.testing.assert_allclose(ours.inputs[0], theirs.inputs[0], atol=1e-9 * max(1.0, limit), rtol=0)
        np.testing.assert_allclose(ours.inputs, theirs.inputs, atol=1e-8 * max(1.0, limit), rtol=0)
        np.testing.assert_allclose(ours.inputs[0], ref.inputs[0], atol=tolerance, rtol=0)
        cost = problem.cost(params, ours.inputs, ours.slacks)
        assert cost == pytest.approx(problem.cost(params, ref.inputs, ref.slacks), rel=1e-6, abs=1e-9)
        active += bool(
            np.any(np.isclose(np.abs(ours.inputs - (problem.input_upper + problem.input_lower) / 2), limit, atol=1e-9))
        )
    assert active >= 2  # the instances do saturate


def first_steps(controller, plant, y, r, steps=3):
    xc = controller.initial_state(y, r)
    for _ in range(steps):
        xc, _ = controller.step(xc, y, r)
    return xc


@pytest.mark.parametrize("fault, status", [("measurement", 1), ("estimate", 2), ("estimate and plan", 2 | 16)])
def test_exported_step_reports_non_finite_values_as_python_does(fault, status):
    plant = models.get("pendulum")
    python = build("linear", "pendulum")
    compiled = export_linear_mpc(python, "faults").load()
    y, r = plant.output(plant.equilibrium()[0]), np.array([0.3])
    xc = first_steps(python, plant, y, r)
    np.testing.assert_allclose(first_steps(compiled, plant, y, r), xc, atol=1e-12, rtol=0)
    xc, y = xc.copy(), y.copy()
    if fault == "measurement":
        y[1] = np.nan
    else:
        xc[1] = np.inf
    if fault == "estimate and plan":
        xc[plant.nx + 1 :] = np.nan
    results = [controller.step(xc, y, r) for controller in (python, compiled)]
    info = compiled.step_info()
    assert info["code"] == status and not info["success"]
    assert info["status"] == python.step_info()["status"]
    for (xc_python, u_python), (xc_c, u_c) in zip(results[:1], results[1:]):
        np.testing.assert_array_equal(np.isnan(u_c), np.isnan(u_python))
        np.testing.assert_allclose(u_c, u_python, atol=1e-12, rtol=0)
        np.testing.assert_allclose(xc_c, xc_python, atol=1e-12, rtol=0)
    if fault == "estimate and plan":
        assert np.all(np.isnan(results[1][1]))  # never a NaN turned into a limit


def test_exported_init_refuses_a_non_finite_first_measurement():
    compiled = export_linear_mpc(build("linear", "arm"), "init").load()
    with pytest.raises(ValueError, match=r"init returned 1 \(non-finite measurement\)"):
        compiled.initial_state([np.nan], [0.0])


def test_status_codes_are_named_in_the_header():
    exported = export_linear_mpc(build("linear", "arm"), "arm_mpc")
    for code, text in STATUS.items():
        assert f"#define ARM_MPC_{text.upper().replace(' ', '_').replace('-', '')} {code}\n" in exported.header
    assert "#define ARM_MPC_NONFINITE_COMMAND 16\n" in exported.header


def test_what_cannot_be_exported_is_named():
    with pytest.raises(
        UnsupportedExport,
        match=r"nonlinear MPC: only mpc.LinearMPC and mpc.TubeMPC are exported here; "
        r"NonlinearMPC is not one \(mpc.export_nmpc.export_nonlinear_mpc exports",
    ):
        export_linear_mpc(build("nonlinear", "arm"), "nmpc")
    with pytest.raises(
        UnsupportedExport,
        match="linear MPC: only models.Block controllers are exported here; "
        r"LinearMPC is not one \(use mpc.export.export_linear_mpc\)",
    ):
        models.export.export_block(build("linear", "arm"), "mpc")
    with pytest.raises(ValueError, match="name must be a C identifier prefix"):
        export_linear_mpc(build("linear", "arm"), "linear MPC")


#: A C program counting the allocator's calls (GNU ld's --wrap puts these in front of malloc and free):
#: init, 50 steps, a second init, then free; it prints the calls after each phase.
COUNTING_PROGRAM = r"""
#include <stdio.h>
#include <stdlib.h>
#include "counted.h"
static long allocations = 0, releases = 0;
void *__real_malloc(size_t); void *__real_calloc(size_t, size_t); void *__real_realloc(void *, size_t);
void __real_free(void *);
void *__wrap_malloc(size_t n) { ++allocations; return __real_malloc(n); }
void *__wrap_calloc(size_t n, size_t size) { ++allocations; return __real_calloc(n, size); }
void *__wrap_realloc(void *p, size_t n) { ++allocations; return __real_realloc(p, n); }
void __wrap_free(void *p) { if (p) ++releases; __real_free(p); }
static counted_state state;
int main(void) {
    double y[COUNTED_N_MEASURED] = {0}, r[1] = {0.3}, u[1];
    int k, failed = 0;
    failed |= counted_init(&state, y, r);
    printf("%ld %ld\n", allocations, releases);
    for (k = 0; k < 50; ++k) { y[1] = 0.01 * (k % 7); failed |= counted_step(&state, y, r, u) & ~16; }
    printf("%ld %ld\n", allocations, releases);
    failed |= counted_init(&state, y, r);
    printf("%ld %ld\n", allocations, releases);
    counted_free(&state);
    printf("%ld %ld %d\n", allocations, releases, failed);
    return 0;
}
"""


@pytest.mark.skipif(sys.platform != "linux", reason="counts allocations with GNU ld's --wrap")
def test_daqp_allocates_at_init_only_and_frees_it_all(tmp_path):
    """On the pendulum (soft bound: rows that change every sample): DAQP's setup in name_init is the
    only allocation; 50 steps allocate nothing; a second init frees the first workspace before
    allocating again; name_free releases everything."""
    exported = export_linear_mpc(build("linear", "pendulum"), "counted")
    exported.write(tmp_path)
    (tmp_path / "main.c").write_text(COUNTING_PROGRAM)
    wrap = "-Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc,--wrap=free"
    arguments = ["-std=c99", "-O2", f"-I{daqp_include_directory()}", "-o", "counted", "main.c", "counted.c"]
    subprocess.run([*mc.compiler(), *arguments, daqp_library(), "-lm", wrap], cwd=tmp_path, check=True)
    printed = subprocess.run([str(tmp_path / "counted")], check=True, capture_output=True, text=True).stdout
    counts = [[int(v) for v in line.split()] for line in printed.splitlines()]
    (init, none), (after_steps, still_none), (again, freed), (total, released, failed) = counts
    assert failed == 0
    assert init > 0 and none == 0
    assert (after_steps, still_none) == (init, 0)
    assert (again, freed) == (2 * init, init)
    assert total == released == 2 * init
