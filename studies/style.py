"""The one style table: a colour, a line style and a marker per controller, the same on every plot and page.

The case studies' controllers have fixed, distinct entries (no two share a
colour); any other label (a user's controller) gets one picked from its name
by a stable hash, so it too looks the same on every plot of every plant.
Verdicts have their own symbols and colours for tables, heat maps and scatters.
States are shown in the units of `display_unit`: angles in degrees, lengths in metres.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from models import specs


def is_angle(name: str) -> bool:
    """Whether a coordinate of the case plants is an angle (θ…, φ…), drawn and printed in degrees."""
    return name.startswith(("theta", "phi"))


def display_unit(name: str) -> tuple[float, str]:
    """(factor, unit) to show a state of the case plants: angles in deg, lengths in m, their rates per s."""
    rate = name.startswith("d") and len(name) > 1
    base = name[1:] if rate else name
    scale, unit = (180 / math.pi, "deg") if is_angle(base) else (1.0, "m")
    return scale, unit + ("/s" if rate else "")


@dataclass(frozen=True)
class Style:
    """How one controller is drawn: colour (hex), matplotlib line style, marker shape.

    `shape` is a matplotlib marker name ("o"), a regular star or polygon (sides, style, angle), or a
    filled polygon's vertices ((x, y), ...) within [-1, 1]; `marker` gives it to matplotlib.
    """

    color: str
    linestyle: str
    shape: str | tuple

    @property
    def marker(self) -> Any:  # str, (sides, style, angle) or an (n, 2) array: what matplotlib takes
        """The matplotlib marker: the name or (sides, style, angle) as given, a polygon as an (n, 2) array."""
        if isinstance(self.shape, tuple) and self.shape and isinstance(self.shape[0], tuple):
            return np.asarray(self.shape, dtype=float)
        return self.shape

    def line(self, linewidth: float = 1.3) -> dict:
        """Keyword arguments of `Axes.plot` for this controller's lines."""
        return {"color": self.color, "linestyle": self.linestyle, "linewidth": linewidth}

    @property
    def dash(self) -> str:
        """The line style as an SVG stroke-dasharray (in units of the stroke width), "" for solid."""
        return {"-": "", "--": "6 3", "-.": "6 3 1.5 3", ":": "1.5 2.5"}[self.linestyle]


def _closed(points) -> tuple:
    """A filled marker's vertices: the polygon through `points` (x, y within [-1, 1]), closed."""
    return (*map(tuple, points), tuple(points[0]))


def _crescent(n: int = 16) -> tuple:
    """A crescent opening right: the unit circle's arc from 50° to 310° and back along a circle about
    (0.45, 0) through the same two ends."""
    top = (math.cos(math.radians(50)), math.sin(math.radians(50)))
    radius = math.hypot(top[0] - 0.45, top[1])
    end = math.atan2(top[1], top[0] - 0.45)
    outer = [(math.cos(a), math.sin(a)) for a in np.linspace(math.radians(50), math.radians(310), 2 * n)]
    inner = [(0.45 + radius * math.cos(a), radius * math.sin(a)) for a in np.linspace(2 * math.pi - end, end, n)]
    return _closed(outer + inner[1:-1])


_half = [(math.cos(math.pi * k / 24), math.sin(math.pi * k / 24) - 0.4) for k in range(25)]
#: Marker shapes of their own, beside matplotlib's: a half disc, a bar, a bow tie, an arrow, a crescent.
HALF_DISC = _closed(_half)
CRESCENT = _crescent()
BAR = _closed([(-1, -0.35), (1, -0.35), (1, 0.35), (-1, 0.35)])
BOW_TIE = _closed([(-1, -0.8), (0, -0.15), (1, -0.8), (1, 0.8), (0, 0.15), (-1, 0.8)])
ARROW = _closed([(-1, -0.3), (0.2, -0.3), (0.2, -0.8), (1, 0), (0.2, 0.8), (0.2, 0.3), (-1, 0.3)])

