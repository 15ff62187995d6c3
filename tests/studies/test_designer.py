"""The control designer: its update against an independent run of the closed loop, its margins against
python-control's, the refusal of bad input, divergence, Export, Tune, and the page in headless Chromium."""

import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import models
import models.export
import studies
from models import Block, metrics
from studies import designer
from studies.plots import tracked_scale

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def arm():
    return designer.Designer.for_case("arm", "PD")


def independent_run(session, **gains):
    """The step of `session`'s case with its designed block at `gains`, run here with models.simulate_closed_loop."""
    case = session.case
    plant = models.get(case.plant)
    xe, _ = plant.equilibrium()
    base = xe[plant.state_names.index(case.tracked)]
    block = session.block.with_gains(**gains)
    return models.simulate_closed_loop(
        plant, block, lambda t: base + case.step, case.duration, substeps=case.substeps, allow_divergence=True
    )


def test_a_changed_gain_gives_the_response_simulate_closed_loop_gives(arm):
    kp = 1.7 * arm.block.gains["kp"]
    update = arm.update({"kp": kp})
    run = independent_run(arm, kp=kp)
    design = independent_run(arm)
    k = run.state_names.index("theta")
    for t in (0.5, 1.5, 4.0):
        i = int(np.argmin(np.abs(run.t - t)))
        assert update.t[i] == pytest.approx(t, abs=1e-12)
        assert update.tracked[i] == pytest.approx(run.x[i, k], rel=1e-9, abs=1e-12)
    np.testing.assert_allclose(update.u, run.u[:, 0], rtol=1e-9, atol=1e-12)
    # The gain matters: the design's response differs from it.
    assert np.max(np.abs(design.x[:, k] - run.x[:, k])) > 1e-2
    assert update.gains == {"kp": kp, "kd": float(arm.block.gains["kd"])}


def test_the_verdict_names_the_overshoot_exactly_when_the_run_exceeds_the_bound(arm):
    bound = arm.case.specs["*"].max_overshoot_pct
    seen = set()
    for kd in (0.1, 0.2):
        update = arm.update({"kp": 0.5, "kd": kd})
        run = independent_run(arm, kp=0.5, kd=kd)
        overshoot = metrics.run_metrics(run, "theta")["overshoot_pct"]
        named = "overshoot" in [v.spec for v in update.verdict.violations]
        assert named == (overshoot > bound)
        seen.add(named)
    assert seen == {True, False}, "the two gains should fall on both sides of the overshoot bound"


def test_margins_hold_on_the_loops_frequency_response_on_the_arm_uuv_and_pendulum(arm):
    """The page's margins against L(e^{jωTs}) computed here by a second method (z I − A solved per
    frequency): |L| = 1 at the gain crossover, the phase margin 180° + ∠L there; L real and negative at
    the phase crossover (at ω = 0 too: an open-loop unstable arm's lower gain margin), gm = 1/|L|."""
    for session in (arm, designer.Designer.for_case("uuv", "PID"), designer.Designer.for_case("pendulum", "PD")):
        block = session.block_for()
        run = session.simulate(block, "step")
        loop = session.loop_gain(block, run)
        ours = session.update({}).margins
        ts, A, B, C = loop.sample_period, loop.A, loop.B, loop.C

        def L(w, ts=ts, A=A, B=B, C=C):
            return complex((C @ np.linalg.solve(np.exp(1j * w * ts) * np.eye(A.shape[0]) - A, B))[0, 0])

        wgc, wpc = ours["gain_crossover_rad_s"], ours["phase_crossover_rad_s"]
        assert np.isfinite(wgc), session.case.plant
        assert abs(L(wgc)) == pytest.approx(1.0, rel=1e-9)
        assert ours["phase_margin_deg"] == pytest.approx((np.degrees(np.angle(L(wgc))) + 360) % 360 - 180, abs=1e-6)
        if np.isfinite(ours["gain_margin_db"]):
            value = L(wpc)
            assert value.real < 0 and abs(value.imag) <= 1e-9 * abs(value), session.case.plant
            assert ours["gain_margin_db"] == pytest.approx(-20 * np.log10(abs(value)), rel=1e-9)


