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
# Each step is a function of `studies.course`, shared by every case's notebook: it returns its numbers and
# checks them against an independent derivation (an AssertionError names the numbers that disagree).

# %%
import numpy as np

import models
import studies
from designs.pid import PID
from models.metrics import run_metrics
from studies import course

case = studies.get("arm")

# %% [markdown]
# ## The plant, linearized about the level arm
#
# The transfer function θ/τ = b / (s² + a₁ s + a₀) of the two-state linearization: its poles are the
# eigenvalues of A.

# %%
plant = course.linearization(case)
print(plant.report())

# %% [markdown]
# ## Classical: a PD placing the closed-loop poles at ωn = 10 rad/s, ζ = 0.707
#
# With u = kp e − kd θ̇ the closed loop's denominator is s² + (a₁ + b kd) s + (a₀ + b kp), so
# kp = (ωn² − a₀) / b and kd = (2 ζ ωn − a₁) / b.

# %%
pd = course.pd_by_poles(course.loop_model(case), wn=10.0, zeta=0.707)
print(pd.report("N m"))

# %% [markdown]
# ## State space: the LQR's Riccati solution
#
# Bryson's rule: at most 0.2 rad of angle, 5 rad/s of rate and the full 1 N m. The project's continuous LQR
# against K = R⁻¹ Bᵀ P from SciPy's Riccati solver and against python-control's `lqr`.

# %%
Q, R = np.diag([1 / 0.2**2, 1 / 5.0**2]), np.array([[1 / plant.limit**2]])
print("K =", course.lqr_gain(plant.A, plant.B, Q, R))

# %% [markdown]
# ## The PD on the true nonlinear arm, the text's 50° step

# %%
timing = dict(sample_period=case.sample_period, sigma=case.derivative_time_constant)
controller = PID(plant.known, "theta", kp=pd.kp, kd=pd.kd, output_limit=plant.limit, name="PD", **timing)
run = models.simulate_closed_loop(models.get("arm"), controller, np.deg2rad(50), 8.0)
assert np.max(np.abs(run.u)) <= plant.limit + 1e-12  # the actuator limit holds
print({k: v for k, v in course.rounded(run_metrics(run, "theta")).items() if isinstance(v, float)})

# %% [markdown]
# ## Tuning: the PID's gains searched on the known arm
#
# `python -m studies.tuner arm` started from the hand design's gains and searched them on the known plant
# against the case's specs; the result is stored beside the case file. On the linearization the PID's closed
# loop has the denominator s³ + (a₁ + b kd) s² + (a₀ + b kp) s + b ki, whose roots stay in the left half plane.

# %%
gains = course.tuned_gains(case)
print("hand design:", course.rounded(gains["start_gains"]))
print("tuned:      ", course.rounded(gains["gains"]))
assert np.all(pd.pid_poles(**gains["gains"]).real < 0)

# %% [markdown]
# ## Every controller on the text's step: the quick study's table
#
# The classical, state-space, MPC and tuned controllers on the true arm, on the step scenario only and without
# the Monte Carlo (`python -m studies arm --quick` runs every scenario). Every input stays within its limit.

# %%
result = course.quick_table(case, expected=["PD", "LQR", "linear MPC", "tuned"])
result.table[course.TABLE_COLUMNS].round(3)

# %% [markdown]
# ## The linear MPC's prediction model
#
# The linear MPC predicts with the linearization held over each sample (zero-order hold): A_d = e^{A Ts} and
# B_d = ∫₀^Ts e^{A τ} dτ B, both read off one matrix exponential of [[A, B], [0, 0]] Ts (Van Loan).

# %%
print(course.prediction_model(result.controllers["linear MPC"], plant.A, plant.B).report())
