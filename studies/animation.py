"""Animations of a plant from its simulated state: a GIF and a self-contained HTML page.

Each plant is drawn once, here, as a list of primitives (lines, polygons,
circles) in world coordinates (m, y up) computed from the state and the
plant's own parameters (ℓ, ℓ1, ℓ2, ...). The GIF renders the primitives with
matplotlib; the HTML page embeds them as JSON and an inline script draws them
in SVG, with a play button and a time slider (the text's slider-driven
animation, homework .2). The satellite and the UUV have no lengths among
their parameters; they are drawn with unit dimensions.
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Callable

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Circle, Polygon  # noqa: E402
from PIL import Image  # noqa: E402

from models import files  # noqa: E402

BODY, ACCENT, REFERENCE, GROUND = "#1f4e79", "#e07b00", "#c00000", "#555555"


def _line(points, color=BODY, width=3.0, dashed=False) -> dict:
    return {"k": "line", "p": [list(p) for p in points], "c": color, "w": width, "d": dashed}


def _polygon(points, fill=BODY, stroke=BODY) -> dict:
    return {"k": "poly", "p": [list(p) for p in points], "f": fill, "c": stroke}


def _circle(center, radius, fill=ACCENT, stroke=BODY) -> dict:
    return {"k": "circle", "p": list(center), "r": radius, "f": fill, "c": stroke}


def _rotated_rectangle(center, length, width, angle) -> list:
    c, s = math.cos(angle), math.sin(angle)
    half = [(length / 2, width / 2), (-length / 2, width / 2), (-length / 2, -width / 2), (length / 2, -width / 2)]
    return [(center[0] + c * a - s * b, center[1] + s * a + c * b) for a, b in half]


def _marker(x, y, size, up=True) -> list:
    """A small triangle pointing at (x, y) from below (up=True) or above."""
    h = size if up else -size
    return [(x, y), (x - size / 2, y - h), (x + size / 2, y - h)]


# ------------------------------------------------------------------------------- the plants
def _arm(p: dict, s: dict, r: float) -> list:
    ell, th = p["ell"], s["theta"]
    tip = (ell * math.cos(th), ell * math.sin(th))
    return [
        _polygon([(-0.15 * ell, -0.3 * ell), (0.15 * ell, -0.3 * ell), (0, 0)], fill=GROUND, stroke=GROUND),
        _line([(0, 0), (ell * 1.1 * math.cos(r), ell * 1.1 * math.sin(r))], REFERENCE, 1.5, True),
        _line([(0, 0), tip], BODY, 8),
        _circle((0, 0), 0.04 * ell, ACCENT),
    ]


def _pendulum(p: dict, s: dict, r: float) -> list:
    ell, z, th = p["ell"], s["z"], s["theta"]
    width, height = 0.6 * ell, 0.3 * ell
    pivot = (z, height)
    bob = (z + ell * math.sin(th), height + ell * math.cos(th))
    return [
        _line([(z - 40 * ell, 0), (z + 40 * ell, 0)], GROUND, 2),
        _polygon(_marker(r, 0, 0.12 * ell), REFERENCE, REFERENCE),
        _polygon([(z - width / 2, 0), (z + width / 2, 0), (z + width / 2, height), (z - width / 2, height)]),
        _line([pivot, bob], GROUND, 3),
        _circle(bob, 0.08 * ell, ACCENT),
    ]


def _satellite(p: dict, s: dict, r: float) -> list:
    th, ph = s["theta"], s["phi"]
    panel = []
    for side in (1, -1):
        center = (side * 1.5 * math.cos(ph), side * 1.5 * math.sin(ph))
        panel.append(_polygon(_rotated_rectangle(center, 2.0, 0.25, ph), fill=ACCENT, stroke=BODY))
    return [
        _line([(-3 * math.cos(r), -3 * math.sin(r)), (3 * math.cos(r), 3 * math.sin(r))], REFERENCE, 1.5, True),
        *panel,
        _line([(-0.5 * math.cos(ph), -0.5 * math.sin(ph)), (0.5 * math.cos(ph), 0.5 * math.sin(ph))], GROUND, 2),
        _polygon(_rotated_rectangle((0, 0), 1.0, 1.0, th)),
    ]


def _uuv(p: dict, s: dict, r: float) -> list:
    phi = s["phi"]
    up = (-math.sin(phi), math.cos(phi))        # the vehicle's mast direction, upright at phi = 0
    ref = (-math.sin(r), math.cos(r))
    hull = [(math.cos(a), 0.8 * math.sin(a)) for a in np.linspace(0, 2 * math.pi, 25)[:-1]]
    c, sn = math.cos(phi), math.sin(phi)
    hull = [(c * x - sn * y, sn * x + c * y) for x, y in hull]
    return [
        _line([(-1.8, 1.2), (1.8, 1.2)], GROUND, 1.5),
        _line([(-1.6 * ref[0], -1.6 * ref[1]), (1.6 * ref[0], 1.6 * ref[1])], REFERENCE, 1.5, True),
        _polygon(hull, fill=BODY, stroke=BODY),
        _line([(0.8 * up[0], 0.8 * up[1]), (1.3 * up[0], 1.3 * up[1])], ACCENT, 5),
        _line([(-0.8 * up[0], -0.8 * up[1]), (-1.2 * up[0], -1.2 * up[1])], ACCENT, 5),
    ]


def _ballbeam(p: dict, s: dict, r: float) -> list:
    ell, z, th = p["ell"], s["z"], s["theta"]
    along, normal = (math.cos(th), math.sin(th)), (-math.sin(th), math.cos(th))
    radius = 0.04 * ell
    ball = (z * along[0] + radius * normal[0], z * along[1] + radius * normal[1])
    mark = (r * along[0] - 0.01 * ell * normal[0], r * along[1] - 0.01 * ell * normal[1])
    return [
        _polygon([(-0.06 * ell, -0.15 * ell), (0.06 * ell, -0.15 * ell), (0, 0)], fill=GROUND, stroke=GROUND),
        _line([(0, 0), (ell * along[0], ell * along[1])], BODY, 6),
        _polygon([mark, (mark[0] - 0.03 * ell * normal[0] - 0.02 * ell * along[0],
                         mark[1] - 0.03 * ell * normal[1] - 0.02 * ell * along[1]),
                  (mark[0] - 0.03 * ell * normal[0] + 0.02 * ell * along[0],
                   mark[1] - 0.03 * ell * normal[1] + 0.02 * ell * along[1])], REFERENCE, REFERENCE),
        _circle(ball, radius, ACCENT),
    ]


def _crane(p: dict, s: dict, r: float) -> list:
    x = s["x"]
    ell1, ell2 = p["ell1"], p["ell2"]
    width, height = 0.3 * ell1, 0.12 * ell1
    shapes = [
        _line([(x - 10 * ell2, height), (x + 10 * ell2, height)], GROUND, 2),
        _polygon(_marker(r, height, 0.08 * ell1, up=False), REFERENCE, REFERENCE),
        _polygon([(x - width / 2, 0), (x + width / 2, 0), (x + width / 2, height), (x - width / 2, height)]),
    ]
    for ell, th, mass in ((ell1, s["theta1"], p["m1"]), (ell2, s["theta2"], p["m2"])):
        load = (x + ell * math.sin(th), -ell * math.cos(th))
        shapes.append(_line([(x, 0), load], GROUND, 1.5))
        shapes.append(_circle(load, 0.05 * ell1 * (mass / p["m1"]) ** (1 / 3), ACCENT))
    return shapes


#: plant name -> drawing (params dict, state dict, reference value) -> primitives
DRAWINGS: dict[str, Callable] = {"arm": _arm, "pendulum": _pendulum, "satellite": _satellite, "uuv": _uuv,
                                 "ballbeam": _ballbeam, "crane": _crane}


def draw(plant, x, reference: float) -> list:
    """Primitives of `plant` in state x (nx,) with the tracked coordinate's reference marked."""
    if plant.name not in DRAWINGS:
        raise ValueError(f"no drawing for {plant.name!r}; drawings exist for {', '.join(DRAWINGS)}")
    return DRAWINGS[plant.name](dict(plant.params), dict(zip(plant.state_names, np.asarray(x, dtype=float))),
                                float(reference))


