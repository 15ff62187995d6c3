"""Blocks exported as C (models.export): the C step against the Python block on the nonlinear
plant, the files' contents, and the errors for what cannot be exported. The closed loops of every
designed controller kind on several plants are in tests/test_export_closed_loop.py."""

from __future__ import annotations

import re
import subprocess

import casadi as ca
import numpy as np
import pytest

import models
from models import compile as mc
from models.export import UnsupportedExport, c_array, c_identifiers, c_name, c_number, export_block


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("CODESIGN_CONTROL_CACHE", str(tmp_path_factory.getbasetemp() / "compile-cache"))


class PendulumPD(models.Block):
    """PD on theta with a dirty derivative, a cart PD outside it (one block), saturated at 5 N:
    state (theta_prev, theta_rate, z_prev, z_rate); an if_else that switches the derivative gain."""

    def __init__(self):
        super().__init__(
            sample_period=0.01,
            n_state=4,
            n_measured=2,
            n_reference=1,
            n_input=1,
            gains={"k": np.array([-0.05, -0.08, 40.0, 3.0]), "sigma": 0.05},
        )

    def expr(self, xc, y, r, gains):
        k, ts = gains["k"], self.sample_period
        beta = (2 * gains["sigma"] - ts) / (2 * gains["sigma"] + ts)
        z_rate = beta * xc[3] + (1 - beta) / ts * (y[0] - xc[2])
        theta_rate = beta * xc[1] + (1 - beta) / ts * (y[1] - xc[0])
        theta_ref = k[0] * (r[0] - y[0]) - k[1] * z_rate
        kd = ca.if_else(ca.fabs(theta_rate) > 1.0, 1.5 * k[3], k[3])
        u = -(k[2] * (theta_ref - y[1]) - kd * theta_rate)
        return ca.vertcat(y[1], theta_rate, y[0], z_rate), models.saturate(u, 5.0)

    def initial_state(self, y0, r0):
        y0 = np.asarray(y0, dtype=float)
        return np.array([y0[1], 0.0, y0[0], 0.0])


def test_exported_block_runs_the_same_closed_loop_as_the_python_block():
    plant = models.get("pendulum")
    block = PendulumPD()
    controller = export_block(block, "pendulum_pd").load(initial_state=block.initial_state)
    assert isinstance(controller, models.Controller)
    runs = [
        models.simulate_closed_loop(plant, c, 0.5, 10.0, input_disturbance=0.3, noise_std=1e-3, seed=4)
        for c in (block, controller)
    ]
    assert runs[0].diverged_at is None and np.max(np.abs(runs[0].u)) == 5.0  # it saturates
    np.testing.assert_allclose(runs[1].u, runs[0].u, atol=1e-9, rtol=0)
    np.testing.assert_allclose(runs[1].x, runs[0].x, atol=1e-9, rtol=0)
    assert all(s["code"] == 0 for s in runs[1].status)


def test_exported_files_are_self_contained_c99_without_allocation(tmp_path):
    exported = export_block(PendulumPD(), "pendulum_pd", initial_measurement=[0.2, 0.01], initial_reference=[0.5])
    written = exported.write(tmp_path / "out")
    assert sorted(p.name for p in written) == ["pendulum_pd.c", "pendulum_pd.h"]
    assert (tmp_path / "out" / "pendulum_pd.c").read_text() == exported.source
    includes = set(re.findall(r'#include [<"]([^>"]+)[>"]', exported.source + exported.header))
    assert includes == {"math.h", "pendulum_pd.h"}
    assert not re.search(r"\b(malloc|calloc|realloc|free)\s*\(", exported.source)
    for macro, value in (
        ("N_STATE", 4),
        ("N_MEASURED", 2),
        ("N_REFERENCE", 1),
        ("N_INPUT", 1),
        ("SAMPLE_PERIOD", "0.01"),
    ):
        assert f"#define PENDULUM_PD_{macro} {value}\n" in exported.header
    # The initial state offered is the block's own at the (y0, r0) given.
    np.testing.assert_array_equal(exported.initial_state, [0.01, 0.0, 0.2, 0.0])
    assert "const double PENDULUM_PD_INITIAL_STATE[4] = {\n    0.01, 0.0, 0.2, 0.0\n};" in exported.source
    # Strict C99 with every warning of -Wall an error, and the header from C++ too.
    command = mc.compiler()
    subprocess.run(
        [*command, "-std=c99", "-pedantic", "-Wall", "-Werror", "-c", "pendulum_pd.c", "-o", "x.o"],
        cwd=tmp_path / "out",
        check=True,
        capture_output=True,
    )
    subprocess.run(
        [*command, "-x", "c++", "-fsyntax-only", "-Wall", "-Werror", "pendulum_pd.h"],
        cwd=tmp_path / "out",
        check=True,
        capture_output=True,
    )


