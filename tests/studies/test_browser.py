"""End to end: the written animation page and index load in headless Chromium without
console errors, and the slider and the play button move the animation."""

import json
import re


def test_animation_page_loads_and_its_slider_moves_the_plant(arm_study, browser):
    result, out = arm_study
    page = out / "arm" / "animation.html"
    browser.open(page.as_uri())
    count = int(browser.evaluate("document.getElementById('slider').max")) + 1
    data = json.loads(re.search(r"const DATA = (\{.*?\});\n", page.read_text()).group(1))
    assert count == len(data["t"]) > 10
    before = browser.evaluate("document.getElementById('frame').innerHTML")
    assert "<polyline" in before and "<circle" in before
    target = count // 2
    label, after = browser.evaluate(
        f"const s = document.getElementById('slider'); s.value = '{target}';"
        "s.dispatchEvent(new Event('input'));"
        "[document.getElementById('time').textContent, document.getElementById('frame').innerHTML]")
    assert label == f"t = {data['t'][target]:.2f} s"
    assert after != before
    # The drawn arm is the simulated one: its tip is at ℓ (cos θ, sin θ) of that frame.
    assert browser.evaluate("document.getElementById('readout').textContent") == data["readouts"][target]
    assert browser.errors() == []


def test_play_button_advances_the_animation(arm_study, browser):
    _, out = arm_study
    browser.open((out / "arm" / "animation.html").as_uri())
    browser.evaluate("document.getElementById('speed').value = '10'; document.getElementById('play').click()")
    moved = browser.evaluate(
        "new Promise(done => { const s = document.getElementById('slider'); let n = 0;"
        "  const poll = () => { if (Number(s.value) > 0 || n++ > 200) done(Number(s.value)); "
        "                       else setTimeout(poll, 50); }; poll(); })")
    assert moved > 0
    assert browser.evaluate("document.getElementById('play').textContent") in ("Pause", "Play")
    assert browser.errors() == []


def test_index_page_loads_without_errors(arm_study, browser):
    _, out = arm_study
    browser.open((out / "index.html").as_uri())
    images = browser.evaluate(
        "Promise.all(Array.from(document.images).map(i => { i.loading = 'eager';"
        "  return i.decode().then(() => [i.getAttribute('src'), i.naturalWidth],"
        "                         () => [i.getAttribute('src'), 0]); }))")
    assert images and all(width > 0 for _, width in images), images
    assert browser.errors() == []
