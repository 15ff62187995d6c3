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
# (successive loop closure). Upright, the pendulum is unstable: the linearization has an eigenvalue near
# +4.8 rad/s, and it is a pole of z/F as of every transfer function of this plant.
#
# The designs see the model the case says the controller knows (its parameters off by the case's error); the
# runs use the true nonlinear plant with its actuator limit. Each step is a function of `studies.course`
# that returns its numbers and checks them against an independent derivation (see its docstrings).

# %%
import numpy as np

import studies
from studies import course

case = studies.get("pendulum")
plant = course.linearization(case)
print(plant.report())

# %% [markdown]
# ## Classical: a PD at ωn = 10.0 rad/s, ζ = 0.707
#
# The inner loop's model θ/F = b / (s² + a₁ s + a₀) (`designs.loops.cascade_plants`): b < 0 and a₀ < 0
# (the unstable fall), so both of the PD's gains come out negative.

# %%
pd = course.pd_by_poles(course.loop_model(case), wn=10.0, zeta=0.707)
print(pd.report("N"))

# %% [markdown]
# ## State space: the LQR
#
# Q = I on (z, θ, ż, θ̇), R = 1/(5 N)²: the whole force for a unit of any state.

# %%
K = course.lqr_gain(plant.A, plant.B, np.eye(4), np.array([[1 / plant.limit**2]]))
print("K =", np.round(K, 4))

# %% [markdown]
# ## The case's controllers on the text's step, the table
#
# Every controller the pendulum case designs and the tuned gains stored with it (`python -m studies.tuner pendulum`
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