def test_a_c_program_using_the_header_gets_the_python_commands(tmp_path):
    """The documented use from C (no Python in between): state from the header's constant, steps
    on recorded measurements, commands printed with 17 digits and read back."""
    block = PendulumPD()
    y = np.array([[0.0, 0.0], [0.01, 0.02], [0.03, -0.01], [0.1, 0.3], [0.2, 1.4]])
    exported = export_block(block, "pd", initial_measurement=y[0], initial_reference=[0.5])
    exported.write(tmp_path)
    rows = ",\n".join("{" + ", ".join(c_number(v) for v in row) + "}" for row in y)
    (tmp_path / "main.c").write_text(f"""#include <stdio.h>
#include "pd.h"
static const double Y[{len(y)}][2] = {{{rows}}};
int main(void) {{
    pd_state state;
    double r[1] = {{0.5}}, u[1];
    int k;
    pd_set_state(&state, PD_INITIAL_STATE);
    for (k = 0; k < {len(y)}; ++k) {{
        if (pd_step(&state, Y[k], r, u)) return 1;
        printf("%.17g\\n", u[0]);
    }}
    return 0;
}}
""")
    command = mc.compiler()
    subprocess.run([*command, "-std=c99", "-O2", "-o", "main", "main.c", "pd.c", "-lm"], cwd=tmp_path, check=True)
    printed = subprocess.run([str(tmp_path / "main")], check=True, capture_output=True, text=True).stdout
    xc, expected = block.initial_state(y[0], [0.5]), []
    for row in y:
        xc, u = block.step(xc, row, [0.5])
        expected.append(u[0])
    np.testing.assert_allclose([float(v) for v in printed.split()], expected, atol=1e-12, rtol=0)


class CallbackGain(ca.Callback):
    """A gain computed in Python: CasADi can call it, C cannot contain it."""

    def __init__(self):
        ca.Callback.__init__(self)
        self.construct("python_gain", {})

    def eval(self, arg):
        return [2.0 * arg[0]]


class PythonInside(models.Block):
    def __init__(self):
        super().__init__(sample_period=0.01, n_state=0, n_measured=1, n_reference=1, n_input=1, gains={"k": 1.0})
        self._callback = CallbackGain()

    def expr(self, xc, y, r, gains):
        return ca.SX(0, 1), gains["k"] * (r[0] - y[0])

    @property
    def casadi_step(self):
        xc, y, r, g = ca.MX.sym("xc", 0), ca.MX.sym("y", 1), ca.MX.sym("r", 1), ca.MX.sym("g", 1)
        return ca.Function(
            "step",
            [xc, y, r, g],
            [ca.MX(0, 1), self._callback(g * (r - y))],
            ["xc", "y", "r", "gains"],
            ["xc_next", "u"],
        )


class NotABlock:
    name = "hand-written controller"
    sample_period, measures, n_reference = 0.01, "outputs", 1

    def initial_state(self, y0, r0):
        return np.zeros(0)

    def step(self, xc, y, r):
        return xc, np.zeros(1)


def test_what_cannot_be_exported_is_named():
    with pytest.raises(
        UnsupportedExport,
        match=r"PythonInside: its step calls something that is not plain "
        r"arithmetic: python_gain \(CallbackInternal\)",
    ):
        export_block(PythonInside(), "inside")
    with pytest.raises(
        UnsupportedExport,
        match="hand-written controller: only models.Block controllers are exported here; NotABlock is not one",
    ):
        export_block(NotABlock(), "hand")


@pytest.mark.parametrize("name", ["my controller", "1pid", "int", "pid__fast", "", "x" * 49, 3])
def test_names_must_be_c_identifiers(name):
    with pytest.raises(ValueError, match="name must be a C identifier prefix"):
        export_block(PendulumPD(), name)


@pytest.mark.parametrize(
    "text, expected",
    [
        ("PID (no anti-windup)", "pid_no_anti_windup"),
        ("LQR + Kalman", "lqr_kalman"),
        ("arm_pole placement + integrator", "arm_pole_placement_integrator"),
        ("lead-lag (IV.11)", "lead_lag_iv_11"),
        ("2nd order", "c_2nd_order"),
        ("int", "int_c"),
        ("", "controller"),
        ("Régulateur à avance", "regulateur_a_avance"),
        ("__x__", "x"),
    ],
)
def test_a_c_identifier_is_derived_from_free_text(text, expected):
    (derived,) = c_identifiers([text])
    assert derived == expected and c_name(derived) == derived


def test_derived_c_identifiers_are_distinct_and_short_enough():
    texts = ["a b", "a-b", "a_b", "A B", "x" * 80, "x" * 81]
    derived = c_identifiers(texts)
    assert derived[:4] == ["a_b", "a_b_2", "a_b_3", "a_b_4"]
    assert len(set(derived)) == len(derived) and all(c_name(d) == d for d in derived)
    assert derived[4] == "x" * 48 and derived[5] == "x" * 46 + "_2"


def test_c_array_reads_back_every_double_bit_for_bit_and_refuses_non_finite_ones():
    """c_array's numbers are c_number's text (one per entry, six a line) and parse back to the same bits:
    integers, signed zeros, the largest and the smallest subnormal included; inf and nan are refused."""
    rng = np.random.default_rng(3)
    values = rng.standard_normal(600) * 10.0 ** rng.integers(-300, 300, 600)
    values[:6] = [0.0, -0.0, 3.0, -7.0, np.finfo(float).max, 5e-324]
    text = c_array("v", values)
    body = text[text.index("{") + 1 : text.rindex("}")]
    items = [item.strip() for item in body.split(",")]
    assert items == [c_number(v) for v in values]
    assert np.array_equal(np.array([float(item) for item in items]).view(np.int64), values.view(np.int64))
    for bad in (np.inf, -np.inf, np.nan):
        with pytest.raises(ValueError, match="non-finite"):
            c_array("w", [1.0, bad])
