"""Loop algebra and the frequency- and steady-state answers of the .10 and .13 homework.

Every closed loop here is the two-degree-of-freedom loop

    u = C_r(s) r − C_y(s) (y + n) + d_i,    y = P(s) u + d_o,

which covers PD/PID with the derivative on the error (C_r = C_y) or on the
measurement (C_r = k_p + k_i/s, C_y = k_p + k_i/s + k_d s), prefilters
(C_r = F C) and any C(s). Transfer functions are built from polynomial
products, never by subtracting rational functions, so a zero at s = 0 that
the algebra produces (an integrator, a derivative on the measurement) is an
exact zero and the system type and the steady-state limits come out exact:
an infinite error stays ``inf``.

Angles are in rad, frequencies in rad/s; "percent" values are 100·|G(jω)|
of the named transfer function (for a disturbance in N or N m reaching an
angle, that is rad per 100 N m, as the text's questions count it).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from models import deferred

if TYPE_CHECKING:
    import control
else:
    control = deferred.module("control")
scipy = deferred.module("scipy")

__all__ = [
    "Loop",
    "UnstableLoopError",
    "SpecCheck",
    "polynomial",
    "poly_add",
    "poly_sub",
    "poly_mul",
    "zeros_at_origin",
    "as_polynomials",
    "tf",
    "pid_tf",
    "limit_at_zero",
    "dc_gain",
    "steady_state_errors",
    "band_max",
    "percent_tracking_error_below",
    "percent_input_disturbance_below",
    "percent_output_disturbance_below",
    "percent_noise_above",
    "margins",
    "crossover_margins",
    "discrete_grid",
    "sampled_response",
    "bode_data",
    "step_info",
    "step_response",
    "check_band_ratio",
    "check_phase_margin",
    "check_crossover",
    "check_step",
    "step_checks",
    "check_step_nonlinear",
    "check_stable",
    "check_damping",
    "check_bandwidth",
]

#: Coefficients below this fraction of their polynomial's largest count as exact zeros.
ZERO_TOL = 1e-12


class UnstableLoopError(ValueError):
    """A steady-state or frequency answer was asked of a closed loop that is not stable."""


# ----------------------------------------------------------------- polynomials
def polynomial(coeffs) -> np.ndarray:
    """Descending coefficients as a float array with leading zeros removed (at least [0])."""
    arr = np.atleast_1d(np.asarray(coeffs, dtype=float)).ravel()
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"polynomial coefficients must be finite, got {arr}")
    nonzero = np.flatnonzero(arr)
    return arr[nonzero[0] :] if nonzero.size else np.zeros(1)


def poly_add(a, b) -> np.ndarray:
    """a(s) + b(s), descending coefficients."""
    a, b = polynomial(a), polynomial(b)
    n = max(a.size, b.size)
    return polynomial(np.pad(a, (n - a.size, 0)) + np.pad(b, (n - b.size, 0)))


def poly_sub(a, b) -> np.ndarray:
    """a(s) − b(s), descending coefficients."""
    return poly_add(a, -polynomial(b))


def poly_mul(*polys) -> np.ndarray:
    """The product of the polynomials, descending coefficients."""
    out = np.ones(1)
    for p in polys:
        out = np.polymul(out, polynomial(p))
    return polynomial(out)


def zeros_at_origin(p, tol: float = ZERO_TOL) -> int:
    """Number of roots at s = 0: trailing coefficients that are zero (relative to the largest)."""
    p = polynomial(p)
    scale = np.max(np.abs(p))
    if scale == 0:
        return p.size
    count = 0
    for c in p[::-1]:
        if abs(c) > tol * scale:
            break
        count += 1
    return count


def as_polynomials(G) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) descending coefficients of a SISO continuous-time transfer function or a number."""
    if np.isscalar(G) or (isinstance(G, np.ndarray) and G.size == 1):
        return polynomial([float(np.asarray(G).ravel()[0])]), np.ones(1)
    if not isinstance(G, control.TransferFunction):
        raise TypeError(f"expected a control.TransferFunction or a number, got {type(G).__name__}")
    if G.ninputs != 1 or G.noutputs != 1:
        raise ValueError(f"expected a SISO transfer function, got {G.noutputs}x{G.ninputs}")
    if G.dt not in (0, None):
        raise ValueError(f"expected a continuous-time transfer function, got dt = {G.dt}")
    den = polynomial(G.den[0][0])
    if not np.any(den):
        raise ValueError("transfer function has a zero denominator")
    return polynomial(G.num[0][0]), den


