"""Animations of a plant from its simulated state: a GIF and a self-contained HTML page.

Each case draws its plant once, in its case file, as a list of primitives
(`studies.drawing`: lines, polygons, circles) in world coordinates (m, y up)
computed from the state and the plant's own parameters. The GIF renders the
primitives with matplotlib; the HTML page embeds them as JSON and an inline
script draws them in SVG, with a play button and a time slider (the text's
slider-driven animation, homework .2).
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Circle, Polygon  # noqa: E402
from PIL import Image  # noqa: E402

from models import files  # noqa: E402

from .drawing import GROUND  # noqa: E402



def draw(case, plant, x, reference: float) -> list:
    """Primitives of the case's drawing of `plant` in state x (nx,), the tracked coordinate's reference marked."""
    if case.drawing is None:
        raise ValueError(f"the {case.plant} case has no drawing")
    return case.drawing(dict(plant.params), dict(zip(plant.state_names, np.asarray(x, dtype=float))),
                        float(reference))


# ------------------------------------------------------------------------------- frames
def frames(case, plant, run, max_frames: int) -> tuple[np.ndarray, list, list]:
    """Subsampled times (s), primitives and state readouts of a closed-loop run.

    Returns
    -------
    times : (M,) s;  shapes : M lists of primitives;  readouts : M strings
    """
    stride = max(1, math.ceil(len(run.t) / max_frames))
    index = np.arange(0, len(run.t), stride)
    if index[-1] != len(run.t) - 1:
        index = np.append(index, len(run.t) - 1)
    times = run.t[index]
    shapes, readouts = [], []
    for k in index:
        if not np.all(np.isfinite(run.x[k])):
            break
        shapes.append(draw(case, plant, run.x[k], run.r[k, 0]))
        readouts.append(_readout(plant, run.x[k], run.r[k, 0]))
    return times[:len(shapes)], shapes, readouts


def _readout(plant, x, reference) -> str:
    parts = []
    for name, value in zip(plant.coordinate_names, x[:plant.nq]):
        angle = name.startswith(("theta", "phi"))
        parts.append(f"{name} = {math.degrees(value):.1f} deg" if angle else f"{name} = {value:.3f} m")
    return ", ".join(parts)


def view(shapes: list, margin: float = 0.08) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) holding every point of every frame, with a margin.

    Long ground and track lines are left out so the view follows the plant.
    """
    xs, ys = [], []
    for frame in shapes:
        for prim in frame:
            if prim["k"] == "line" and prim["c"] == GROUND and prim["w"] == 2:
                continue
            if prim["k"] == "circle":
                (cx, cy), rad = prim["p"], prim["r"]
                xs += [cx - rad, cx + rad]
                ys += [cy - rad, cy + rad]
            else:
                xs += [q[0] for q in prim["p"]]
                ys += [q[1] for q in prim["p"]]
    xmin, xmax, ymin, ymax = min(xs), max(xs), min(ys), max(ys)
    pad = margin * max(xmax - xmin, ymax - ymin)
    return xmin - pad, xmax + pad, ymin - pad, ymax + pad