#: The controllers of the case studies, in the registry's table order, and their styles. No two
#: markers are one shape turned or mirrored (tests/studies/test_style.py measures their overlap):
#: matplotlib's "X" is "P" turned, "8", "h" and "p" are nearly "o", "D" is "s" turned, the triangles
#: one shape (and a star of 3 points is one too), so each family is used once; stars of 6 and 8
#: points, card suits and the shapes above make up the rest.
TABLE = {
    "PD": Style("#1f77b4", "-", "o"),
    "PID": Style("#ff7f0e", "-", "s"),
    "PID (no anti-windup)": Style("#843c39", ":", "d"),
    "loopshaped": Style("#9467bd", "-.", "^"),
    "lead-lag (IV.11)": Style("#e377c2", "-.", BOW_TIE),
    "PD (zero-cancelling filter)": Style("#17becf", "--", HALF_DISC),
    "pole placement": Style("#2ca02c", "-", (6, 1, 0)),
    "pole placement + integrator": Style("#bcbd22", "--", (8, 1, 0)),
    "observer-based": Style("#7f7f7f", "-.", CRESCENT),
    "disturbance observer": Style("#d62728", ":", "*"),
    "LQR": Style("#393b79", "-", "P"),
    "LQR + Kalman": Style("#e7ba52", "--", "$\u2663$"),
    "linear MPC": Style("#000000", "-", BAR),
    "nonlinear MPC": Style("#7b4173", "--", ARROW),
    "tuned": Style("#8c564b", "-", "$\u2665$"),
}

#: Colours, line styles and markers for labels not in `TABLE`, picked by a hash of the label.
_EXTRA_COLORS = (
    "#637939",
    "#3182bd",
    "#e6550d",
    "#31a354",
    "#756bb1",
    "#636363",
    "#d6616b",
    "#ce6dbd",
    "#8ca252",
    "#bd9e39",
    "#6b6ecf",
    "#ad494a",
)
_EXTRA_LINES = ("-", "--", "-.", ":")
_EXTRA_MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*")

#: The reference (command) line and the actuator limit.
REFERENCE = {"color": "#444444", "linestyle": (0, (4, 3)), "linewidth": 1.0}
LIMIT_COLOR = "#c00000"


def of(label: str) -> Style:
    """The style of controller `label` (fixed for the case studies' labels, hashed for others)."""
    if label in TABLE:
        return TABLE[label]
    code = zlib.crc32(str(label).encode("utf-8"))
    return Style(
        _EXTRA_COLORS[code % len(_EXTRA_COLORS)],
        _EXTRA_LINES[(code >> 8) % len(_EXTRA_LINES)],
        _EXTRA_MARKERS[(code >> 16) % len(_EXTRA_MARKERS)],
    )


#: Verdict label -> (symbol, colour) used in tables, the heat map and the scatters.
VERDICTS = {
    specs.MEETS: ("✓", "#1a7f37"),
    specs.VIOLATES: ("✗", "#b35900"),
    specs.LIMIT_CYCLE: ("∿", "#8250df"),
    specs.DIVERGED: ("†", "#cf222e"),
    specs.FAILED: ("!", "#cf222e"),
    specs.SKIPPED: ("–", "#6e7781"),
}


def verdict_symbol(label: str) -> str:
    """The one-character symbol of a verdict label ("?" for an unknown one)."""
    return VERDICTS.get(str(label), ("?", "#6e7781"))[0]


def verdict_color(label: str) -> str:
    """The colour (hex) of a verdict label (grey for an unknown one)."""
    return VERDICTS.get(str(label), ("?", "#6e7781"))[1]


def legend_columns(labels, width_inches: float, fontsize: float = 7.0, handle_points: float = 30.0) -> int:
    """How many legend columns of `labels` fit across `width_inches` at `fontsize` (at least 1)."""
    longest = max((len(str(label)) for label in labels), default=1)
    column = handle_points + 0.55 * fontsize * longest + 12  # points: handle, text, padding
    return max(1, min(len(list(labels)) or 1, int(width_inches * 72 // column)))
