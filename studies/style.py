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
    """How one controller is drawn: colour (hex), matplotlib line style, marker."""

    color: str
    linestyle: str
    marker: str

    def line(self, linewidth: float = 1.3) -> dict:
        """Keyword arguments of `Axes.plot` for this controller's lines."""
        return {"color": self.color, "linestyle": self.linestyle, "linewidth": linewidth}

    @property
    def dash(self) -> str:
        """The line style as an SVG stroke-dasharray (in units of the stroke width), "" for solid."""
        return {"-": "", "--": "6 3", "-.": "6 3 1.5 3", ":": "1.5 2.5"}[self.linestyle]


#: The controllers of the case studies, in the registry's table order, and their styles.
TABLE = {
    "PD": Style("#1f77b4", "-", "o"),
    "PID": Style("#ff7f0e", "-", "s"),
    "PID (no anti-windup)": Style("#843c39", ":", "D"),
    "loopshaped": Style("#9467bd", "-.", "^"),
    "lead-lag (IV.11)": Style("#e377c2", "-.", "v"),
    "PD (zero-cancelling filter)": Style("#17becf", "--", "<"),
    "pole placement": Style("#2ca02c", "-", ">"),
    "pole placement + integrator": Style("#bcbd22", "--", "p"),
    "observer-based": Style("#7f7f7f", "-.", "h"),
    "disturbance observer": Style("#d62728", ":", "*"),
    "LQR": Style("#393b79", "-", "X"),
    "LQR + Kalman": Style("#e7ba52", "--", "P"),
    "linear MPC": Style("#000000", "-", "d"),
    "nonlinear MPC": Style("#7b4173", "--", "8"),
    "tuned": Style("#8c564b", "-", "H"),
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
