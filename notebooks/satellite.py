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
# # The satellite with a flexible panel: plant, classical, state space, LQR and MPC, the table
#
# The panel's angle φ is tracked through the body's angle θ: an inner loop τ → θ and an outer loop θ → φ; the
# panel's spring and damper couple the two. The linearization has a double pole at the origin (the whole
# craft turns freely) and the panel's lightly damped mode near 0.42 rad/s.
#
# The designs see the model the case says the controller knows (its parameters off by the case's error); the
# runs use the true nonlinear plant with its actuator limit. Each step is a function of `studies.course`
# that returns its numbers and checks them against an independent derivation (see its docstrings).

# %%
import numpy as np

import studies
from studies import course

case = studies.get("satellite")
plant = course.linearization(case)
print(plant.report())

# %% [markdown]
# ## Classical: a PD at ωn = 1.0 rad/s, ζ = 0.707
#
# The inner loop's model θ/τ = b / (s² + a₁ s + a₀) seen with the panel's coupling folded in
# (`designs.loops.cascade_plants`).

# %%
pd = course.pd_by_poles(course.loop_model(case), wn=1.0, zeta=0.707)
print(pd.report("N m"))

# %% [markdown]
# ## State space: the LQR
#
# Q = I on (θ, φ, θ̇, φ̇), R = 1/(5 N m)².

# %%
K = course.lqr_gain(plant.A, plant.B, np.eye(4), np.array([[1 / plant.limit**2]]))
print("K =", np.round(K, 4))

# %% [markdown]
# ## The case's controllers on the text's step, the table
#
# Every controller the satellite case designs and the tuned gains stored with it (`python -m studies.tuner satellite`
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