def test_root_locus_at_unit_gain_is_the_closed_loop_of_the_update(arm):
    update = arm.update({"kd": 0.2})
    k = int(np.argmin(np.abs(designer.LOCUS_GAINS - 1.0)))
    assert designer.LOCUS_GAINS[k] == pytest.approx(1.0)
    # The poles of the linear closed loop decay as the nonlinear run does: none in the right half plane
    # while the run settles (overshoot and all).
    assert np.all(update.poles.real[np.isfinite(update.poles.real)] < 0)
    np.testing.assert_allclose(np.sort_complex(update.locus[k]), np.sort_complex(update.poles), rtol=1e-9)


@pytest.mark.parametrize(
    "text, message",
    [
        ("abc", "kp: 'abc' is not a number"),
        ("nan", "kp: nan is not finite"),
        ("inf", "kp: inf is not finite"),
        ("-0.2", "kp: -0.2 is outside the allowed range"),
        ("1e3", "kp: 1000 is outside the allowed range"),
    ],
)
def test_a_bad_typed_gain_is_refused_with_a_message(arm, text, message):
    (control,) = [c for c in arm.controls if c.key == "kp"]
    with pytest.raises(ValueError, match=re.escape(message)):
        control.parse(text)
    with pytest.raises(ValueError, match=re.escape(message)):
        arm.update({"kp": text})


def test_gain_ranges_keep_the_sign_and_span_the_design_either_way():
    session = designer.Designer.for_case("pendulum", "PD")
    for c in session.controls:
        assert c.low * c.high > 0 and c.low < c.high
        assert c.parse(c.design) == c.design
        assert (c.low, c.high) == pytest.approx(sorted((c.design / designer.RANGE, c.design * designer.RANGE)))
        assert c.from_log(math.log10(abs(c.design))) == pytest.approx(c.design, rel=1e-12)
    assert {c.key for c in session.controls} == {"outer.kp", "outer.kd", "inner.kp", "inner.kd"}
    with pytest.raises(ValueError, match="no gain control 'kp'"):
        session.update({"kp": 1.0})


class Proportional(Block):
    """u = k (r - y): no saturation of its own, so a wrong sign runs away."""

    def __init__(self, k: float):
        super().__init__(
            sample_period=0.01, n_state=0, n_measured=1, n_reference=1, n_input=1, gains={"k": k}, name="proportional"
        )

    def expr(self, xc, y, r, gains):
        return ca.SX(0, 1), gains["k"] * (r - y)


def test_an_unstable_gain_says_diverged_at_the_time_simulate_closed_loop_finds():
    case = studies.get("arm")
    plant = models.get("arm").with_input_limit(1e12)
    session = designer.Designer(case, Proportional(-50.0), plant=plant)
    update = session.update({"k": -200.0})
    run = models.simulate_closed_loop(
        plant,
        Proportional(-200.0),
        lambda t: session.base + case.step,
        case.duration,
        substeps=case.substeps,
        allow_divergence=True,
    )
    assert run.diverged_at is not None
    assert update.diverged
    assert update.verdict_text() == f"diverged at t = {run.diverged_at:.3g} s"
    # The loop analysis, about the equilibrium at the reference, shows why: a pole in the right half plane.
    assert np.any(update.poles.real > 0)


def test_the_monte_carlo_envelope_is_the_quantiles_of_runs_on_the_same_samples(arm):
    envelope = arm.envelope({"kd": 0.2}, samples=6, seed=3)
    plant = models.get("arm")
    params = models.sample_params(plant, 6, rel=0.05, seed=3)
    block = arm.block.with_gains(kd=0.2)
    runs = [
        models.simulate_closed_loop(
            plant, block, lambda t: arm.base + arm.case.step, arm.case.duration, params=p, substeps=arm.case.substeps
        )
        for p in params
    ]
    expected = np.quantile([r.x[:, 0] for r in runs], designer.ENVELOPE_QUANTILES, axis=0)
    np.testing.assert_allclose(envelope["tracked"], expected, rtol=1e-9, atol=1e-12)
    assert envelope["diverged"] == 0 and np.ptp(expected[:, -1]) > 1e-3  # the samples differ