def tf(num, den) -> control.TransferFunction:
    """Continuous-time SISO transfer function from descending coefficients (validated)."""
    num, den = polynomial(num), polynomial(den)
    if not np.any(den):
        raise ValueError("denominator polynomial is zero")
    return control.tf(num, den)


def _pid_polynomials(kp, ki, kd, sigma, integrator: bool, rolloff: bool):
    """Numerator and denominator of k_p + k_i/s + k_d s/(σ s + 1) over s^[integrator] (σ s + 1)^[rolloff]."""
    den = np.ones(1)
    if integrator:
        den = poly_mul(den, [1.0, 0.0])
    if rolloff:
        den = poly_mul(den, [sigma, 1.0])
    num = poly_mul([kp], den)
    if integrator:
        num = poly_add(num, poly_mul([ki], [sigma, 1.0] if rolloff else [1.0]))
    derivative = poly_mul([kd, 0.0], [1.0, 0.0] if integrator else [1.0])
    num = poly_add(num, derivative)
    return num, den


def pid_tf(kp: float, ki: float = 0.0, kd: float = 0.0, sigma: float | None = None) -> control.TransferFunction:
    """k_p + k_i/s + k_d s/(σ s + 1) (ideal derivative when `sigma` is None), continuous time."""
    if sigma is not None and not sigma > 0:
        raise ValueError(f"sigma must be > 0 s, got {sigma}")
    return tf(*_pid_polynomials(kp, ki, kd, sigma, ki != 0, sigma is not None and kd != 0))


def _cancel_origin(num, den) -> control.TransferFunction:
    """num/den with common factors of s removed exactly."""
    num, den = polynomial(num), polynomial(den)
    common = min(zeros_at_origin(num), zeros_at_origin(den))
    if common:
        num, den = polynomial(num[:-common]), polynomial(den[:-common])
    return tf(num, den)


