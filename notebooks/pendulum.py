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
# # The inverted pendulum on a cart: plant, classical, state space, LQR and MPC, the table
#
# The cart's position z is tracked through the pendulum's angle θ: an inner loop F → θ and an outer loop θ → z
# (successive loop closure). The plant is unstable about the upright equilibrium.
# The designs see the model the case says the controller knows (its parameters off by the case's error);
# the runs use the true nonlinear plant with its actuator limit. Each step checks its numbers against an
# independent derivation.

# %%
import control
import numpy as np
import scipy.linalg

import studies
from designs.loops import cascade_plants
from designs.pid import pd_design
from models.lqr import lqr
from studies import providers, tuner
from studies.runner import Options, run_study

case = studies.get("pendulum")
known = case.known_plant()
limit = float(known.input_limit[0])
linear = known.linearize()
(u_name,) = linear.input_names
print(case.plant, "tracked:", case.tracked, "input:", u_name, "limit:", limit, case.input_unit)

# %% [markdown]
# ## The plant, linearized about its operating point
#
# Every pole of the transfer function from the input to the tracked coordinate (python-control's `ss2tf` of
# the linearization with C picking that coordinate's state) is an eigenvalue of the linearization's A.

# %%
A, B = np.asarray(linear.A, dtype=float), np.asarray(linear.B, dtype=float)
eigs = np.linalg.eigvals(A)
C = np.eye(A.shape[0])[[linear.state_names.index(case.tracked)]]
G = control.ss2tf(A, B, C, np.zeros((1, 1)))
poles = np.roots(np.ravel(G.den[0][0]))
assert all(np.min(np.abs(eigs - p)) <= 1e-6 * max(1.0, abs(p)) for p in poles), (poles, eigs)
print("eigenvalues of A:", np.round(eigs, 4))
print("poles of G(s):", np.round(poles, 4))

# %% [markdown]
# ## Classical: a PD on the theta loop's second-order model
#
# The loop's model is b / (s² + a₁ s + a₀), read from the linearization's row of theta's acceleration. With
# u = kp e − kd thetȧ the closed loop's denominator is s² + (a₁ + b kd) s + (a₀ + b kp), so
# kp = (ωn² − a₀) / b and kd = (2 ζ ωn − a₁) / b; here ωn = 10.0 rad/s and ζ = 0.707.

# %%
G_in = cascade_plants(known, case.cascade[0], case.cascade[1]).inner
num, den = np.ravel(G_in.num[0][0]), np.ravel(G_in.den[0][0])
b, a1, a0 = num[-1] / den[0], den[1] / den[0], den[2] / den[0]
WN, ZETA = 10.0, 0.707
pd = pd_design(G_in, zeta=ZETA, wn=WN)
assert np.isclose(pd.kp, (WN**2 - a0) / b, rtol=1e-9), pd.kp
assert np.isclose(pd.kd, (2 * ZETA * WN - a1) / b, rtol=1e-9), pd.kd
closed = np.roots([1.0, a1 + b * pd.kd, a0 + b * pd.kp])
assert np.allclose(np.abs(closed), WN, rtol=1e-9) and np.allclose(-closed.real / np.abs(closed), ZETA, rtol=1e-9)
print(f"kp = {pd.kp:.6g} N/rad, kd = {pd.kd:.6g} (the same per rad/s)")

# %% [markdown]
# ## State space: the LQR's Riccati solution
#
# The project's continuous LQR (`models.lqr.lqr`) against K = R⁻¹ Bᵀ P with P from scipy's
# `solve_continuous_are`, and against python-control's `lqr`; the closed loop A − B K is stable.

# %%
Q, R = np.eye(A.shape[0]), np.array([[1 / limit**2]])
P = scipy.linalg.solve_continuous_are(A, B, Q, R)
K = np.linalg.solve(R, B.T @ P)
K_project = np.atleast_2d(lqr(A, B, Q, R)[0])
K_control, _, _ = control.lqr(A, B, Q, R)
assert np.allclose(K_project, K, rtol=1e-8), (K_project, K)
assert np.allclose(K_control, K, rtol=1e-8), (K_control, K)
assert np.all(np.linalg.eigvals(A - B @ K).real < 0)
print("K =", np.round(K, 4))

# %% [markdown]
# ## The case's controllers on the text's step, the table
#
# Every controller the case designs (classical, state space, linear and nonlinear MPC) and the tuned gains
# stored with the case (`python -m studies.tuner pendulum` finds them), run on the true plant on the step
# scenario only, without the Monte Carlo: the quick settings. Every input stays within its limit.

# %%
kinds = [providers.classical, providers.statespace, providers.mpc, providers.tuned]
result = run_study(case, Options(scenarios=("step",), mc=0, quick=True), providers=kinds)
table = result.table
assert (table["peak_u"] <= table["u_limit"] + 1e-9).all(), table[["controller", "peak_u", "u_limit"]]
assert {"LQR", "linear MPC", "nonlinear MPC", "tuned"} <= set(table["controller"])
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
print(f"Ts = {Ts} s; the largest |eigenvalue| of A_d: {np.max(np.abs(np.linalg.eigvals(block[:n, :n]))):.6f}")

# %% [markdown]
# ## Tuning
#
# The tuned controller's gains, read from the case's stored file beside its case file: the tuner started
# from the hand design's gains and searched on the known plant against the case's specs.

# %%
gains = tuner.stored(case)
print("hand design:", {k: round(v, 4) for k, v in gains["start_gains"].items()})
print("tuned:      ", {k: round(v, 4) for k, v in gains["gains"].items()})
print(table.loc[table["controller"] == "tuned", ["verdict", "verdict_detail"]].to_string(index=False))