def test_placed_poles_are_the_eigenvalues_of_the_known_linear_loop_and_the_run_uses_their_gains():
    session = designer.Designer.for_case("arm", "pole placement")
    assert [c.key for c in session.pole_controls] == ["p1.re", "p1.im"]
    block = session.place({"p1.re": -4.0, "p1.im": 3.0})
    lin = session.case.known_plant().linearize()
    np.testing.assert_allclose(
        np.sort_complex(np.linalg.eigvals(lin.A - lin.B @ block.gains["K"])), [-4 - 3j, -4 + 3j], rtol=1e-9
    )
    # The gain controls now range about the new design, and the run uses it.
    (k0,) = [c for c in session.controls if c.key == "K[0,0]"]
    assert k0.design == pytest.approx(float(block.gains["K"][0, 0]))
    update = session.update()
    run = models.simulate_closed_loop(
        models.get("arm"),
        block,
        lambda t: session.base + session.case.step,
        session.case.duration,
        substeps=session.case.substeps,
    )
    np.testing.assert_allclose(update.tracked, run.x[:, 0], rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match=re.escape("p1.re: 4 is outside the allowed range")):
        session.place({"p1.re": 4.0})
    session.place(None)
    assert session.block.gains["K"] == pytest.approx(session.text_block.gains["K"])
    # The LQR comes from weights, not poles: no pole controls.
    labels, make = designer.catalog("arm")
    assert "LQR" in labels and make("LQR").pole_controls == ()
    assert make("observer-based").pole_controls


def test_export_gives_the_gains_in_force_and_the_c_step(arm):
    data = arm.export({"kd": 0.2})
    assert data["gains"] == {"kp": float(arm.block.gains["kp"]), "kd": 0.2}
    assert any(name.endswith(".c") for name in data["c"])
    json.dumps(data)


def test_every_arm_controller_exports_under_a_distinct_c_name_it_shows():
    """Before, Export failed for 6 of the arm's 11 controllers: their labels ('PID (no anti-windup)',
    'LQR + Kalman' ...) are not C names. Each now exports under a C identifier derived from its label,
    distinct from the others', given in the export; the C of one of them steps as its Python block."""
    labels, make = designer.catalog("arm")
    exported = {label: make(label).export() for label in labels}
    names = {label: data["c_name"] for label, data in exported.items()}
    assert len(labels) >= 11 and len(set(names.values())) == len(labels)  # the 11 hand and tuned ones, and more
    for label, data in exported.items():
        assert models.export.c_name(data["c_name"]) == data["c_name"] and data["c_name"].startswith("arm_")
        assert sorted(data["c"]) == [f"{data['c_name']}.c", f"{data['c_name']}.h"], label
    assert names["PID (no anti-windup)"] == "arm_pid_no_anti_windup"
    assert names["LQR + Kalman"] == "arm_lqr_kalman"
    session = make("pole placement + integrator")
    block = session.block_for()
    compiled = models.export.export_block(block, names["pole placement + integrator"]).load()
    y, r = np.full(block.n_measured, 0.1), np.full(block.n_reference, 0.3)
    xc = np.asarray(block.initial_state(y, r), dtype=float) + 0.05
    xc_c, u_c = compiled.step(xc, y, r)
    xc_py, u_py = (np.asarray(v, dtype=float).ravel() for v in block.casadi_step(xc, y, r, block.gain_vector()))
    np.testing.assert_allclose(u_c, u_py, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(xc_c, xc_py, rtol=1e-12, atol=1e-12)


def test_tune_is_at_least_as_good_as_its_start_on_an_independent_run(arm):
    start = {"kp": 0.3, "kd": 0.1}
    result, tuned = arm.tune(start, "step", max_iter=60)
    before = independent_run(arm, **start)
    after = independent_run(arm, **tuned)
    itae = [metrics.run_metrics(r, "theta")["itae"] for r in (before, after)]
    assert itae[1] <= itae[0] * (1 + 1e-9)
    for c in arm.controls:
        assert c.low <= tuned[c.key] <= c.high


def test_the_command_refuses_an_unknown_plant_or_controller_naming_the_choices(capsys):
    from studies.designer.__main__ import main

    with pytest.raises(SystemExit) as stop:
        main(["nowhere"])
    assert stop.value.code == 2
    assert "unknown plant 'nowhere'; choose from arm" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["arm", "no such controller"])
    assert "arm has no controller 'no such controller' with gains; choose from PD, PID" in capsys.readouterr().err