# ----------------------------------------------------------------- the loop
@dataclass(frozen=True)
class Loop:
    """The two-degree-of-freedom loop u = C_r r − C_y (y + n) + d_i, y = P u + d_o.

    Attributes
    ----------
    plant : P(s), from the plant input to the measured (controlled) output
    feedback : C_y(s), acting on the measurement
    reference : C_r(s), acting on the reference
    name : str
    """

    plant: control.TransferFunction
    feedback: control.TransferFunction
    reference: control.TransferFunction
    name: str = ""

    @classmethod
    def unity(cls, plant, controller, name: str = "") -> Loop:
        """Error feedback u = C (r − y): C_r = C_y = C."""
        return cls(_as_tf(plant), _as_tf(controller), _as_tf(controller), name)

    @classmethod
    def pid(
        cls,
        plant,
        kp: float,
        ki: float = 0.0,
        kd: float = 0.0,
        *,
        sigma: float | None = None,
        derivative_on: str = "measurement",
        prefilter=None,
        name: str = "",
    ) -> Loop:
        """PID with the derivative on the measurement (the text's choice) or on the error.

        With `prefilter` F(s), the reference path is F·C_r.
        """
        if derivative_on not in ("measurement", "error"):
            raise ValueError(f"derivative_on must be 'measurement' or 'error', got {derivative_on!r}")
        if sigma is not None and not sigma > 0:
            raise ValueError(f"sigma must be > 0 s, got {sigma}")
        flags = (ki != 0, sigma is not None and kd != 0)
        feedback = tf(*_pid_polynomials(kp, ki, kd, sigma, *flags))
        kd_reference = kd if derivative_on == "error" else 0.0
        # Same denominator on both paths, so N_Cy - N_Cr cancels exactly.
        reference = tf(*_pid_polynomials(kp, ki, kd_reference, sigma, *flags))
        if prefilter is not None:
            reference = _as_tf(prefilter) * reference
        return cls(_as_tf(plant), feedback, reference, name)

    # polynomial parts over one controller denominator
    def _parts(self):
        n_p, d_p = as_polynomials(self.plant)
        n_y, d_y = as_polynomials(self.feedback)
        n_r, d_r = as_polynomials(self.reference)
        if d_y.size == d_r.size and np.array_equal(d_y / d_y[0], d_r / d_r[0]):
            d_c = d_y
            n_r = n_r * (d_y[0] / d_r[0])
        else:
            d_c = poly_mul(d_y, d_r)
            n_y, n_r = poly_mul(n_y, d_r), poly_mul(n_r, d_y)
        return n_p, d_p, n_y, n_r, d_c

    def characteristic(self) -> np.ndarray:
        """Closed-loop characteristic polynomial D_P D_C + N_P N_Cy (descending)."""
        n_p, d_p, n_y, _, d_c = self._parts()
        return poly_add(poly_mul(d_p, d_c), poly_mul(n_p, n_y))

    def poles(self) -> np.ndarray:
        """Closed-loop poles (complex), sorted by real part."""
        roots = np.roots(self.characteristic())
        return roots[np.argsort(roots.real)]

    def is_stable(self) -> bool:
        """All closed-loop poles strictly in the left half plane."""
        return bool(np.all(self.poles().real < 0))

    def loop_gain(self) -> control.TransferFunction:
        """L(s) = P(s) C_y(s), the loop broken at the plant input."""
        n_p, d_p = as_polynomials(self.plant)
        n_y, d_y = as_polynomials(self.feedback)
        return _cancel_origin(poly_mul(n_p, n_y), poly_mul(d_p, d_y))

    def _closed(self, num) -> control.TransferFunction:
        return tf(num, self.characteristic())

    def reference_to_output(self) -> control.TransferFunction:
        """T_r = P C_r / (1 + P C_y)."""
        n_p, _, _, n_r, _ = self._parts()
        return self._closed(poly_mul(n_p, n_r))

    def reference_to_error(self) -> control.TransferFunction:
        """E/R = 1 − T_r = (D_P D_C + N_P (N_Cy − N_Cr)) / Δ, e = r − y."""
        n_p, d_p, n_y, n_r, d_c = self._parts()
        return self._closed(poly_add(poly_mul(d_p, d_c), poly_mul(n_p, poly_sub(n_y, n_r))))

    def input_disturbance_to_output(self) -> control.TransferFunction:
        """Y/D_i = P / (1 + P C_y)."""
        n_p, _, _, _, d_c = self._parts()
        return self._closed(poly_mul(n_p, d_c))

    def output_disturbance_to_output(self) -> control.TransferFunction:
        """Y/D_o = 1 / (1 + P C_y), the sensitivity S."""
        _, d_p, _, _, d_c = self._parts()
        return self._closed(poly_mul(d_p, d_c))

    def noise_to_output(self) -> control.TransferFunction:
        """Y/N = −P C_y / (1 + P C_y) = −T."""
        n_p, _, n_y, _, _ = self._parts()
        return self._closed(-poly_mul(n_p, n_y))

    def reference_to_input(self) -> control.TransferFunction:
        """U/R = C_r D_P / ... : the command a reference asks of the actuator."""
        _, d_p, _, n_r, _ = self._parts()
        return self._closed(poly_mul(d_p, n_r))

    def require_stable(self, what: str = "this answer") -> None:
        """Raise UnstableLoopError naming the right-half-plane poles unless the loop is stable."""
        poles = self.poles()
        bad = poles[poles.real >= 0]
        if bad.size:
            raise UnstableLoopError(
                f"{self.name or 'closed loop'} is not stable (poles "
                f"{np.array2string(bad, precision=4)} in the closed right half plane): "
                f"{what} does not exist"
            )


def _as_tf(G) -> control.TransferFunction:
    num, den = as_polynomials(G)
    return tf(num, den)


# ----------------------------------------------------------------- steady state
def limit_at_zero(num, den, power: int = 0) -> float:
    """lim_{s→0} N(s) / (D(s) s^power), exact: 0, a finite ratio, or ±inf.

    The sign of an infinite limit is the sign approached from s → 0⁺.
    """
    num, den = polynomial(num), polynomial(den)
    if not np.any(den):
        raise ValueError("denominator is zero")
    if not np.any(num):
        return 0.0
    zn, zd = zeros_at_origin(num), zeros_at_origin(den) + power
    ratio = num[num.size - 1 - zn] / den[den.size - 1 - zeros_at_origin(den)]
    if zn > zd:
        return 0.0
    if zn == zd:
        return float(ratio)
    return float(np.sign(ratio) * np.inf)


def dc_gain(G) -> float:
    """G(0), exact; ±inf for a pole at the origin."""
    return limit_at_zero(*as_polynomials(G))


def steady_state_errors(loop: Loop) -> dict:
    """System type and steady-state error e = r − y to unit step, ramp and parabola.

    The type is the number of zeros at s = 0 of E/R; the errors are
    lim s→0 of E/R · s / s^(k+1). Exact (``inf`` for an unbounded error).

    Raises
    ------
    UnstableLoopError
        If the closed loop is not stable (no steady state exists).
    """
    loop.require_stable("a steady-state error")
    num, den = as_polynomials(loop.reference_to_error())
    return {
        "type": zeros_at_origin(num),
        "ess_step": limit_at_zero(num, den, 0),
        "ess_ramp": limit_at_zero(num, den, 1),
        "ess_parabola": limit_at_zero(num, den, 2),
    }


