# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # The single-link arm: plant, PD, LQR, tuning, the table
#
# The plant is declared once by its energies (`models.get("arm")`); the designs see the model the case says
# the controller knows (mass and length 5 % off), the runs use the true nonlinear arm with its 1 N m limit.
# Each step checks its numbers against an independent derivation.

# %%
import control
import numpy as np
import scipy.linalg

import models
import studies
from designs.pid import PID, pd_design
from models.lqr import lqr
from models.metrics import run_metrics
from studies import providers, tuner
from studies.runner import Options, run_study

case = studies.get("arm")
known = case.known_plant()
truth = models.get("arm")
limit = float(known.input_limit[0])

# %% [markdown]
# ## The plant, linearized about the level arm
#
# The linearization's transfer function θ/τ = b / (s² + a₁ s + a₀); its poles are the roots of that
# denominator, which must be the eigenvalues of the linearization's A.

# %%
linear = known.linearize()
G = linear.tf("theta", "tau")
num, den = np.ravel(G.num[0][0]), np.ravel(G.den[0][0])
den = den / den[0]
b = num[-1] / 1.0
a1, a0 = den[1], den[2]
hand = np.roots([1.0, a1, a0])
eigs = np.linalg.eigvals(np.asarray(linear.A, dtype=float))
assert np.allclose(np.sort_complex(hand), np.sort_complex(eigs), atol=1e-9), (hand, eigs)
print("poles:", hand)

# %% [markdown]
# ## Classical: a PD placing the closed-loop poles at ωn = 10 rad/s, ζ = 0.707
#
# With u = kp e − kd θ̇ the closed loop's denominator is s² + (a₁ + b kd) s + (a₀ + b kp), so
# kp = (ωn² − a₀) / b and kd = (2 ζ ωn − a₁) / b.

# %%
WN, ZETA = 10.0, 0.707
pd = pd_design(G, zeta=ZETA, wn=WN)
assert np.isclose(pd.kp, (WN**2 - a0) / b, rtol=1e-9), pd.kp
assert np.isclose(pd.kd, (2 * ZETA * WN - a1) / b, rtol=1e-9), pd.kd
print(f"kp = {pd.kp:.6g} N m/rad, kd = {pd.kd:.6g} N m s/rad")

# %% [markdown]
# ## State space: the LQR's Riccati solution
#
# The project's continuous LQR (`models.lqr.lqr`) against K = R⁻¹ Bᵀ P with P from scipy's
# `solve_continuous_are`, and against python-control's `lqr`; the closed loop A − B K is stable.

# %%
A, B = np.asarray(linear.A, dtype=float), np.asarray(linear.B, dtype=float)
Q, R = np.diag([1 / 0.2**2, 1 / 5.0**2]), np.array([[1 / limit**2]])
P = scipy.linalg.solve_continuous_are(A, B, Q, R)
K = np.linalg.solve(R, B.T @ P)
K_project = np.atleast_2d(lqr(A, B, Q, R)[0])
K_control, _, _ = control.lqr(A, B, Q, R)
assert np.allclose(K_project, K, rtol=1e-8), (K_project, K)
assert np.allclose(K_control, K, rtol=1e-8), (K_control, K)
assert np.all(np.linalg.eigvals(A - B @ K).real < 0)
print("K =", K)

# %% [markdown]
# ## The PD on the true nonlinear arm, the text's 50° step

# %%
timing = dict(sample_period=case.sample_period, sigma=case.derivative_time_constant)
controller = PID(known, "theta", kp=pd.kp, kd=pd.kd, output_limit=limit, name="PD", **timing)
run = models.simulate_closed_loop(truth, controller, np.deg2rad(50), 8.0)
m = run_metrics(run, "theta")
assert np.max(np.abs(run.u)) <= limit + 1e-12  # the actuator limit holds
print({k: round(float(v), 4) for k, v in m.items() if isinstance(v, float)})

# %% [markdown]
# ## Tuning: the PID's gains searched on the known arm
#
# `python -m studies.tuner arm` started from the hand design's gains and searched them on the known plant
# against the case's specs; the result is stored beside the case file. On the linearization the PID's closed
# loop has the denominator s³ + (a₁ + b kd) s² + (a₀ + b kp) s + b ki, whose roots stay in the left half plane.

# %%
gains = tuner.stored(case)
print("hand design:", {k: round(v, 4) for k, v in gains["start_gains"].items()})
print("tuned:      ", {k: round(v, 4) for k, v in gains["gains"].items()})
tuned = gains["gains"]
assert np.all(np.roots([1.0, a1 + b * tuned["kd"], a0 + b * tuned["kp"], b * tuned["ki"]]).real < 0)

# %% [markdown]
# ## Every controller on the text's step: the quick study's table
#
# The classical, state-space, MPC and tuned controllers on the true arm, on the step scenario only and without
# the Monte Carlo (`python -m studies arm --quick` runs every scenario). Every input stays within its limit.

# %%
kinds = [providers.classical, providers.statespace, providers.mpc, providers.tuned]
result = run_study(case, Options(scenarios=("step",), mc=0, quick=True), providers=kinds)
table = result.table
assert (table["peak_u"] <= table["u_limit"] + 1e-9).all(), table[["controller", "peak_u", "u_limit"]]
columns = ["controller", "verdict", "rise_time_s", "settling_time_s", "overshoot_pct", "peak_u", "u_limit"]
table[columns].round(3)

# %% [markdown]
# ## The linear MPC's prediction model
#
# The linear MPC predicts with the linearization held over each sample (zero-order hold): A_d = e^{A Ts} and
# B_d = ∫₀^Ts e^{A τ} dτ B, both read off one matrix exponential of [[A, B], [0, 0]] Ts (Van Loan).

# %%
mpc_controller = result.controllers["linear MPC"]
Ts = mpc_controller.sample_period
n, m = B.shape
block = scipy.linalg.expm(np.block([[A, B], [np.zeros((m, n + m))]]) * Ts)
assert np.allclose(mpc_controller.model.A, block[:n, :n], rtol=1e-8, atol=1e-10)
assert np.allclose(mpc_controller.model.B, block[:n, n:], rtol=1e-8, atol=1e-10)
print(f"Ts = {Ts} s")
