"""End to end in headless Chromium (Selenium): the animation page draws the simulated plant where the
simulation put it, for the controller picked, with a ghost and the command beside it; the index's
heat map, scatter and box plots name exactly the tables' controllers; no console errors."""

import json
import math
import re

import numpy as np
import pandas as pd
import pytest
from example_providers import controllers as example_controllers

import models
import studies
from studies import animation, drawing

BODY, ACCENT = drawing.BODY, drawing.ACCENT


def page_data(path):
    return json.loads(re.search(r"const DATA = (\{.*?\});\n", path.read_text(encoding="utf-8")).group(1))


def move_slider(browser, index: int) -> str:
    return browser.evaluate(
        f"const s = document.getElementById('slider'); s.value = '{index}';"
        "s.dispatchEvent(new Event('input')); document.getElementById('time').textContent"
    )


def pick(browser, select: str, label: str) -> None:
    browser.evaluate(
        f"const p = document.getElementById('{select}'); p.value = {json.dumps(label)};"
        "p.dispatchEvent(new Event('change')); 0"
    )


def drawn(browser, group: str = "frame") -> list:
    """The primitives drawn in the scene's group: tag, attributes that place them."""
    return browser.evaluate(
        f"Array.from(document.getElementById('{group}').children).map(e => ({{tag: e.tagName,"
        " points: e.getAttribute('points'), stroke: e.getAttribute('stroke'), fill: e.getAttribute('fill'),"
        " width: e.getAttribute('stroke-width'), cx: e.getAttribute('cx'), cy: e.getAttribute('cy'),"
        " text: e.textContent}))"
    )


def points(element) -> np.ndarray:
    return np.array([[float(v) for v in p.split(",")] for p in element["points"].split()])


def sample(run, t: float) -> int:
    """The run's sample at frame time t (frames are samples of the run, t rounded to 1e-4 s)."""
    k = int(np.argmin(np.abs(run.t - t)))
    assert abs(run.t[k] - t) < 1e-3
    return k


def arm_tip(browser) -> np.ndarray:
    (rod,) = [e for e in drawn(browser) if e["tag"] == "polyline" and e["stroke"] == BODY and e["width"] == "8"]
    return points(rod)[-1]


