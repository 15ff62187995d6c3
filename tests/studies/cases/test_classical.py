"""Every plant's homework record against an independent computation.

Closed forms are derived here from the plants' parameters; frequency and
time answers are recomputed with python-control's own interconnections
(feedback, margins, frequency responses, step_info).
"""

import control
import numpy as np
import pytest
import scipy.optimize
from case_designs import DESIGNED, classical_answers, classical_controllers

import models
import studies
from studies import homework

ZETA = homework.ZETA


def _tf(record, prefix=""):
    return control.tf(record[f"{prefix}num"], record[f"{prefix}den"])


def _two_dof(P, kp, ki, kd, sigma=None):
    """T = P C_r/(1 + P C_y) and E/R = 1 − T with python-control, derivative on the measurement."""
    s = control.tf([1, 0], [1])
    deriv = kd * s if sigma is None else kd * s / (sigma * s + 1)
    C_r = kp + (ki / s if ki else 0)
    C_y = C_r + deriv
    return control.feedback(P * C_y, 1) * C_r / C_y


def _mag(G, w):
    return np.abs(control.frequency_response(G, np.atleast_1d(w)).magnitude).ravel()


@pytest.fixture(scope="module")
def arm_answers():
    return classical_answers("arm")


def test_arm_8_closed_forms(arm_answers):
    a, arm = arm_answers, models.get("arm")
    m, ell, g, b = (arm.params[k] for k in ("m", "ell", "g", "b"))
    b0, a1 = 3 / (m * ell**2), 3 * b / (m * ell**2)
    bound = 1 - m * g * ell / 2
    kp = bound / np.deg2rad(50)
    wn = np.sqrt(b0 * kp)
    assert a["I.8(b)"]["bound"] == pytest.approx(bound, rel=1e-9)
    assert a["I.8(c)"]["kp"] == pytest.approx(kp, rel=1e-9)
    assert a["I.8(d)"]["wn"] == pytest.approx(wn, rel=1e-9)
    assert a["I.8(d)"]["kd"] == pytest.approx((2 * ZETA * wn - a1) / b0, rel=1e-9)
    np.testing.assert_allclose(
        sorted(a["I.8(e)"]["poles"], key=lambda p: p.imag),
        sorted(np.roots([1, 2 * ZETA * wn, wn**2]), key=lambda p: p.imag),
        rtol=1e-9,
    )


def test_arm_10_types_and_errors(arm_answers):
    a = arm_answers
    kp, kd, ki = a["I.8(c)"]["kp"], a["I.8(d)"]["kd"], a["I.10(d)"]["ki"]
    b0, a1 = 66.6666667, 0.6666667
    r = a["I.10(a)"]
    assert (r["type"], r["ess_step"], r["ess_parabola"]) == (1, 0.0, np.inf)
    assert r["ess_ramp"] == pytest.approx((a1 + b0 * kd) / (b0 * kp), rel=1e-6)
    assert (r["type_pid"], r["ess_ramp_pid"]) == (2, 0.0)
    assert r["ess_parabola_pid"] == pytest.approx((a1 + b0 * kd) / (b0 * ki), rel=1e-6)
    assert a["I.10(b)"]["ess_input_disturbance"] == pytest.approx(1 / kp, rel=1e-6)
    assert a["I.10(b)"]["ess_input_disturbance_pid"] == 0.0
    # The k_i locus: every pole keeps ζ >= 0.9·0.707, recomputed from the closed loop.
    T = _two_dof(control.tf([b0], [1, a1, 0]), kp, ki, kd)
    poles = control.poles(control.minreal(T, verbose=False))
    assert np.all(-poles.real / np.abs(poles) >= 0.9 * ZETA - 1e-6)


