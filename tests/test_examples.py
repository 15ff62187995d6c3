"""Each script in examples/ runs in a fresh interpreter, from an empty folder, and one number it prints is
checked against a second method: a closed form or a hand computation from the text's numbers."""

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def run_example(name: str, cwd: Path, *args: str) -> str:
    """The script's standard output; its standard error in the failure message."""
    env = dict(
        os.environ,
        MPLBACKEND="Agg",
        PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
    )
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, f"{name} exited {done.returncode}:\n{done.stderr[-3000:]}"
    return done.stdout


def number(output: str, label: str) -> float:
    """The number printed after `label =` (one occurrence)."""
    found = re.findall(rf"^{re.escape(label)} = ([-+0-9.eE]+)", output, flags=re.MULTILINE)
    assert len(found) == 1, f"expected one line '{label} = ...' in:\n{output}"
    return float(found[0])


def test_every_example_has_a_test():
    tested = {"declare_a_plant.py", "pid_on_a_case_study.py", "optimal_control.py", "add_a_case_study.py"}
    assert {p.name for p in EXAMPLES.glob("*.py")} == tested


def test_declare_a_plant_matches_the_closed_form_step_response(tmp_path):
    out = run_example("declare_a_plant.py", tmp_path)
    m, k, b, force, t = 2.0, 8.0, 1.6, 4.0, 6.0
    wn, zeta = math.sqrt(k / m), b / (2 * math.sqrt(k * m))
    assert number(out, "natural frequency") == pytest.approx(wn, rel=1e-9)
    assert number(out, "damping ratio") == pytest.approx(zeta, rel=1e-9)
    # Underdamped step response from rest: x = F/k (1 − e^{−ζω_n t} (cos ω_d t + ζ/√(1−ζ²) sin ω_d t)).
    wd = wn * math.sqrt(1 - zeta**2)
    x = (
        force
        / k
        * (1 - math.exp(-zeta * wn * t) * (math.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * math.sin(wd * t)))
    )
    assert number(out, "x at 6 s") == pytest.approx(x, abs=1e-8)
    # m s² + (b + k_d) s + (k + k_p) = m (s² + 2ζω s + ω²) with ω = 4 rad/s, ζ = 0.7.
    assert number(out, "kp") == pytest.approx(m * 16 - k)
    assert number(out, "kd") == pytest.approx(m * 2 * 0.7 * 4 - b)


def test_pid_on_a_case_study_pd_rests_where_gravity_balances_the_gain(tmp_path):
    out = run_example("pid_on_a_case_study.py", tmp_path)
    kp = float(re.search(r"kp = ([-0-9.e]+)", out).group(1))
    rows = [line.split() for line in out.splitlines()]
    finals = {row[0]: float(row[-1]) for row in rows if len(row) == 6 and row[0] in ("PD", "PID", "LQR")}
    assert set(finals) == {"PD", "PID", "LQR"}, out
    reference = math.radians(50)
    # The text's arm (m = 0.5 kg, ℓ = 0.3 m, g = 9.8 m/s²) at rest under a PD without feedforward:
    # k_p (r − θ) = m g ℓ/2 cos θ, unsaturated (the torque is below 1 N m there).
    torque = 0.5 * 9.8 * 0.3 / 2
    rest = scipy.optimize.brentq(lambda th: kp * (reference - th) - torque * math.cos(th), -math.pi / 2, reference)
    assert kp * (reference - rest) < 1.0
    assert finals["PD"] == pytest.approx(rest, abs=1e-6)
    # Integral action takes the error to zero.
    assert finals["PID"] == pytest.approx(reference, abs=1e-5)
    assert finals["LQR"] == pytest.approx(reference, abs=1e-5)


def test_optimal_control_matches_the_least_norm_sampled_transfer(tmp_path):
    out = run_example("optimal_control.py", tmp_path)
    assert "status = solved" in out
    # Second method: the inputs are held on 50 intervals, so the least ∫F² dt = h Σ u_k² is the least-norm
    # solution of x_N = Σ A_d^{N-1-k} B_d u_k = (1, 0), with (A_d, B_d) the exact zero-order-hold model.
    m, k, final_time, n = 1.0, 4.0, 2.0, 50
    h = final_time / n
    A, B = np.array([[0.0, 1.0], [-k / m, 0.0]]), np.array([[0.0], [1.0 / m]])
    held = scipy.linalg.expm(np.block([[A, B], [np.zeros((1, 3))]]) * h)
    A_d, B_d = held[:2, :2], held[:2, 2:]
    G = np.hstack([np.linalg.matrix_power(A_d, n - 1 - j) @ B_d for j in range(n)])
    u = G.T @ np.linalg.solve(G @ G.T, [1.0, 0.0])
    assert number(out, "minimum effort") == pytest.approx(h * u @ u, rel=1e-7)
    assert number(out, "largest state defect on re-simulation") < 1e-6


def test_add_a_case_study_pd_error_is_the_hand_computed_one(tmp_path):
    out = run_example("add_a_case_study.py", tmp_path)
    # The PD is designed on the known plant (m, k, b all 5 % high): m wₙ² = k + k_p with wₙ = 3 rad/s gives
    # k_p = 1.05 (9 − 4); on the true plant at rest k x = k_p (r − x), so the error is r k / (k + k_p).
    kp = 1.05 * (1.0 * 3.0**2 - 4.0)
    assert number(out, "PD steady-state error on the step") == pytest.approx(0.5 * 4.0 / (4.0 + kp), rel=1e-6)
    rows = [line.split() for line in out.splitlines()]
    assert any(row[:3] == ["LQR", "step", "meets"] for row in rows)