def test_the_arm_is_drawn_where_the_simulation_put_it_at_three_slider_positions(arm_study, browser):
    result, out = arm_study
    path = out / "arm" / "animation.html"
    data = page_data(path)
    selected = data["selected"]
    assert selected == result.best("step", meeting=False)
    browser.open(path.as_uri())
    frames = data["runs"][selected]["t"]
    assert int(browser.evaluate("document.getElementById('slider').max")) + 1 == len(frames) > 10
    run, ell = result.runs[(selected, "step")], result.plant.params["ell"]
    for index in (len(frames) // 5, len(frames) // 2, len(frames) - 1):
        label = move_slider(browser, index)
        assert label == f"t = {frames[index]:.2f} s"
        theta = run.x[sample(run, frames[index]), 0]
        # The tip of the rod is at ℓ (cos θ, sin θ) of that sample (4 significant digits on the page).
        np.testing.assert_allclose(arm_tip(browser), ell * np.array([math.cos(theta), math.sin(theta)]), atol=2e-4)
        assert (
            browser.evaluate("document.getElementById('readout').textContent")
            == data["runs"][selected]["readouts"][index]
        )
    labels = [e["text"] for e in drawn(browser) if e["tag"] == "text"]
    assert labels == ["target θ = 50°"]
    assert browser.errors() == []


def test_the_picker_switches_controller_the_ghost_follows_and_the_command_is_beside_it(arm_study, browser):
    result, out = arm_study
    data = page_data(out / "arm" / "animation.html")
    first = data["selected"]
    other = next(label for label in data["order"] if label != first)
    browser.open((out / "arm" / "animation.html").as_uri())
    assert (
        browser.evaluate("Array.from(document.getElementById('controller').options).map(o => o.value)") == data["order"]
    )
    pick(browser, "controller", other)
    frames = data["runs"][other]["t"]
    index = len(frames) // 3
    move_slider(browser, index)
    run, ell = result.runs[(other, "step")], result.plant.params["ell"]
    k = sample(run, frames[index])
    np.testing.assert_allclose(
        arm_tip(browser), ell * np.array([math.cos(run.x[k, 0]), math.sin(run.x[k, 0])]), atol=2e-4
    )
    # The command beside the drawing is that run's at that sample; the limit is the arm's 1 N m.
    shown = browser.evaluate("document.getElementById('input-value').textContent")
    assert shown.startswith("tau = ") and shown.endswith(" N m")
    assert float(shown.split()[2]) == pytest.approx(run.u[k, 0], rel=5e-3, abs=1e-3)
    assert browser.evaluate("document.getElementById('limit-label').textContent") == "limit ±1 N m"
    assert browser.evaluate("document.querySelectorAll('#input-plot polyline.command').length") == 1
    # The ghost is the first controller at the same time, drawn faintly behind.
    pick(browser, "ghost", first)
    ghost_run = result.runs[(first, "step")]
    ghost = [e for e in drawn(browser, "ghostframe") if e["tag"] == "polyline" and e["width"] == "8"]
    g = sample(ghost_run, max(t for t in data["runs"][first]["t"] if t <= frames[index] + 1e-9))
    np.testing.assert_allclose(
        points(ghost[0])[-1], ell * np.array([math.cos(ghost_run.x[g, 0]), math.sin(ghost_run.x[g, 0])]), atol=2e-4
    )
    assert browser.evaluate("document.getElementById('ghostframe').getAttribute('opacity')") == "0.3"
    assert browser.evaluate("document.querySelectorAll('#input-plot polyline.ghost-command').length") == 1
    pick(browser, "ghost", "")
    assert drawn(browser, "ghostframe") == []
    assert browser.errors() == []


@pytest.mark.parametrize("name", ["pendulum", "crane"])
def test_cart_and_loads_are_drawn_where_the_simulation_put_them(name, browser, tmp_path):
    case, plant = studies.get(name), models.get(name)
    xe, _ = plant.equilibrium()
    base = xe[plant.state_names.index(case.tracked)]
    blocks = example_controllers(name, plant)
    runs = {
        label: models.simulate_closed_loop(
            plant, blocks[label], models.signals.step(case.step, 0.0, base), 4.0, substeps=2
        )
        for label in ("LQR", "LQR fast")
    }
    path = animation.write_html(
        tmp_path / "animation.html", case, plant, runs, "LQR", max_frames=60, scenario="the step"
    )
    data = page_data(path)
    browser.open(path.as_uri())
    p = plant.params
    for label in ("LQR", "LQR fast"):
        pick(browser, "controller", label)
        frames, run = data["runs"][label]["t"], runs[label]
        for index in (5, len(frames) // 2, len(frames) - 1):
            move_slider(browser, index)
            s = dict(zip(plant.state_names, run.x[sample(run, frames[index])]))
            shapes = drawn(browser)
            cart = [points(e) for e in shapes if e["tag"] == "polygon" and e["fill"] == BODY]
            circles = np.array([[float(e["cx"]), float(e["cy"])] for e in shapes if e["tag"] == "circle"])
            if name == "pendulum":
                # The cart is centred on z; the bob is ℓ from the pivot on the cart's top, θ from up.
                assert cart[0][:, 0].mean() == pytest.approx(s["z"], abs=1e-3)
                top = cart[0][:, 1].max()
                np.testing.assert_allclose(
                    circles[0],
                    [s["z"] + p["ell"] * math.sin(s["theta"]), top + p["ell"] * math.cos(s["theta"])],
                    atol=1e-3,
                )
            else:
                # The car is centred on x; each load hangs ℓi below it at θi from down.
                assert cart[0][:, 0].mean() == pytest.approx(s["x"], abs=1e-2)
                loads = [
                    [s["x"] + p[f"ell{i}"] * math.sin(s[f"theta{i}"]), -p[f"ell{i}"] * math.cos(s[f"theta{i}"])]
                    for i in (1, 2)
                ]
                np.testing.assert_allclose(circles, loads, atol=1e-2)
    assert browser.errors() == []


def test_play_button_advances_the_animation(arm_study, browser):
    _, out = arm_study
    browser.open((out / "arm" / "animation.html").as_uri())
    browser.evaluate("document.getElementById('speed').value = '10'; document.getElementById('play').click(); 0")
    moved = browser.wait(
        "new Promise(done => { const s = document.getElementById('slider'); let n = 0;"
        "  const poll = () => { if (Number(s.value) > 0 || n++ > 200) done(Number(s.value)); "
        "                       else setTimeout(poll, 50); }; poll(); })"
    )
    assert moved > 0
    assert browser.evaluate("document.getElementById('play').textContent") in ("Pause", "Play")
    assert browser.errors() == []


def test_index_pictures_name_exactly_the_tables_controllers(arm_study, browser):
    _, out = arm_study
    table = pd.read_csv(out / "arm" / "table.csv")
    samples = pd.read_csv(out / "arm" / "monte_carlo.csv")
    browser.open((out / "index.html").as_uri())
    heat = browser.evaluate("Array.from(document.querySelectorAll('#heatmap tbody th')).map(e => e.textContent)")
    assert sorted(heat) == sorted(set(table.controller))
    marks = browser.evaluate(
        "Array.from(document.querySelectorAll('#heatmap td[data-controller]')).map("
        "e => [e.dataset.controller, e.dataset.verdict])"
    )
    step = table[table.scenario == "step"].set_index("controller")
    assert {c: v for c, v in marks} == {c: step.loc[c, "verdict"] for c in step.index}
    legend = browser.evaluate(
        "Array.from(document.querySelectorAll('#scatter [id^=\"legend-label\"] text')).map(e => e.textContent)"
    )
    assert sorted(legend) == sorted(set(table.controller))
    boxes = browser.evaluate(
        "Array.from(document.querySelectorAll('#boxplots [id^=\"box-label\"] text')).map(e => e.textContent)"
    )
    finite = samples[np.isfinite(samples.itae)]
    assert sorted(boxes) == sorted(set(finite.controller))
    images = browser.wait(
        "Promise.all(Array.from(document.images).map(i => { i.loading = 'eager';"
        "  return i.decode().then(() => [i.getAttribute('src'), i.naturalWidth],"
        "                         () => [i.getAttribute('src'), 0]); }))"
    )
    assert images and all(width > 0 for _, width in images), images
    assert browser.errors() == []