# ---------------------------------------------------------------------------- the page
def read(browser, expression: str):
    return browser.evaluate(f"const D = Bokeh.documents[0]; {expression}")


def click(browser, name: str) -> None:
    """Click the button named `name` as a user does (its view's own <button>)."""
    read(browser, f"Bokeh.index.find_one(D.get_model_by_name('{name}')).button_el.click(); 0")


def wait_for(browser, expression: str, timeout: float = 30.0):
    """Poll a JavaScript expression until it is truthy; its value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = browser.evaluate(expression)
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {expression}")


@pytest.fixture
def server():
    """`python -m studies.designer arm PD` on a free port of 127.0.0.1; its URL. Stopped at the end."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    process = subprocess.Popen(
        [sys.executable, "-m", "studies.designer", "arm", "PD"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        url = None
        for line in process.stdout:
            match = re.search(r"running at (http://127\.0\.0\.1:\d+/)", line)
            if match:
                url = match.group(1)
                break
        assert url, "the designer did not print its URL"
        yield url
    finally:
        process.terminate()
        process.wait(timeout=30)
    assert process.returncode is not None


@pytest.mark.slow  # about 20 s: the server designs the arm's controllers, then Tune runs
def test_the_page_follows_a_typed_gain_and_refuses_a_bad_one(server, browser, arm, tmp_path):
    browser.driver.set_window_size(1480, 1120)
    browser.open(server)
    wait_for(
        browser,
        "window.Bokeh && Bokeh.documents.length && Bokeh.documents[0].get_model_by_name('response').get_length() > 0",
    )
    scale, _ = tracked_scale(arm.case.tracked_unit)
    verdict_before = read(browser, "D.get_model_by_name('verdict').text")
    assert "overshoot" in verdict_before
    first_y = read(browser, "D.get_model_by_name('response').data.y[100]")

    started = time.monotonic()
    read(browser, "D.get_model_by_name('gain:kd').value = '0.7'; 0")
    wait_for(browser, f"Bokeh.documents[0].get_model_by_name('response').data.y[100] !== {first_y!r}")
    page_seconds = time.monotonic() - started
    t = read(browser, "Array.from(D.get_model_by_name('response').data.t)")
    y = read(browser, "Array.from(D.get_model_by_name('response').data.y)")
    run = independent_run(arm, kd=0.7)
    k = run.state_names.index("theta")
    for when in (0.5, 1.5, 4.0):
        i = int(np.argmin(np.abs(np.asarray(t) - when)))
        assert t[i] == pytest.approx(run.t[i], abs=1e-12)
        assert y[i] / scale == pytest.approx(run.x[i, k], rel=1e-9, abs=1e-12)
    verdict_after = wait_for(
        browser,
        "Bokeh.documents[0].get_model_by_name('verdict').text.includes('settling')"
        " && Bokeh.documents[0].get_model_by_name('verdict').text",
    )
    assert "overshoot" not in verdict_after, "kd = 0.7 brings the overshoot under the 10 % bound"
    assert read(browser, "D.get_model_by_name('slider:kd').value") == pytest.approx(math.log10(0.7))

    read(browser, "D.get_model_by_name('gain:kd').value = 'abc'; 0")
    message = wait_for(browser, "Bokeh.documents[0].get_model_by_name('gain_error:kd').text")
    assert message.startswith("kd: 'abc' is not a number")
    wait_for(browser, "Bokeh.documents[0].get_model_by_name('gain:kd').value === '0.7'")
    assert read(browser, "D.get_model_by_name('response').data.y[100]") == pytest.approx(y[100], rel=0, abs=0)

    # Tune from the gains in force: the gains it loads (exported exactly) do at least as well on an
    # independent run; Export gives the gains in force.
    start = {"kp": float(arm.block.gains["kp"]), "kd": 0.7}
    click(browser, "export_button")
    assert json.loads(wait_for(browser, "Bokeh.documents[0].get_model_by_name('export').text"))["gains"] == start
    click(browser, "tune")
    status = wait_for(
        browser,
        "Bokeh.documents[0].get_model_by_name('tune_status').text.startsWith('tun') && "
        "!Bokeh.documents[0].get_model_by_name('tune_status').text.startsWith('tuning') && "
        "Bokeh.documents[0].get_model_by_name('tune_status').text",
        timeout=120,
    )
    assert status.startswith("tuned: ITAE"), status
    wait_for(browser, f"Bokeh.documents[0].get_model_by_name('response').data.y[100] !== {y[100]!r}")
    click(browser, "export_button")
    tuned = wait_for(
        browser,
        "JSON.parse(Bokeh.documents[0].get_model_by_name('export').text).gains.kd !== 0.7 && "
        "JSON.parse(Bokeh.documents[0].get_model_by_name('export').text).gains",
    )
    assert set(tuned) == set(start) and tuned != start
    for c in arm.controls:
        assert read(browser, f"D.get_model_by_name('gain:{c.key}').value") == f"{tuned[c.key]:.6g}"
    itae = [metrics.run_metrics(independent_run(arm, **g), "theta")["itae"] for g in (start, tuned)]
    assert itae[1] <= itae[0]

    click(browser, "reset")
    wait_for(browser, f"Bokeh.documents[0].get_model_by_name('gain:kd').value === '{arm.block.gains['kd']:.6g}'")

    read(browser, "D.get_model_by_name('envelope_box').active = true; 0")
    wait_for(browser, "Bokeh.documents[0].get_model_by_name('envelope').get_length() > 0")
    low = read(browser, "Array.from(D.get_model_by_name('envelope').data.min)")
    high = read(browser, "Array.from(D.get_model_by_name('envelope').data.max)")
    assert all(a <= b for a, b in zip(low, high)) and max(b - a for a, b in zip(low, high)) > 0

    # The animation draws the design's run where the simulation put it: the rod's tip at ℓ (cos θ, sin θ).
    run, ell = independent_run(arm), models.get("arm").params["ell"]
    for when in (0.3, 1.0, 4.0):
        read(browser, f"D.get_model_by_name('anim_time').value = {when}; 0")
        wait_for(browser, f"Bokeh.documents[0].get_model_by_name('readout').text.startsWith('t = {when:.2f} s')")
        rods = read(
            browser,
            "const L = D.get_model_by_name('scene_lines').data; "
            "Array.from(L.width).map((w, i) => [w, Array.from(L.xs[i]), Array.from(L.ys[i])])",
        )
        (tip,) = [(xs[-1], ys[-1]) for width, xs, ys in rods if width == 8]
        theta = run.x[int(np.argmin(np.abs(run.t - when))), 0]
        np.testing.assert_allclose(tip, ell * np.array([math.cos(theta), math.sin(theta)]), rtol=1e-9, atol=1e-12)

    # A drag: the slider's value moves in many steps; the page ends at the last one's response.
    (kp,) = [c for c in arm.controls if c.key == "kp"]
    exponents = np.linspace(math.log10(kp.design), math.log10(kp.design) + 0.5, 12)
    read(
        browser,
        f"const s = D.get_model_by_name('slider:kp'); {json.dumps(list(exponents))}"
        ".forEach(e => {{ s.value = e }}); 0",
    )
    dragged = kp.from_log(float(exponents[-1]))
    wait_for(browser, f"Bokeh.documents[0].get_model_by_name('gain:kp').value === '{dragged:.6g}'")
    run = independent_run(arm, kp=dragged)
    wait_for(
        browser,
        f"Math.abs(Bokeh.documents[0].get_model_by_name('response').data.y[150] - "
        f"{float(run.x[150, 0] * scale)!r}) < 1e-9",
    )
    y = read(browser, "Array.from(D.get_model_by_name('response').data.y)")
    np.testing.assert_allclose(np.asarray(y) / scale, run.x[:, 0], rtol=1e-9, atol=1e-12)

    browser.driver.save_screenshot(str(tmp_path / "designer.png"))
    if os.environ.get("DESIGNER_SCREENSHOT"):
        browser.driver.save_screenshot(os.environ["DESIGNER_SCREENSHOT"])

    # Another plant: its controllers are designed, its first one shown and run.
    read(browser, "D.get_model_by_name('plant').value = 'uuv'; 0")
    wait_for(browser, "Bokeh.documents[0].get_model_by_name('title').text.includes('uuv: PD')", timeout=120)
    wait_for(browser, "Bokeh.documents[0].get_model_by_name('response').data.t.length === 1001")
    assert "PID" in read(browser, "D.get_model_by_name('controller').options")
    assert browser.errors() == []
    print(f"page updated {1e3 * page_seconds:.0f} ms after the typed gain (polled every 50 ms)")


def test_the_page_shows_labels_and_messages_as_text_in_its_html():
    pytest.importorskip("bokeh")
    from types import SimpleNamespace

    from studies.designer import app

    assert app.fragment("title", "<b>arm</b>", "P & D") == "<h3>&lt;b&gt;arm&lt;/b&gt;: P &amp; D</h3>"
    message = "ValueError: kp: '<img>' is not a number"
    assert app.fragment("error", message) == (
        "<b style='color:#cf222e'>ValueError: kp: &#x27;&lt;img&gt;&#x27; is not a number</b>"
    )
    assert app._margins_text(SimpleNamespace(margins={}, notes=["a <b> & c", "d"]), {}) == (
        "<i>a &lt;b&gt; &amp; c; d</i>"
    )
    margins = {
        "gain_margin_db": 6.0,
        "phase_crossover_rad_s": 10.0,
        "phase_margin_deg": 45.0,
        "gain_crossover_rad_s": 3.0,
    }
    update = SimpleNamespace(margins=margins, loop="input", poles=np.array([-1.0 + 0j, 2.0 + 0j]), notes=[])
    spec = {"item": "<IV.11>", "checks": {"crossover": True, "phase_margin": None}}
    assert app._margins_text(update, spec) == (
        "input loop: gain margin 6 dB at 10 rad/s, phase margin 45° at 3 rad/s; 1 closed-loop pole in the right "
        "half plane<br>loopshaping specs (&lt;IV.11&gt;): crossover met, phase_margin not checked"
    )
    assert type(app.fragment("busy", "designing")) is str  # a plain str for Bokeh's Div


def test_typed_html_reaches_only_plain_text_divs():
    """Self-XSS (issue 31): a typed value quoted in an error message is shown by a Div that renders its
    text as text; every other Div gets escaped fragments only."""
    pytest.importorskip("bokeh")
    from studies.designer import app

    page = app.Page(designer.catalog, list(studies.cases.names()), "arm", "PD")
    typed = "<img src=x onerror=alert(1)>"
    for c in page.designer.controls:
        page._on_text("gain", c, typed)
        error = page.rows[("gain", c.key)][3]
        assert typed in error.text and error.render_as_text
    divs = [m for m in page.layout.references() if type(m).__name__ == "Div"]
    assert all(d.render_as_text or "<img" not in d.text for d in divs)
    assert {d.name for d in divs if not d.render_as_text} == {"title", "margins", "verdict"}  # fragments only


def test_the_page_says_under_which_c_name_it_exported():
    data = {"c_name": "arm_lqr_kalman", "c": {"arm_lqr_kalman.h": "", "arm_lqr_kalman.c": ""}}
    assert designer.export_note(data) == (
        "exported the gains and the C step as arm_lqr_kalman_step (arm_lqr_kalman.c, arm_lqr_kalman.h)"
    )
    assert (
        designer.export_note({"c_name": "x", "c_note": "MPC: not a Block\nmore"})
        == "exported the gains; no C: MPC: not a Block"
    )


def test_a_port_in_use_is_refused_before_designing():
    """Before: the designer designed every controller, then died with a tornado traceback (exit 1)."""
    pytest.importorskip("bokeh")
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        done = subprocess.run(
            [sys.executable, "-m", "studies.designer", "arm", "--port", str(port)],
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
    assert done.returncode == 2, done.stderr[-2000:]
    assert "designing" not in done.stdout and "Traceback" not in done.stderr
    assert f"--port {port}: 127.0.0.1:{port} is in use" in done.stderr, done.stderr[-2000:]


def test_the_command_without_bokeh_says_what_to_install():
    code = (
        "import sys; sys.modules['bokeh'] = None\n"  # as if the optional "designer" extra were not installed
        "from studies.designer.__main__ import main\n"
        "main(['arm'])"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert "the designer's page needs bokeh (pip install 'codesign-control[designer]')" in done.stderr