# ------------------------------------------------------------------------------- frames
def frames(plant, run, max_frames: int) -> tuple[np.ndarray, list, list]:
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
        shapes.append(draw(plant, run.x[k], run.r[k, 0]))
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
def write_gif(path: Path, plant, run, label: str, max_frames: int = 100, dpi: int = 80,
              frame_ms: int | None = None) -> Path:
    """An animated GIF of the run, at most `max_frames` frames, real time or faster.

    Frames last at least 40 ms (browsers slow down faster GIFs); a long run
    plays faster than real time and the caption says how much.
    """
    times, shapes, readouts = frames(plant, run, max_frames)
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


def write_html(path: Path, plant, run, label: str, caption: str = "", max_frames: int = 800) -> Path:
    """A self-contained HTML page (inline SVG and script) animating the run, with play button and slider."""
    times, shapes, readouts = frames(plant, run, max_frames)
    xmin, xmax, ymin, ymax = view(shapes)
    digits = max(3, 3 - int(math.floor(math.log10(max(xmax - xmin, ymax - ymin)))) + 1)
    data = {"t": [round(float(t), 4) for t in times], "frames": _rounded(shapes, digits), "readouts": readouts,
            "view": [xmin, ymin, xmax - xmin, ymax - ymin]}
    page = _TEMPLATE.replace("__TITLE__", html.escape(f"{plant.title}: {label}"))
    page = page.replace("__CAPTION__", html.escape(caption))
    # </script> cannot occur in JSON of numbers and plain labels; escape '<' anyway.
    page = page.replace("__DATA__", json.dumps(data, separators=(",", ":")).replace("<", "\\u003c"))
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
