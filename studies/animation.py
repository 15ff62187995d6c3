"""Animations of a plant from its simulated state: a GIF and a self-contained HTML page.

Each case draws its plant once, in its case file, as a list of primitives
(`studies.drawing`: lines, polygons, circles) in world coordinates (m, y up)
computed from the state and the plant's own parameters. The GIF renders the
primitives with matplotlib; the HTML page embeds them as JSON and an inline
script draws them in SVG, with a play button and a time slider (the text's
slider-driven animation, homework .2), a picker of the controller shown, an
optional faint "ghost" of a second controller, and the commanded input beside
the drawing with the actuator limit. The reference marker carries a label.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from models import deferred, files

from . import style, templates
from .drawing import GROUND, REFERENCE, text

if TYPE_CHECKING:
    from matplotlib.artist import Artist

# Matplotlib and Pillow are imported at the first GIF, not with the writers; the frames are drawn on an
# Agg canvas of their own (no pyplot, no global backend).
mpl_figure = deferred.module("matplotlib.figure")
mpl_lines = deferred.module("matplotlib.lines")
mpl_patches = deferred.module("matplotlib.patches")
backend_agg = deferred.module("matplotlib.backends.backend_agg")
pil_image = deferred.module("PIL.Image")


def draw(case, plant, x, reference: float) -> list:
    """Primitives of the case's drawing of `plant` in state x (nx,), the tracked coordinate's reference marked
    and labelled (`label_target`)."""
    if case.drawing is None:
        raise ValueError(f"the {case.plant} case has no drawing")
    shapes = case.drawing(
        dict(plant.params), dict(zip(plant.state_names, np.asarray(x, dtype=float))), float(reference)
    )
    return label_target(shapes, target_text(case, reference))


def target_text(case, reference: float) -> str:
    """ "target θ = 50°" / "target z = 2 m": the reference of the tracked coordinate, angles in degrees."""
    symbol = {"theta": "θ", "phi": "φ", "z": "z", "x": "x"}.get(case.tracked, case.tracked)
    if case.tracked_unit == "rad":
        return f"target {symbol} = {math.degrees(reference):.3g}°"
    return f"target {symbol} = {reference:.3g} {case.tracked_unit}"


def label_target(shapes: list, label: str) -> list:
    """`shapes` with a text label beside the first primitive drawn in the reference colour.

    The label goes past the marker, away from the centre of the other primitives, by a
    tenth of the drawing's size. Without such a primitive the shapes are returned unchanged.
    """
    marks = [prim for prim in shapes if prim.get("c") == REFERENCE or prim.get("f") == REFERENCE]
    if not marks:
        return shapes
    mark = np.array(marks[0]["p"] if marks[0]["k"] != "circle" else [marks[0]["p"]], dtype=float)
    others = [
        q
        for prim in shapes
        if prim is not marks[0] and prim["k"] != "text" and not is_track(prim)
        for q in (prim["p"] if prim["k"] != "circle" else [prim["p"]])
    ]
    everything = np.vstack([mark, np.array(others, dtype=float).reshape(-1, 2)])
    size = float(np.max(np.ptp(everything, axis=0))) or 1.0
    if marks[0]["k"] == "line":
        anchor = mark[-1]  # a reference line's far end
    else:
        anchor = mark.mean(axis=0)
    center = np.array(others, dtype=float).reshape(-1, 2).mean(axis=0) if others else anchor - [0, 1]
    away = anchor - center
    away = away / (np.linalg.norm(away) or 1.0)
    if marks[0]["k"] != "line":
        away = np.array([0.0, -1.0 if away[1] <= 0 else 1.0])  # markers sit on a rail or beam: label below/above
    spot = anchor + 0.1 * size * away
    return [*shapes, text(tuple(spot), label, REFERENCE)]


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
        readouts.append(readout(plant, run.x[k]))
    return times[: len(shapes)], shapes, readouts


def readout(plant, x) -> str:
    """The coordinates of state `x` as the page prints them: "z = 0.123 m, theta = 45.0 deg"."""
    parts = []
    for name, value in zip(plant.coordinate_names, x[: plant.nq]):
        scale, unit = style.display_unit(name)
        parts.append(f"{name} = {value * scale:.{1 if style.is_angle(name) else 3}f} {unit}")
    return ", ".join(parts)


def is_track(prim: dict) -> bool:
    """Whether a primitive is a long ground line or track (left out of views and label placement)."""
    return prim["k"] == "line" and prim["c"] == GROUND and prim["w"] == 2


def view(shapes: list, margin: float = 0.08) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) holding every point of every frame, with a margin.

    Long ground and track lines are left out so the view follows the plant.
    """
    xs, ys = [], []
    for frame in shapes:
        for prim in frame:
            if is_track(prim):
                continue
            if prim["k"] == "circle":
                (cx, cy), rad = prim["p"], prim["r"]
                xs += [cx - rad, cx + rad]
                ys += [cy - rad, cy + rad]
            elif prim["k"] == "text":
                xs.append(prim["p"][0])
                ys.append(prim["p"][1])
            else:
                xs += [q[0] for q in prim["p"]]
                ys += [q[1] for q in prim["p"]]
    xmin, xmax, ymin, ymax = min(xs), max(xs), min(ys), max(ys)
    pad = margin * max(xmax - xmin, ymax - ymin)
    return xmin - pad, xmax + pad, ymin - pad, ymax + pad