def test_arm_13_frequency_answers(arm_answers):
    a, arm = arm_answers, models.get("arm")
    G = arm.linearize().tf("theta", "tau")
    kp, kd, ki = a["I.8(c)"]["kp"], a["I.8(d)"]["kd"], a["I.10(d)"]["ki"]
    s = control.tf([1, 0], [1])
    C_y = kp + ki / s + kd * s / (0.05 * s + 1)
    gm, pm, _, _, wc, _ = control.stability_margins(G * C_y)
    assert a["I.13"]["pm_deg_pid"] == pytest.approx(pm, rel=1e-6)
    assert a["I.13"]["crossover_pid"] == pytest.approx(wc, rel=1e-6)
    T = _two_dof(G, kp, ki, kd, sigma=0.05)
    low = np.logspace(-5, np.log10(0.4), 2000)
    assert a["I.13(a)"]["tracking_error_percent"] == pytest.approx(100 * np.max(_mag(1 - T, low)), rel=1e-4)
    high = np.logspace(2, 6, 2000)
    noise = control.feedback(G * C_y, 1)
    assert a["I.13(d)"]["noise_percent"] == pytest.approx(100 * np.max(_mag(noise, high)), rel=1e-4)
    disturbance = control.feedback(G, C_y)
    assert a["I.13(c)"]["input_disturbance_percent"] == pytest.approx(
        100 * np.max(_mag(disturbance, np.logspace(-6, -2, 2000))), rel=1e-4
    )
    assert a["I.13(b)"]["ess_ramp"] == 0.0  # PID on a type-1 plant: type 2


def test_arm_14_specs_are_met_and_true(arm_answers):
    rec = arm_answers["I.14"]
    assert all(s["met"] for s in rec["specs"]), [s for s in rec["specs"] if not s["met"]]
    gm, pm, _, _, wc, _ = control.stability_margins(
        _tf(rec, "C_")
        * models.get("arm").linearize().tf("theta", "tau")
        * _pd_dirty(arm_answers["I.8(c)"]["kp"], arm_answers["I.8(d)"]["kd"])
    )
    assert pm == pytest.approx(60.0, abs=0.5)
    assert rec["overshoot_percent_with_prefilter"] < rec["overshoot_percent_without_prefilter"]


def _pd_dirty(kp, kd, sigma=0.05):
    s = control.tf([1, 0], [1])
    return kp + kd * s / (sigma * s + 1)


def test_pendulum_8_closed_forms():
    a, p = classical_answers("pendulum"), models.get("pendulum")
    m1, m2, ell, g = (p.params[k] for k in ("m1", "m2", "ell", "g"))
    b0, a0 = -1 / (m2 * ell), -(m1 + m2) * g / (m2 * ell)
    a_th = a["II.8(d)"]["step"]
    kp = -5.0 / a_th
    wn = np.sqrt(a0 + b0 * kp)
    assert a["II.8(d)"]["kp"] == pytest.approx(kp, rel=1e-9)
    assert a["II.8(e)"]["wn"] == pytest.approx(wn, rel=1e-9)
    assert a["II.8(e)"]["kd"] == pytest.approx(2 * ZETA * wn / b0, rel=1e-9)
    K = b0 * kp / (a0 + b0 * kp)
    assert a["II.8(f)"]["dc_gain"] == pytest.approx(K, rel=1e-9)
    kpz = a_th / 2.0
    wnz = np.sqrt(K * g * kpz)
    assert a["II.8(h)"]["kp"] == pytest.approx(kpz, rel=1e-9)
    assert a["II.8(i)"]["wn"] == pytest.approx(wnz, rel=1e-9)
    assert a["II.8(i)"]["kd"] == pytest.approx(2 * ZETA * wnz / (K * g), rel=1e-9)
    assert wn / wnz == pytest.approx(homework.SEPARATION)
    # Full linearization under u = kp_θ(kp_z(r − z) − kd_z ż − θ) − kd_θ θ̇, written out by hand.
    lin = p.linearize()
    kdz, kdt = a["II.8(i)"]["kd"], a["II.8(e)"]["kd"]
    K_row = np.array([kp * kpz, kp, kp * kdz, kdt])
    poles = np.linalg.eigvals(lin.A - lin.B @ K_row[None, :])
    np.testing.assert_allclose(np.sort_complex(a["II.8(j)"]["full_poles"]), np.sort_complex(poles), rtol=1e-8)
    assert a["II.13(b)"]["ess"] == pytest.approx(2.0 * (1 - K), rel=1e-9)


