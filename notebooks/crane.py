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
# # The overhead crane with two loads: plant, classical, state space, LQR and MPC, the table
#
# The trolley's position x is tracked through the load's swing: the classical design uses the one-load,
# frictionless model (the case's `one_load_model`), the runs use the double pendulum. The two swing modes
# (near 0.65 and 1.12 rad/s) and the trolley's free motion are the poles of x/F.
#
# The designs see the model the case says the controller knows (its parameters off by the case's error); the
# runs use the true nonlinear plant with its actuator limit. Each step is a function of `studies.course`
# that returns its numbers and checks them against an independent derivation (see its docstrings).

# %%
import numpy as np

import studies
from studies import course
from studies.cases.crane import one_load_model

case = studies.get("crane")
plant = course.linearization(case)
print(plant.report())

# %% [markdown]
# ## Classical: a PD at ωn = 3.0 rad/s, ζ = 0.707
#
# The inner loop's model θ/F = b / (s² + a₁ s + a₀) of the one-load model (`one_load_model(plant.known)`,
# m₂ = ℓ₂ = b = 0), as the text designs it.

# %%
pd = course.pd_by_poles(course.loop_model(case, one_load_model(plant.known)), wn=3.0, zeta=0.707)
print(pd.report("N"))

# %% [markdown]
# ## State space: the LQR
#
# Q = I on (x, θ₁, θ₂, ẋ, θ̇₁, θ̇₂), R = 1/(5000 N)².

# %%
K = course.lqr_gain(plant.A, plant.B, np.eye(6), np.array([[1 / plant.limit**2]]))
print("K =", np.round(K, 4))

# %% [markdown]
# ## The case's controllers on the text's step, the table
#
# Every controller the crane case designs and the tuned gains stored with it (`python -m studies.tuner crane`
# finds them), on the true plant, the step scenario only, without the Monte Carlo. Every input stays within
# its limit.

# %%
result = course.quick_table(case, expected=["LQR", "linear MPC", "nonlinear MPC", "tuned"])
result.table[course.TABLE_COLUMNS].round(3)

# %% [markdown]
# ## The linear MPC's prediction model and the tuned gains

# %%
print(course.prediction_model(result.controllers["linear MPC"], plant.A, plant.B).report())
print(course.tuning_report(case, result.table))