# ------------------------------------------------------------------------------- GIF
def write_gif(path: Path, case, plant, run, label: str, max_frames: int = 100, dpi: int = 80,
              frame_ms: int | None = None) -> Path:
    """An animated GIF of the run, at most `max_frames` frames, real time or faster.

    Frames last at least 40 ms (browsers slow down faster GIFs); a long run
    plays faster than real time and the caption says how much.
    """
    times, shapes, readouts = frames(case, plant, run, max_frames)
    step = float(times[1] - times[0]) if len(times) > 1 else 0.1
    frame_ms = frame_ms or int(min(100, max(40, round(1000 * step))))
    speed = 1000 * step / frame_ms
    xmin, xmax, ymin, ymax = view(shapes)
    aspect = (ymax - ymin) / (xmax - xmin)
    height = min(5.0, max(2.2, 5.0 * aspect)) + 0.7
    fig = Figure(figsize=(5.0, height))
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes([0.02, 0.02, 0.96, 1 - 0.75 / height])
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.set_aspect("equal", adjustable="box")
    ax.axis("off")
    title = fig.text(0.5, 1 - 0.08 / height, "", ha="center", va="top", fontsize=8)
    artists = [_artist(ax, prim, dpi) for prim in shapes[0]]
    images = []
    for t, frame, readout in zip(times, shapes, readouts):
        for artist, prim in zip(artists, frame):
            _update(artist, prim)
        pace = "" if abs(speed - 1) < 0.05 else f", {speed:.3g}x speed"
        title.set_text(f"{plant.title}\n{label}: t = {t:.2f} s{pace}\n{readout}")
        canvas.draw()
        images.append(Image.frombuffer("RGBA", canvas.get_width_height(), canvas.buffer_rgba()).convert("RGB"))
    palette = images[len(images) // 2].quantize(colors=64)
    frames_p = [im.quantize(palette=palette, dither=Image.Dither.NONE) for im in images]
    with files.atomic_path(path) as tmp:
        frames_p[0].save(tmp, format="GIF", save_all=True, append_images=frames_p[1:], duration=frame_ms, loop=0,
                         optimize=False)
    return path


def _artist(ax, prim: dict, dpi: int):
    width = prim.get("w", 1.0) * 72 / dpi
    if prim["k"] == "line":
        points = np.array(prim["p"])
        artist = Line2D(points[:, 0], points[:, 1], color=prim["c"], linewidth=width,
                        linestyle="--" if prim["d"] else "-", solid_capstyle="round")
        ax.add_line(artist)
    elif prim["k"] == "poly":
        artist = Polygon(prim["p"], closed=True, facecolor=prim["f"], edgecolor=prim["c"], linewidth=1)
        ax.add_patch(artist)
    else:
        artist = Circle(prim["p"], prim["r"], facecolor=prim["f"], edgecolor=prim["c"], linewidth=1)
        ax.add_patch(artist)
    return artist


def _update(artist, prim: dict) -> None:
    if prim["k"] == "line":
        points = np.array(prim["p"])
        artist.set_data(points[:, 0], points[:, 1])
    elif prim["k"] == "poly":
        artist.set_xy(prim["p"])
    else:
        artist.set_center(prim["p"])
        artist.set_radius(prim["r"])


# ------------------------------------------------------------------------------- HTML
def _rounded(value, digits: int = 4):
    if isinstance(value, float):
        return round(value, digits)
    if isinstance(value, list):
        return [_rounded(v, digits) for v in value]
    if isinstance(value, dict):
        return {k: _rounded(v, digits) for k, v in value.items()}
    return value


def write_html(path: Path, case, plant, run, label: str, caption: str = "", max_frames: int = 800) -> Path:
    """A self-contained HTML page (inline SVG and script) animating the run, with play button and slider."""
    times, shapes, readouts = frames(case, plant, run, max_frames)
    xmin, xmax, ymin, ymax = view(shapes)
    digits = max(3, 3 - int(math.floor(math.log10(max(xmax - xmin, ymax - ymin)))) + 1)
    data = {"t": [round(float(t), 4) for t in times], "frames": _rounded(shapes, digits), "readouts": readouts,
            "view": [xmin, ymin, xmax - xmin, ymax - ymin]}
    # One pass: a label containing a placeholder is shown as it is, never filled in. '<' is escaped in
    # the JSON so no label can close the script.
    page = files.fill_template(_TEMPLATE, {
        "__TITLE__": html.escape(f"{plant.title}: {label}"), "__CAPTION__": html.escape(caption),
        "__DATA__": json.dumps(data, separators=(",", ":")).replace("<", "\\u003c")})
    return files.write_text(path, page)


_TEMPLATE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>__TITLE__</title>
<style>
  body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }
  #scene { width: 100%; max-width: 720px; height: 440px; border: 1px solid #ccc; background: #fafafa; display: block; }
  .controls { display: flex; gap: 0.8em; align-items: center; max-width: 720px; margin-top: 0.6em; }
  #slider { flex: 1; }
  #time { font-variant-numeric: tabular-nums; min-width: 6em; }
  #readout { font-size: 0.9em; color: #444; margin-top: 0.4em; }
  .caption { font-size: 0.85em; color: #555; max-width: 720px; }
</style>
</head>
<body>
<h1 style="font-size:1.2em">__TITLE__</h1>
<p class="caption">__CAPTION__</p>
<svg id="scene" xmlns="http://www.w3.org/2000/svg" preserveAspectRatio="xMidYMid meet">
  <g id="world"><g id="frame"></g></g>
</svg>
<div class="controls">
  <button id="play" type="button">Play</button>
  <input id="slider" type="range" min="0" value="0" step="1" aria-label="time">
  <span id="time">t = 0.00 s</span>
  <label>speed <select id="speed"><option value="0.5">0.5x</option><option value="1" selected>1x</option>
  <option value="2">2x</option><option value="5">5x</option><option value="10">10x</option></select></label>
</div>
<div id="readout"></div>
<script>
"use strict";
const DATA = __DATA__;
const NS = "http://www.w3.org/2000/svg";
const scene = document.getElementById("scene");
const world = document.getElementById("world");
const frameGroup = document.getElementById("frame");
const slider = document.getElementById("slider");
const playButton = document.getElementById("play");
const timeLabel = document.getElementById("time");
const readout = document.getElementById("readout");
const speedSelect = document.getElementById("speed");
const [vx, vy, vw, vh] = DATA.view;
scene.setAttribute("viewBox", `${vx} ${-(vy + vh)} ${vw} ${vh}`);
world.setAttribute("transform", "scale(1,-1)");
slider.max = String(DATA.t.length - 1);

function points(list) { return list.map(p => `${p[0]},${p[1]}`).join(" "); }

function element(prim) {
  let el;
  if (prim.k === "line") {
    el = document.createElementNS(NS, "polyline");
    el.setAttribute("points", points(prim.p));
    el.setAttribute("fill", "none");
    el.setAttribute("stroke-width", prim.w);
    el.setAttribute("stroke-linecap", "round");
    if (prim.d) el.setAttribute("stroke-dasharray", "6 4");
  } else if (prim.k === "poly") {
    el = document.createElementNS(NS, "polygon");
    el.setAttribute("points", points(prim.p));
    el.setAttribute("fill", prim.f);
    el.setAttribute("stroke-width", 1);
  } else {
    el = document.createElementNS(NS, "circle");
    el.setAttribute("cx", prim.p[0]);
    el.setAttribute("cy", prim.p[1]);
    el.setAttribute("r", prim.r);
    el.setAttribute("fill", prim.f);
    el.setAttribute("stroke-width", 1);
  }
  el.setAttribute("stroke", prim.c);
  el.setAttribute("vector-effect", "non-scaling-stroke");
  return el;
}

let current = 0;
function show(index) {
  current = Math.max(0, Math.min(DATA.t.length - 1, index));
  frameGroup.replaceChildren(...DATA.frames[current].map(element));
  slider.value = String(current);
  timeLabel.textContent = `t = ${DATA.t[current].toFixed(2)} s`;
  readout.textContent = DATA.readouts[current];
}

let playing = false, lastStamp = null, simTime = 0;
function tick(stamp) {
  if (!playing) return;
  if (lastStamp !== null) simTime += (stamp - lastStamp) / 1000 * Number(speedSelect.value);
  lastStamp = stamp;
  let index = current;
  while (index < DATA.t.length - 1 && DATA.t[index + 1] <= simTime) index++;
  show(index);
  if (index >= DATA.t.length - 1) { stop(); return; }
  requestAnimationFrame(tick);
}
function start() {
  if (current >= DATA.t.length - 1) show(0);
  playing = true; lastStamp = null; simTime = DATA.t[current];
  playButton.textContent = "Pause";
  requestAnimationFrame(tick);
}
function stop() { playing = false; playButton.textContent = "Play"; }
playButton.addEventListener("click", () => (playing ? stop() : start()));
slider.addEventListener("input", () => { stop(); show(Number(slider.value)); });
show(0);
</script>
</body>
</html>
"""