# ----------------------------------------------------------------- frequency
def _magnitude(G, omega) -> np.ndarray:
    num, den = as_polynomials(G)
    s = 1j * np.asarray(omega, dtype=float)
    return np.abs(np.polyval(num, s) / np.polyval(den, s))


def band_max(G, low: float, high: float, points_per_decade: int = 400) -> tuple[float, float]:
    """Largest |G(jω)| for low ≤ ω ≤ high and the frequency where it occurs.

    `low` may be 0 (the DC limit is included) and `high` may be inf (the
    limit at infinity is included). Between, a logarithmic grid of
    `points_per_decade` points per decade, an interior peak refined by a
    bounded scalar search; an open end extends six decades beyond the
    slowest (fastest) pole or zero.
    """
    if not (0 <= low < high):
        raise ValueError(f"need 0 <= low < high, got low = {low}, high = {high}")
    num, den = as_polynomials(G)
    corners = np.abs(np.concatenate([np.roots(num), np.roots(den)]))
    corners = corners[corners > 0]
    slowest = corners.min() if corners.size else 1.0
    fastest = corners.max() if corners.size else 1.0
    lo = low if low > 0 else min(slowest, high) * 1e-6
    hi = high if np.isfinite(high) else max(fastest, lo) * 1e6
    decades = max(np.log10(hi / lo), 1e-3)
    grid = np.logspace(np.log10(lo), np.log10(hi), int(np.ceil(decades * points_per_decade)) + 1)
    mags = _magnitude(G, grid)
    best = int(np.argmax(mags))
    value, where = float(mags[best]), float(grid[best])
    if 0 < best < grid.size - 1:
        # Refine an interior peak between its grid neighbours.
        res = scipy.optimize.minimize_scalar(
            lambda lw: -_magnitude(G, 10.0**lw),
            method="bounded",
            bounds=(np.log10(grid[best - 1]), np.log10(grid[best + 1])),
            options={"xatol": 1e-12},
        )
        if -res.fun > value:
            value, where = float(-res.fun), float(10.0**res.x)
    if low == 0:
        at_zero = abs(limit_at_zero(num, den))
        if at_zero > value:
            value, where = at_zero, 0.0
    if not np.isfinite(high):
        at_inf = 0.0 if num.size < den.size else (np.inf if num.size > den.size else abs(num[0] / den[0]))
        if at_inf > value:
            value, where = float(at_inf), float(np.inf)
    return value, where


def percent_tracking_error_below(loop: Loop, omega: float) -> float:
    """100·max |E/R(jw)| for references with all frequency content below `omega` rad/s."""
    loop.require_stable("a tracking error")
    return 100.0 * band_max(loop.reference_to_error(), 0.0, omega)[0]


def percent_input_disturbance_below(loop: Loop, omega: float) -> float:
    """100·max |Y/D_i(jw)| below `omega`: the part of an input disturbance seen at the output."""
    loop.require_stable("a disturbance response")
    return 100.0 * band_max(loop.input_disturbance_to_output(), 0.0, omega)[0]


def percent_output_disturbance_below(loop: Loop, omega: float) -> float:
    """100·max |S(jw)| below `omega`: the part of an output disturbance left in the output."""
    loop.require_stable("a disturbance response")
    return 100.0 * band_max(loop.output_disturbance_to_output(), 0.0, omega)[0]


def percent_noise_above(loop: Loop, omega: float) -> float:
    """100·max |T(jw)| above `omega`: the part of measurement noise that reaches the output."""
    loop.require_stable("a noise response")
    return 100.0 * band_max(loop.noise_to_output(), omega, np.inf)[0]


