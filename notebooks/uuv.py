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
# # The underwater vehicle's pitch: plant, classical, state space, LQR and MPC, the table
#
# A single loop: the thruster's torque τ drives the pitch φ, with gravity and buoyancy and hydrodynamic damping;
# the thruster saturates at 50 N m. The linearization is a lightly damped oscillator (poles near
# −0.06 ± 1.2j rad/s), the poles of φ/τ.
#
# The designs see the model the case says the controller knows (its parameters off by the case's error); the
# runs use the true nonlinear plant with its actuator limit. Each step is a function of `studies.course`
# that returns its numbers and checks them against an independent derivation (see its docstrings).

# %%
import numpy as np

import studies
from studies import course

case = studies.get("uuv")
plant = course.linearization(case)
print(plant.report())

# %% [markdown]
# ## Classical: a PD at ωn = 2.0 rad/s, ζ = 0.9
#
# One loop, so the PD is placed on φ/τ itself: the pitch model is second order already, with ζ = 0.9
# asked for by the homework.

# %%
pd = course.pd_by_poles(course.loop_model(case), wn=2.0, zeta=0.9)
print(pd.report("N m"))

# %% [markdown]
# ## State space: the LQR
#
# Q = I on (φ, φ̇), R = 1/(50 N m)².

# %%
K = course.lqr_gain(plant.A, plant.B, np.eye(2), np.array([[1 / plant.limit**2]]))
print("K =", np.round(K, 4))

# %% [markdown]
# ## The case's controllers on the text's step, the table
#
# Every controller the uuv case designs and the tuned gains stored with it (`python -m studies.tuner uuv`
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
