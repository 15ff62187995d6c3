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
# # Co-design: a spring's stiffness and its input, local and global optima
#
# A mass on a spring, m s̈ = −k s + u, is moved in T = 2 s from rest at s = −d to rest at s = +d with the least
# energy ½∫u² dt, plus a price c·k on the stiffness, k chosen in [0.5, 70] N/m. The plant and the input are
# designed together: the stiffness is a decision of the optimal control problem (`ocp.choose`).
#
# For a fixed k the problem is the minimum-energy transfer of a linear system, whose answer is given by the
# controllability Gramian W(T) = ∫₀ᵀ e^{Aτ} B Bᵀ e^{Aᵀτ} dτ: E*(k) = ½ rᵀ W(T)⁻¹ r with r = x_T − e^{AT} x₀.
# The free motion makes the transfer by itself whenever ωT is an odd multiple of π, so J*(k) = E*(k) + c k has
# a local minimum just below each of k ≈ 2.47, 22.2 and 61.7 N/m; the first is the global one.

# %%
import matplotlib.pyplot as plt
import numpy as np
from scipy.linalg import expm
from scipy.optimize import minimize_scalar

import models
import mpc
from models import catalog
from mpc import global_search

MASS, FINAL_TIME, DISTANCE, PRICE, K_RANGE = 1.0, 2.0, 0.05, 1e-3, (0.5, 70.0)
TRANSCRIPTION = mpc.Collocation(intervals=80)
assert models.Plant(catalog.spring_mass).params["m"] == MASS


def gramian_energy(k):
    """E*(k), J: the Gramian by Van Loan's matrix exponential."""
    A = np.array([[0.0, 1.0], [-k / MASS, 0.0]])
    B = np.array([[0.0], [1.0 / MASS]])
    van_loan = np.zeros((4, 4))
    van_loan[:2, :2], van_loan[:2, 2:], van_loan[2:, 2:] = -A, B @ B.T, A.T
    E = expm(van_loan * FINAL_TIME)
    W = E[2:, 2:].T @ E[:2, 2:]
    r = np.array([DISTANCE, 0.0]) - expm(A * FINAL_TIME) @ np.array([-DISTANCE, 0.0])
    return 0.5 * float(r @ np.linalg.solve(W, r))


def total(k):
    return gramian_energy(k) + PRICE * k


# %% [markdown]
# ## The closed form's landscape and its three minima

# %%
ks = np.linspace(*K_RANGE, 2001)
js = np.array([total(k) for k in ks])
inner = np.flatnonzero((js[1:-1] < js[:-2]) & (js[1:-1] < js[2:])) + 1
minima = []
for i in inner:
    found = minimize_scalar(total, bounds=(ks[i - 1], ks[i + 1]), method="bounded", options={"xatol": 1e-10})
    minima.append((float(found.x), float(found.fun)))
resonances = [(2 * n + 1) ** 2 * np.pi**2 * MASS / FINAL_TIME**2 for n in range(3)]
assert len(minima) == 3 and all(0.7 * r < k < r for (k, _), r in zip(minima, resonances))
for (k, j), r in zip(minima, resonances):
    print(f"local minimum k = {k:.4f} N/m (resonance {r:.3f}), J = {j:.6g}")

# %%
fig, ax = plt.subplots(figsize=(6, 3))
ax.semilogy(ks, js)
ax.plot(*zip(*minima), "o")
ax.set(xlabel="stiffness k (N/m)", ylabel="J*(k)", title="the closed form's landscape")
fig.tight_layout()


# %% [markdown]
# ## A local solve, and the global layer
#
# The nested method (`mpc.solve_nested`: the input's problem inside, the stiffness outside) started at
# 15 N/m stops on the second minimum; `mpc.global_search.codesign` sweeps the range, refines the best
# starts and returns the global one, within the transcription's accuracy (k to 1 %, J to 0.2 %).


# %%
def transfer(guess=None):
    ocp = mpc.OptimalControlProblem(models.Plant(catalog.spring_mass), FINAL_TIME)
    k = ocp.choose("k", *K_RANGE, guess=guess)
    ocp.minimize(ocp.integral(ocp.u.u**2 / 2) + PRICE * k)
    ocp.subject_to(ocp.at_start(ocp.state) == [-DISTANCE, 0])
    ocp.subject_to(ocp.at_end(ocp.state) == [DISTANCE, 0])
    return ocp


def close(k_found, j_found, k, j):
    return abs(k_found - k) <= 0.01 * k and abs(j_found - j) <= 2e-3 * abs(j)


local = mpc.solve_nested(transfer(15.0), TRANSCRIPTION)
assert local.success and close(local.params["k"], local.objective, *minima[1])
print(f"local solve from 15 N/m: k = {local.params['k']:.4f} N/m, J = {local.objective:.6g}")

found = global_search.codesign(transfer(15.0), TRANSCRIPTION)
best = min(minima, key=lambda m: m[1])
assert found.converged and close(found.best.params["k"], found.best.objective, *best)
print(found.design, "-", found.how)
for optimum in found.optima:
    print(f"  optimum k = {optimum.params['k']:.4f} N/m, J = {optimum.objective:.6g}")