def crossover_margins(response, omega, values=None) -> dict:
    """Gain and phase margins from a loop's frequency response, crossings found on a grid and refined.

    The algorithm of python-control's `stability_margins` for frequency data, applied to the exact
    response instead of a spline through samples of it: the phase crossovers are the sign changes of
    Im L on the grid where Re L < 0 (and ω = 0 when the grid starts there and L(0) < 0), the gain
    crossovers those of |L| − 1, each refined by `scipy.optimize.brentq` on `response`; of several,
    the gain margin nearest 1 and the phase margin smallest in magnitude. A pair of crossings
    between two grid points (a resonance narrower than the grid) is missed, as in python-control.

    response : callable, omega (F,) rad/s -> L at omega, complex (F,)
    omega : (F,) rad/s, increasing
    values : response(omega) when already computed

    Returns the dict of `margins`.
    """
    omega = np.asarray(omega, dtype=float)
    values = response(omega) if values is None else np.asarray(values)

    def at(w):
        return complex(response(np.array([w]))[0])

    def crossings(f, keep=lambda w: True):
        signs = np.sign(f(values))
        found = []
        for i in np.flatnonzero(signs[:-1] * signs[1:] < 0):
            w = scipy.optimize.brentq(lambda w: f(np.array([at(w)]))[0], omega[i], omega[i + 1], xtol=1e-14)
            if keep(w):
                found.append(w)
        found.extend(float(omega[i]) for i in np.flatnonzero(signs == 0) if keep(omega[i]))
        return np.sort(np.array(found, dtype=float))

    w_180 = crossings(np.imag, keep=lambda w: at(w).real < 0)
    if omega[0] == 0 and values[0].real < 0 and 0.0 not in w_180:
        w_180 = np.concatenate([[0.0], w_180])  # negative at DC: the phase is -180 there
    w_c = crossings(lambda v: np.abs(v) - 1.0)
    out = {"gm": np.inf, "gm_db": np.inf, "pm_deg": np.inf, "phase_crossover": np.nan, "gain_crossover": np.nan}
    if w_180.size:
        with np.errstate(divide="ignore"):
            gm = 1.0 / np.abs([at(w) for w in w_180])
            i = int(np.argmin(np.abs(np.log(gm))))
        if np.isfinite(gm[i]):
            out.update(gm=float(gm[i]), gm_db=float(20 * np.log10(gm[i])), phase_crossover=float(w_180[i]))
    if w_c.size:
        pm = np.remainder(np.angle([at(w) for w in w_c], deg=True), 360.0) - 180.0
        i = int(np.argmin(np.abs(pm)))
        out.update(pm_deg=float(pm[i]), gain_crossover=float(w_c[i]))
    return out


#: Poles and zeros with |ln z| below this fraction of π (a time constant over 3e5 samples) count as at
#: z = 1 in sampled margins: an integrator computed to rounding, not a feature of the loop to resolve.
SLOWEST = 1e-6


def sampled_response(A, B, C, D, sample_period: float, omega) -> np.ndarray:
    """C (zI − A)⁻¹ B + D at z = e^{jωTs} of a SISO sampled state space: complex (F,) at omega (F,) rad/s."""
    omega = np.asarray(omega, dtype=float)
    z = np.exp(1j * omega * sample_period)
    rhs = np.broadcast_to(np.asarray(B, dtype=complex), (len(z), *np.shape(B)))
    return (C @ np.linalg.solve(z[:, None, None] * np.eye(np.shape(A)[0]) - A, rhs))[:, 0, 0] + np.asarray(D)[0, 0]


def discrete_grid(poles_zeros, sample_period: float, points_per_decade: int = 200) -> np.ndarray:
    """A grid (rad/s) below the Nyquist frequency for a sampled loop's crossings.

    0; a logarithmic grid from a decade below the slowest pole or zero (|ln z| / Ts; those below
    `SLOWEST` of the Nyquist frequency count as at z = 1 and are left out) to 0.999 of the Nyquist
    frequency π/Ts; and around each pole or zero, at both |ln z| / Ts and |∠z| / Ts (where e^{jωTs}
    passes nearest to it), offsets from 1e-6 to 0.5 of that frequency on either side, log-spaced:
    a lightly damped mode's resonance, with its pair of crossings far narrower than the
    logarithmic grid's step, is resolved.
    """
    nyquist = np.pi / sample_period
    z = np.asarray(poles_zeros, dtype=complex)
    z = z[np.abs(z) > 1e-300]
    features = np.concatenate([np.abs(np.log(z)), np.abs(np.angle(z))]) / sample_period
    features = features[features > SLOWEST * nyquist]
    slowest = min(features.min(), nyquist) if features.size else 1e-3 * nyquist
    lo, hi = min(slowest, 1e-3 * nyquist) / 10, 0.999 * nyquist
    grid = np.logspace(np.log10(lo), np.log10(hi), int(np.ceil(np.log10(hi / lo) * points_per_decade)) + 1)
    offsets = np.geomspace(1e-6, 0.5, 60)
    local = (features[:, None] * (1 + np.concatenate([-offsets, [0.0], offsets]))[None]).ravel()
    local = local[(local > lo) & (local < hi)]
    return np.concatenate([[0.0], np.unique(np.concatenate([grid, local]))])