def test_satellite_8_and_10_closed_forms():
    a, p = classical_answers("satellite"), models.get("satellite")
    Js, Jp, k, b = (p.params[n] for n in ("Js", "Jp", "k", "b"))
    a_th = a["III.8(b)"]["step"]
    kp = 5.0 / a_th
    assert a["III.8(b)"]["kp"] == pytest.approx(kp, rel=1e-9)
    wn = np.sqrt(k / Js + kp / Js)
    assert a["III.8(d)"]["wn"] == pytest.approx(wn, rel=1e-9)
    assert a["III.8(d)"]["kd"] == pytest.approx((2 * ZETA * wn - b / Js) * Js, rel=1e-9)
    K = (kp / Js) / (k / Js + kp / Js)
    assert a["III.8(e)"]["dc_gain"] == pytest.approx(K, rel=1e-9)
    kpp = a_th / np.deg2rad(30)
    assert a["III.8(g)"]["kp"] == pytest.approx(kpp, rel=1e-9)
    # Outer P loop on K (b s + k)/(J_p s² + b s + k): DC gain K kp/(1 + K kp).
    assert a["III.8(h)"]["dc_gain"] == pytest.approx(K * kpp / (1 + K * kpp), rel=1e-9)
    # III.10(b): θ per unit ψ through d = (b s + k)/(J_s s² + b s + k) ψ, with PD: S(0) W(0) = k/(k + kp).
    assert a["III.10(b)"]["theta_per_psi"] == pytest.approx(k / (k + kp), rel=1e-9)
    assert a["III.10(b)"]["theta_per_psi_pid"] == 0.0
    assert all(s["met"] for s in a["III.14"]["specs"])


def test_uuv_8_10_closed_forms():
    a, p = classical_answers("uuv"), models.get("uuv")
    J, m, L, b, g = (p.params[n] for n in ("J", "m", "L", "b", "g"))
    kp = 50.0 / np.deg2rad(30)
    wn = np.sqrt((m * g * L + kp) / J)
    assert a["IV.8(b)"]["kp"] == pytest.approx(kp, rel=1e-9)
    assert a["IV.8(c)"]["wn"] == pytest.approx(wn, rel=1e-9)
    assert a["IV.8(c)"]["kd"] == pytest.approx(2 * 0.7 * wn * J - b, rel=1e-9)
    assert a["IV.10(a)"]["type"] == 0 and a["IV.10(a)"]["type_pid"] == 1
    assert a["IV.10(a)"]["ess_step"] == pytest.approx(m * g * L / (m * g * L + kp), rel=1e-9)
    assert a["IV.10(b)"]["ess_input_disturbance"] == pytest.approx(1 / (m * g * L + kp), rel=1e-9)


def test_uuv_11_lead_lag_meets_its_specs():
    a = classical_answers("uuv")
    assert all(s["met"] for s in a["IV.11(d)"]["specs"]), a["IV.11(d)"]["specs"]
    # The dominant pair sits where it was placed: closed-loop poles of 1 + C G recomputed here.
    G = models.get("uuv").linearize().tf("phi", "tau")
    rec = a["IV.11(c)"]
    C = (
        rec["gain"]
        * control.tf([1, rec["zero"]], [1, rec["pole"]])
        * control.tf([1, rec["lag_zero"]], [1, rec["lag_pole"]])
    )
    poles = control.poles(control.feedback(C * G, 1))
    target = -0.85 * 5 + 1j * 5 * np.sqrt(1 - 0.85**2)
    assert np.min(np.abs(poles - target)) < 1e-6
    assert control.dcgain(C * G) == pytest.approx(19.0, rel=1e-9)


def test_uuv_13_phases_and_final_design():
    a, p = classical_answers("uuv"), models.get("uuv")
    G = p.linearize().tf("phi", "tau")
    jw = 2j
    g = complex(control.evalfr(G, jw))
    # (a) D = 1/s: PM = 180° + ∠G(j2) − 90°; (b) PI zero at 0.2: + atan(2/0.2).
    pm_a = 180 + np.degrees(np.angle(g)) - 90
    pm_a = (pm_a + 180) % 360 - 180
    assert a["IV.13(a)"]["pm_deg"] == pytest.approx(pm_a, abs=1e-6)
    assert a["IV.13(b)"]["pm_deg"] == pytest.approx(pm_a + np.degrees(np.arctan(10.0)), abs=1e-6)
    J, m, L, gr = (p.params[n] for n in ("J", "m", "L", "g"))
    assert a["IV.13(d)"]["notch_frequency"] == pytest.approx(np.sqrt(m * gr * L / J))
    C = _tf(a["IV.13(e)"], "C_")
    gm, pm, _, _, wc, _ = control.stability_margins(C * G)
    assert wc == pytest.approx(2.0, rel=1e-6) and pm == pytest.approx(60.0, abs=1e-6)
    specs = {s["spec"]: s for s in a["IV.13(e)"]["specs"]}
    damping = specs.pop("every closed-loop pole damped (zeta >= 0.1)")
    assert all(s["met"] for s in specs.values())
    # The notch cancels the roll mode, which keeps about its open-loop damping b/(2 √(J m g L)).
    b = p.params["b"]
    assert not damping["met"] and damping["value"] == pytest.approx(b / (2 * np.sqrt(J * m * gr * L)), rel=0.05)


