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
# # The optimal control layer: least-effort transfer of a mass on a spring
#
# Move the mass from rest at x = 0 to rest at x = 1 m in 2 s with the least ∫ F² dt:
# `mpc.OptimalControlProblem` on a plant declared by its energies, transcribed by direct collocation,
# solved by IPOPT, then re-simulated on the plant. The optimum is checked against the linear
# system's closed form, J* = dᵀ W⁻¹ d with W the controllability Gramian over [0, T].

# %%
import numpy as np
import scipy.integrate
import scipy.linalg

import models
import mpc

M, K = 1.0, 4.0  # kg, N/m
DISTANCE, FINAL_TIME, INTERVALS = 1.0, 2.0, 50  # m, s, held inputs


@models.declare(
    name="my_spring_mass",
    title="mass on a spring",
    coordinates=("x",),
    inputs=("F",),
    params=(models.Param("m", M, "kg"), models.Param("k", K, "N/m")),
    input_limit=100.0,
    register=False,
)
def spring_mass(q, dq, u, p):
    return models.Physics(kinetic=p.m * dq.x**2 / 2, potential=p.k * q.x**2 / 2, forces=[u.F], outputs={"x": q.x})


plant = models.Plant(spring_mass)

# %% [markdown]
# ## The problem, solved

# %%
ocp = mpc.OptimalControlProblem(plant, final_time=FINAL_TIME)
ocp.minimize(ocp.integral(ocp.u.F**2))
ocp.subject_to(ocp.at_start(ocp.state) == [0.0, 0.0])
ocp.subject_to(ocp.at_end(ocp.state) == [DISTANCE, 0.0])
solution = ocp.solve(mpc.Collocation(intervals=INTERVALS, degree=3))
print(solution.status, solution.objective)

# %% [markdown]
# ## Against the closed form
#
# ẋ = A x + B F with A = [[0, 1], [−k/m, 0]], B = [0, 1/m]. The least ∫ F² dt from x(0) = 0 to
# x(T) = x_f is x_fᵀ W⁻¹ x_f with W = ∫₀ᵀ e^{A t} B Bᵀ e^{Aᵀ t} dt. The transcription holds the input
# constant on each of its intervals, so its optimum is slightly above the continuous one.

# %%
A = np.array([[0.0, 1.0], [-K / M, 0.0]])
B = np.array([[0.0], [1.0 / M]])
W = scipy.integrate.quad_vec(lambda t: scipy.linalg.expm(A * t) @ B @ B.T @ scipy.linalg.expm(A.T * t), 0, FINAL_TIME)[
    0
]
target = np.array([DISTANCE, 0.0])
closed_form = float(target @ np.linalg.solve(W, target))
print(f"IPOPT {solution.objective:.6g} N² s, closed form {closed_form:.6g} N² s")
assert closed_form - 1e-9 <= solution.objective <= closed_form * 1.01

# %% [markdown]
# ## Re-simulated on the plant

# %%
check = solution.verify()  # the optimal input re-simulated by CVODES
print(f"largest state defect {check.max_defect:.3g}")
assert check.max_defect < 1e-4