def margins(L) -> dict:
    """Gain and phase margins of a loop gain, the one margins computation.

    L : a continuous or discrete SISO transfer function or state-space system (closed loop 1 + L = 0).
    Continuous loops: python-control's `stability_margins` (its exact polynomial method). Sampled
    loops: `crossover_margins` of the exact L(e^{jωTs}) on `discrete_grid`. python-control falls back
    to a spline through frequency samples there: 100 times slower, and on the studies' lightly damped
    loops (the crane's swing, a PID's integrator) it reported crossings that are not there (a phase
    margin of 0.0004° at 1.5e-4 rad/s on the crane's PD inner loop, whose crossover is at 0.65 rad/s);
    tests/designs/test_analysis.py holds these margins to a refined dense scan to 1e-5.

    Returns
    -------
    dict with gm (ratio, inf when the phase never crosses −180°), gm_db,
    pm_deg, phase_crossover and gain_crossover (rad/s; nan when absent).
    """
    if L.isdtime(strict=True):
        if L.ninputs != 1 or L.noutputs != 1:
            raise ValueError(f"margins need a SISO loop gain, got {L.noutputs}x{L.ninputs}")
        ts = float(L.dt)
        if isinstance(L, control.TransferFunction):
            num, den = np.asarray(L.num[0][0], dtype=float), np.asarray(L.den[0][0], dtype=float)

            def response(w):
                z = np.exp(1j * w * ts)
                return np.polyval(num, z) / np.polyval(den, z)

            poles = np.roots(den)
            features = np.concatenate([np.roots(num), poles])
        else:
            A, B, C, D = (np.asarray(m, dtype=float) for m in (L.A, L.B, L.C, L.D))

            def response(w):
                return sampled_response(A, B, C, D, ts, w)

            poles = np.linalg.eigvals(A)
            # Transmission zeros: the finite generalized eigenvalues of ([[A, B], [C, D]], diag(I, 0)).
            n = A.shape[0]
            pencil = np.zeros((n + 1, n + 1))
            pencil[:n, :n] = np.eye(n)
            with np.errstate(divide="ignore", invalid="ignore"):
                zeros = scipy.linalg.eigvals(np.block([[A, B], [C, D]]), pencil)
            features = np.concatenate([poles, zeros[np.isfinite(zeros)]])
        grid = discrete_grid(features, ts)
        near_one = np.abs(poles - 1) < SLOWEST * np.pi  # |ln z| ≈ |z − 1| there; ln 0 is not asked for
        if np.any(near_one):
            grid = grid[1:]  # a pole at z = 1 (an integrator): L(1) is infinite, not a phase crossover
        return crossover_margins(response, grid)
    gm, pm, _, w_pc, w_gc, _ = control.stability_margins(L)
    gm = float(gm)
    return {
        "gm": gm,
        "gm_db": float(20 * np.log10(gm)) if np.isfinite(gm) and gm > 0 else float(np.inf),
        "pm_deg": float(pm),
        "phase_crossover": float(w_pc),
        "gain_crossover": float(w_gc),
    }


def bode_data(G, omega) -> dict:
    """Magnitude (absolute) and unwrapped phase (deg) of G at the frequencies `omega` (rad/s)."""
    omega = np.asarray(omega, dtype=float)
    num, den = as_polynomials(G)
    resp = np.polyval(num, 1j * omega) / np.polyval(den, 1j * omega)
    return {"omega": omega, "magnitude": np.abs(resp), "phase_deg": np.degrees(np.unwrap(np.angle(resp)))}


# ----------------------------------------------------------------- spec checks
@dataclass(frozen=True)
class SpecCheck:
    """One requirement and whether the design meets it.

    Attributes
    ----------
    spec : what is required, in words
    met : bool
    value : what the design achieves (SI; degrees only where the name says deg)
    required : the bound it is compared with
    frequency : rad/s where the value was found (None for time-domain specs)
    """

    spec: str
    met: bool
    value: float
    required: float
    frequency: float | None = None
    detail: str = field(default="")

    def as_dict(self) -> dict:
        return asdict(self)