def test_ballbeam_8_10_13():
    a, p = classical_answers("ballbeam"), models.get("ballbeam")
    m1, m2, ell, g = (p.params[k] for k in ("m1", "m2", "ell", "g"))
    bound = 15.0 - (m1 + m2 / 2) * g
    assert a["V.8(c)"]["bound"] == pytest.approx(bound, rel=1e-9)
    a_th = a["V.8(d)"]["step"]
    assert a["V.8(d)"]["kp"] == pytest.approx(bound / a_th, rel=1e-9)
    assert a["V.8(h)"]["kp"] == pytest.approx(-a_th / 0.25, rel=1e-9)  # z/θ = −g/s²: negative gain
    # Outer loop input disturbance (on θ): z offset 1/kp_z under PD, none with the integrator.
    assert a["V.10(c)"]["ess_input_disturbance"] == pytest.approx(1 / a["V.8(h)"]["kp"], rel=1e-9)
    assert a["V.10(d)"]["ki"] < 0
    # V.13(b): the lead-lag holds the angle within 1 degree under 13.2 N: |13.2 / C(0)|.
    C = _tf(a["V.13(b)"], "C_")
    assert 13.2 / abs(control.dcgain(C)) == pytest.approx(a["V.13(b)"]["angle_error_lead_lag"], rel=1e-9)
    assert a["V.13(b)"]["angle_error_lead_lag"] < 0.0175
    gm, pm, _, _, wc, _ = control.stability_margins(_tf(a["V.13(c)"], "C_") * control.tf([-g], [1, 0, 0]))
    assert wc == pytest.approx(a["V.13(c)"]["crossover_target"], rel=1e-6)
    assert all(s["met"] for key in ("V.13(a)", "V.13(b)", "V.13(c)") for s in a[key]["specs"])


def test_crane_8_10_13():
    a, p = classical_answers("crane1"), models.get("crane1")
    mc, m, ell, g = (p.params[k] for k in ("mc", "m", "ell", "g"))
    zeta = -np.log(0.5) / np.sqrt(np.pi**2 + np.log(0.5) ** 2)
    assert a["VI.8(c)"]["zeta"] == pytest.approx(zeta, rel=1e-12)
    # The inner closed loop rises 10 % -> 90 % in 1 s: the analytic step response crosses both levels.
    wn = a["VI.8(c)"]["wn"]
    wd = wn * np.sqrt(1 - zeta**2)
    step = lambda t: 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / np.sqrt(1 - zeta**2) * np.sin(wd * t))
    t10 = scipy.optimize.brentq(lambda t: step(t) - 0.1, 1e-6, 1.0 / wn)
    t90 = scipy.optimize.brentq(lambda t: step(t) - 0.9, t10, np.pi / wd)
    assert t90 - t10 == pytest.approx(1.0, abs=2e-3)
    a0 = (mc + m) * g / (mc * ell)
    assert a["VI.8(e)"]["dc_gain"] == pytest.approx(1 - a0 / wn**2, rel=1e-9)
    # VI.8(g)-(h): 1 + K (−(ℓ s² + g)/s²)(k_p + k_d s) = 0 has the pair at ω_n = 0.45, ζ = 0.35.
    K, kp, kd = a["VI.8(e)"]["dc_gain"], a["VI.8(g)"]["kp"], a["VI.8(g)"]["kd"]
    char = np.polyadd([1, 0, 0], np.polymul([-K * ell, 0, -K * g], [kd, kp]))
    roots = np.roots(char)
    assert np.min(np.abs(roots - (-0.35 * 0.45 + 1j * 0.45 * np.sqrt(1 - 0.35**2)))) < 1e-9
    assert a["VI.10(a)"]["type"] == 2 and a["VI.10(a)"]["type_pid"] == 3
    assert a["VI.10(b)"]["x_per_rad"] == pytest.approx(1 / kp, rel=1e-9)
    inner = _tf(a["VI.13(a)"], "C_") * control.tf([-1 / (mc * ell)], [1, 0, a0])
    _, pm, _, _, wc, _ = control.stability_margins(inner)
    assert pm == pytest.approx(25.0, abs=1e-6) and wc == pytest.approx(a["VI.13(a)"]["crossover_target"], rel=1e-6)
    assert all(s["met"] for key in ("VI.13(a)", "VI.13(b)") for s in a[key]["specs"])


