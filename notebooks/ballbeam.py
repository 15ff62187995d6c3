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
# # The ball on a beam: plant, classical, state space, LQR and MPC, the table
#
# The ball's position z is tracked through the beam's angle θ: an inner loop F → θ and an outer loop θ → z; the
# force at the beam's end also holds the beam and ball against gravity. The linearization's poles are
# ±3.57 and ±3.57j rad/s: unstable without feedback.
#
# The designs see the model the case says the controller knows (its parameters off by the case's error); the
# runs use the true nonlinear plant with its actuator limit. Each step is a function of `studies.course`
# that returns its numbers and checks them against an independent derivation (see its docstrings).

# %%
import numpy as np

import studies
from studies import course

case = studies.get("ballbeam")
plant = course.linearization(case)
print(plant.report())

# %% [markdown]
# ## Classical: a PD at ωn = 8.0 rad/s, ζ = 0.707
#
# The inner loop's model θ/F = b / (s² + a₁ s + a₀) (`designs.loops.cascade_plants`), a double integrator
# about the level beam (a₁ = a₀ = 0).

# %%
pd = course.pd_by_poles(course.loop_model(case), wn=8.0, zeta=0.707)
print(pd.report("N"))

# %% [markdown]
# ## State space: the LQR
#
# Q = I on (z, θ, ż, θ̇), R = 1/(15 N)².

# %%
K = course.lqr_gain(plant.A, plant.B, np.eye(4), np.array([[1 / plant.limit**2]]))
print("K =", np.round(K, 4))

# %% [markdown]
# ## The case's controllers on the text's step, the table
#
# Every controller the ballbeam case designs and the tuned gains stored with it (`python -m studies.tuner ballbeam`
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