def check_band_ratio(new, old, low: float, high: float, factor: float, what: str) -> SpecCheck:
    """|new(jω)| ≤ |old(jω)| / factor for all ω in [low, high] (grid as in `band_max`)."""
    num_n, den_n = as_polynomials(new)
    num_o, den_o = as_polynomials(old)
    ratio = tf(poly_mul(num_n, den_o), poly_mul(den_n, num_o))
    worst, where = band_max(ratio, low, high)
    band = f"below {high:g} rad/s" if low == 0 else f"above {low:g} rad/s"
    return SpecCheck(
        f"{what} {band} improved {factor:g}x",
        bool(worst <= 1.0 / factor + 1e-12),
        float(1.0 / worst) if worst > 0 else float(np.inf),
        float(factor),
        where,
        "value: smallest improvement factor old/new in the band",
    )


def check_phase_margin(
    L, minimum_deg: float | None = None, target_deg: float | None = None, tolerance_deg: float = 5.0
) -> SpecCheck:
    """PM ≥ `minimum_deg`, or |PM − target| ≤ tolerance when `target_deg` is given."""
    m = margins(L)
    if target_deg is not None:
        return SpecCheck(
            f"phase margin about {target_deg:g} deg (±{tolerance_deg:g})",
            bool(abs(m["pm_deg"] - target_deg) <= tolerance_deg),
            m["pm_deg"],
            target_deg,
            m["gain_crossover"],
        )
    if minimum_deg is None:
        raise ValueError("check_phase_margin needs minimum_deg or target_deg; got neither")
    return SpecCheck(
        f"phase margin >= {minimum_deg:g} deg",
        bool(m["pm_deg"] >= minimum_deg),
        m["pm_deg"],
        minimum_deg,
        m["gain_crossover"],
    )


def check_crossover(L, omega: float, rel_tol: float = 0.05) -> SpecCheck:
    """Gain crossover within `rel_tol` of `omega` rad/s."""
    w = margins(L)["gain_crossover"]
    return SpecCheck(
        f"crossover at {omega:g} rad/s (±{100 * rel_tol:g} %)",
        bool(np.isfinite(w) and abs(w - omega) <= rel_tol * omega),
        w,
        omega,
        w,
    )


def check_damping(loop: Loop, zeta_min: float) -> SpecCheck:
    """Every closed-loop pole damped at least `zeta_min` (value: the least damped pole's ζ)."""
    poles = loop.poles()
    zeta = float(np.min(-poles.real / np.abs(poles)))
    return SpecCheck(f"every closed-loop pole damped (zeta >= {zeta_min:g})", zeta >= zeta_min, zeta, zeta_min)


def check_bandwidth(T, bandwidth: float, rel_tol: float = 0.2) -> SpecCheck:
    """Closed-loop −3 dB bandwidth of T (1/√2 of its DC gain) within `rel_tol` of `bandwidth` rad/s."""
    value = float(control.bandwidth(T, 20 * np.log10(1 / np.sqrt(2))))
    return SpecCheck(
        f"closed-loop bandwidth about {bandwidth:g} rad/s (±{100 * rel_tol:g} %)",
        bool(abs(value - bandwidth) <= rel_tol * bandwidth),
        value,
        bandwidth,
    )


def check_stable(loop: Loop) -> SpecCheck:
    """All closed-loop poles in the open left half plane (value: largest real part)."""
    worst = float(np.max(loop.poles().real))
    return SpecCheck("closed loop stable", worst < 0, worst, 0.0)


def step_response(T, times) -> np.ndarray:
    """Unit-step response of a stable SISO T at `times` (s), exact by modal decomposition.

    y(t) = D + C V diag((e^{λt} − 1)/λ) V⁻¹ B; falls back to python-control's
    forced_response when the state matrix is not safely diagonalizable.
    """
    times = np.asarray(times, dtype=float)
    sys = control.tf2ss(T)
    A, B, C, D = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (sys.A, sys.B, sys.C, sys.D))
    if A.size == 0:
        return np.full(times.shape, float(D[0, 0]))
    lam, V = np.linalg.eig(A)
    if np.linalg.cond(V) > 1e8 or np.any(np.abs(lam) < 1e-14):
        return np.asarray(control.step_response(T, times).outputs, dtype=float).ravel()
    left = (C @ V).ravel()
    right = np.linalg.solve(V, B).ravel()
    modes = np.expm1(np.outer(times, lam)) / lam
    return (modes @ (left * right)).real + D[0, 0]