def test_two_load_crane_answers_are_the_single_load_ones():
    crane, single = classical_answers("crane"), classical_answers("crane1")
    assert "note" in crane
    for key in ("VI.8(c)", "VI.8(g)", "VI.13(b)"):
        assert crane[key] == single[key]


@pytest.mark.parametrize("name", DESIGNED)
def test_controllers_have_the_labels_and_rebuild_from_gains(name):
    blocks = classical_controllers(name)
    extra = {"uuv": {"lead-lag (IV.11)"}, "pendulum": {"PD (zero-cancelling filter)"}}
    expected = set(homework.LABELS) | extra.get(name, set())
    assert set(blocks) == expected
    plant = models.get(name)
    for block in blocks.values():
        assert block.n_measured == plant.ny and block.n_reference == 1 and block.n_input == 1
        rebuilt = block.with_gains(**block.gains)
        y = plant.output(plant.equilibrium()[0]) + 0.01
        xc = block.initial_state(y, [0.1])
        np.testing.assert_array_equal(block.step(xc, y, [0.1])[1], rebuilt.step(xc, y, [0.1])[1])


def test_bad_requests_are_named():
    with pytest.raises(ValueError, match="unknown plant 'boat'"):
        classical_answers("boat")
    with pytest.raises(ValueError, match="the known plant is 'arm'; the uuv designs take 'uuv'"):
        classical_controllers("uuv", models.get("arm"))


def test_frequency_responses_are_the_loops_behind_the_13_answers(arm_answers):
    a = arm_answers
    w = np.array([0.1, 1.0, 10.0])
    data = homework.frequency_responses(homework.classical_design(studies.get("arm")), omega=w)
    G = models.get("arm").linearize().tf("theta", "tau")
    L = G * (a["I.8(c)"]["kp"] + a["I.10(d)"]["ki"] * control.tf([1], [1, 0]) + _pd_dirty(0.0, a["I.8(d)"]["kd"]))
    np.testing.assert_allclose(data["PID (implemented)"]["loop"]["magnitude"], _mag(L, w), rtol=1e-9)
    np.testing.assert_allclose(data["PID (implemented)"]["plant"]["magnitude"], _mag(G, w), rtol=1e-9)


def test_ballbeam_11_root_locus_lead_places_the_outer_pair():
    """V.11: C(s) K_DC (−g/s²) closed with python-control has the pair at V.8(i)'s ω_n, ζ, all poles stable;
    the angle and magnitude conditions hold at s*; the step numbers are python-control's step_info."""
    a, p = classical_answers("ballbeam"), models.get("ballbeam")
    rec = a["V.11(a)"]
    K_dc, g = a["V.8(f)"]["dc_gain"], p.params["g"]
    G = control.tf([-K_dc * g], [1, 0, 0])
    C = _tf(rec, "C_")
    wn, zeta = a["V.8(i)"]["wn"], a["V.8(i)"]["zeta"]
    s_star = complex(-zeta * wn, wn * np.sqrt(1 - zeta**2))
    loop = complex(control.evalfr(C * G, s_star))
    assert abs(loop) == pytest.approx(1.0, rel=1e-9)
    assert abs(np.angle(loop)) == pytest.approx(np.pi, rel=1e-9)
    assert rec["zero"] == pytest.approx(0.5 * wn) and rec["gain"] < 0  # negative plant gain, negative lead
    T = control.feedback(C * G, 1)
    poles = control.poles(T)
    assert np.min(np.abs(poles - s_star)) < 1e-8 and np.all(poles.real < 0)
    grid = np.linspace(0, 20, 40001)
    info = control.step_info(T, T=grid)  # times to the grid's resolution
    assert a["V.11(b)"]["rise_time"] == pytest.approx(info["RiseTime"], abs=2 * grid[1])
    assert a["V.11(b)"]["overshoot_percent"] == pytest.approx(info["Overshoot"], rel=1e-4)
    assert a["V.11(b)"]["dc_gain"] == pytest.approx(1.0)