# ------------------------------------------------------------------------------- GIF
def write_gif(
    path: Path, case, plant, run, label: str, max_frames: int = 100, dpi: int = 80, frame_ms: int | None = None
) -> Path:
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
    fig = mpl_figure.Figure(figsize=(5.0, height))
    canvas = backend_agg.FigureCanvasAgg(fig)
    ax = fig.add_axes((0.02, 0.02, 0.96, 1 - 0.75 / height))
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
        images.append(pil_image.frombuffer("RGBA", canvas.get_width_height(), canvas.buffer_rgba()).convert("RGB"))
    palette = images[len(images) // 2].quantize(colors=64)
    frames_p = [im.quantize(palette=palette, dither=pil_image.Dither.NONE) for im in images]
    with files.atomic_path(path) as tmp:
        frames_p[0].save(
            tmp, format="GIF", save_all=True, append_images=frames_p[1:], duration=frame_ms, loop=0, optimize=False
        )
    return path


def _artist(ax, prim: dict, dpi: int) -> Artist:
    """The matplotlib artist of primitive `prim` (`studies.drawing`), added to `ax`; a line `w` wide is
    drawn `w` pixels wide at `dpi` dots per inch, as the SVG page draws it."""
    width = prim.get("w", 1.0) * 72 / dpi
    artist: Artist
    if prim["k"] == "line":
        points = np.array(prim["p"])
        artist = mpl_lines.Line2D(
            points[:, 0],
            points[:, 1],
            color=prim["c"],
            linewidth=width,
            linestyle="--" if prim["d"] else "-",
            solid_capstyle="round",
        )
        ax.add_line(artist)
    elif prim["k"] == "poly":
        artist = mpl_patches.Polygon(prim["p"], closed=True, facecolor=prim["f"], edgecolor=prim["c"], linewidth=1)
        ax.add_patch(artist)
    elif prim["k"] == "text":
        artist = ax.text(*prim["p"], prim["s"], color=prim["c"], fontsize=7, ha="center", va="center")
    else:
        artist = mpl_patches.Circle(prim["p"], prim["r"], facecolor=prim["f"], edgecolor=prim["c"], linewidth=1)
        ax.add_patch(artist)
    return artist


def _update(artist, prim: dict) -> None:
    """Move `artist` (made by `_artist` from a primitive of the same kind) to primitive `prim`'s place."""
    if prim["k"] == "line":
        points = np.array(prim["p"])
        artist.set_data(points[:, 0], points[:, 1])
    elif prim["k"] == "poly":
        artist.set_xy(prim["p"])
    elif prim["k"] == "text":
        artist.set_position(prim["p"])
        artist.set_text(prim["s"])
    else:
        artist.set_center(prim["p"])
        artist.set_radius(prim["r"])


# ------------------------------------------------------------------------------- HTML
def _rounded(value, digits: int = 4):
    """`value` (a float, or lists and dicts of them) with every float rounded to `digits` decimals: the page's
    data stay small."""
    if isinstance(value, float):
        return round(value, digits)
    if isinstance(value, list):
        return [_rounded(v, digits) for v in value]
    if isinstance(value, dict):
        return {k: _rounded(v, digits) for k, v in value.items()}
    return value


def write_html(
    path: Path,
    case,
    plant,
    runs: Mapping[str, Any],
    selected: str | None = None,
    caption: str = "",
    max_frames: int = 300,
    verdicts: dict | None = None,
    *,
    scenario: str,
) -> Path:
    """A self-contained HTML page (inline SVG and script) animating the runs of several controllers.

    Parameters
    ----------
    runs : controller label -> ClosedLoopResult (the same scenario), in picker order
    selected : the label shown first (default: the first)
    max_frames : frames kept per run (subsampled evenly, the last always kept)
    verdicts : label -> verdict text, shown in the picker and beside the title
    scenario : what the runs show, the page's title after the plant's (the scenario's or the problem's words)
    """
    runs = dict(runs)
    if not runs:
        raise ValueError("write_html needs at least one run")
    selected = next(iter(runs)) if selected is None else selected
    if selected not in runs:
        raise ValueError(f"selected controller {selected!r} is not among the runs: {', '.join(runs)}")
    data = {
        "order": list(runs),
        "selected": selected,
        "runs": {},
        "input": plant.input_names[0],
        "input_unit": case.input_unit,
        "verdicts": dict(verdicts or {}),
        "colors": {label: style.of(label).color for label in runs},
    }
    for label, run in runs.items():
        data["runs"][label] = run_data(case, plant, run, max_frames)
    page = templates.render("animation.html.j2", title=f"{plant.title}: {scenario}", caption=caption, data=data)
    return files.write_text(path, page)


def run_data(case, plant, run, max_frames: int) -> dict:
    """What the page holds of one run: frame times (s), primitives, readouts, view box, command and limit."""
    times, shapes, readouts = frames(case, plant, run, max_frames)
    xmin, xmax, ymin, ymax = view(shapes)
    digits = max(3, 3 - int(math.floor(math.log10(max(xmax - xmin, ymax - ymin)))) + 1)
    index = np.searchsorted(run.t, times - 1e-9)
    command = run.u[np.minimum(index, len(run.u) - 1), 0]
    return {
        "t": [round(float(t), 4) for t in times],
        "frames": _rounded(shapes, digits),
        "readouts": readouts,
        "view": [xmin, ymin, xmax - xmin, ymax - ymin],
        "u": [round(float(v), 5) for v in command],
        "limit": float(np.max(run.input_limit)),
    }