def step_info(T, settling_threshold: float = 0.02) -> dict:
    """python-control's step_info on a time grid long enough for the slowest pole to settle.

    The grid runs to 10 time constants of the slowest pole (at most 10⁵ s)
    with 20 000 points, the response computed exactly (`step_response`).
    """
    poles = np.roots(as_polynomials(T)[1])
    if poles.size == 0:
        return control.step_info(T, SettlingTimeThreshold=settling_threshold)
    if np.any(poles.real >= 0):
        raise UnstableLoopError(f"step response of an unstable system (poles {poles})")
    end = min(10.0 / np.min(-poles.real), 1e5)
    times = np.linspace(0.0, end, 20001)
    return control.step_info(
        step_response(T, times), T=times, yfinal=dc_gain(T), SettlingTimeThreshold=settling_threshold
    )


def check_step(
    T,
    *,
    amplitude: float = 1.0,
    rise_time: float | None = None,
    settling_time: float | None = None,
    overshoot_percent: float | None = None,
    steady_state_error_percent: float | None = None,
    reference_dc: float = 1.0,
    settling_threshold: float = 0.02,
) -> list[SpecCheck]:
    """Step-response specs of a closed loop T (reference → output), python-control's step_info.

    Rise time 10–90 %, settling to `settling_threshold` of the final value,
    overshoot relative to the final value, steady-state error relative to
    the commanded value (`reference_dc` = 1 for a unit-gain goal).
    """
    return step_checks(
        step_info(T, settling_threshold),
        dc_gain(T),
        reference_dc=reference_dc,
        rise_time=rise_time,
        settling_time=settling_time,
        overshoot_percent=overshoot_percent,
        steady_state_error_percent=steady_state_error_percent,
        settling_threshold=settling_threshold,
    )


def step_checks(
    info: dict,
    final: float,
    *,
    reference_dc: float = 1.0,
    rise_time: float | None = None,
    settling_time: float | None = None,
    overshoot_percent: float | None = None,
    steady_state_error_percent: float | None = None,
    settling_threshold: float = 0.02,
    label_suffix: str = "",
) -> list[SpecCheck]:
    """The step specs asked for, judged on a `control.step_info` result and the final value.

    The one place that turns step-response numbers into `SpecCheck`s, for a
    linear closed loop (`check_step`) and for a nonlinear simulation
    (`check_step_nonlinear`); `label_suffix` tells them apart in the labels.
    """
    out = []
    if rise_time is not None:
        out.append(
            SpecCheck(
                f"rise time < {rise_time:g} s{label_suffix}", info["RiseTime"] < rise_time, info["RiseTime"], rise_time
            )
        )
    if settling_time is not None:
        out.append(
            SpecCheck(
                f"settling time ({100 * settling_threshold:g} %) < {settling_time:g} s{label_suffix}",
                info["SettlingTime"] < settling_time,
                info["SettlingTime"],
                settling_time,
            )
        )
    if overshoot_percent is not None:
        out.append(
            SpecCheck(
                f"overshoot < {overshoot_percent:g} %{label_suffix}",
                info["Overshoot"] < overshoot_percent,
                info["Overshoot"],
                overshoot_percent,
            )
        )
    if steady_state_error_percent is not None:
        err = 100 * abs(reference_dc - final) / abs(reference_dc)
        out.append(
            SpecCheck(
                f"steady-state error < {steady_state_error_percent:g} %{label_suffix}",
                err < steady_state_error_percent,
                err,
                steady_state_error_percent,
            )
        )
    return out


def check_step_nonlinear(
    plant, block, step: float, tracked: str, *, duration: float = 10.0, threshold: float = 0.02, **specs
) -> list[SpecCheck]:
    """Step specs of the nonlinear closed loop (one `models.simulate_closed_loop` run), and the actuator.

    The loop starts at the plant's standard equilibrium and the reference steps
    by `step` on `tracked` at t = 0; `specs` are the keywords of `step_checks`
    (rise_time, settling_time, overshoot_percent, steady_state_error_percent).
    The last check says whether the command stayed within the actuator limit.
    """
    import models

    x0, _ = plant.equilibrium()
    y0 = x0[plant.coordinate_names.index(tracked)]
    res = models.simulate_closed_loop(plant, block, y0 + step, duration, x0=x0)
    y = (res.state(tracked) - y0) / step
    info = control.step_info(y, T=res.t, yfinal=y[-1], SettlingTimeThreshold=threshold)
    checks = step_checks(info, y[-1], settling_threshold=threshold, label_suffix=" (nonlinear)", **specs)
    peak = float(np.max(np.abs(res.u)))
    checks.append(
        SpecCheck(
            f"command within the {plant.input_limit[0]:g} actuator limit",
            peak <= plant.input_limit[0] * (1 + 1e-12),
            peak,
            float(plant.input_limit[0]),
        )
    )
    return checks
