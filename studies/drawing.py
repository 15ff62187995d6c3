"""Drawing primitives of the animations: lines, polygons and circles in world coordinates (m, y up).

A case's drawing is a function (params dict, state dict, reference value) ->
list of these primitives, computed from the state and the plant's own
parameters; `studies.animation` renders the list as GIF frames and as SVG.
"""

from __future__ import annotations

import math

BODY, ACCENT, REFERENCE, GROUND = "#1f4e79", "#e07b00", "#c00000", "#555555"


def line(points, color=BODY, width=3.0, dashed=False) -> dict:
    """A polyline through `points` [(x, y), ...]; width in points."""
    return {"k": "line", "p": [list(p) for p in points], "c": color, "w": width, "d": dashed}


def polygon(points, fill=BODY, stroke=BODY) -> dict:
    """A closed, filled polygon."""
    return {"k": "poly", "p": [list(p) for p in points], "f": fill, "c": stroke}


def circle(center, radius, fill=ACCENT, stroke=BODY) -> dict:
    """A filled circle of `radius` (m) about `center`."""
    return {"k": "circle", "p": list(center), "r": radius, "f": fill, "c": stroke}


def rotated_rectangle(center, length, width, angle) -> list:
    """Corners of a `length` × `width` rectangle about `center`, turned by `angle` (rad)."""
    c, s = math.cos(angle), math.sin(angle)
    half = [(length / 2, width / 2), (-length / 2, width / 2), (-length / 2, -width / 2), (length / 2, -width / 2)]
    return [(center[0] + c * a - s * b, center[1] + s * a + c * b) for a, b in half]


def marker(x, y, size, up=True) -> list:
    """A small triangle pointing at (x, y) from below (up=True) or above."""
    h = size if up else -size
    return [(x, y), (x - size / 2, y - h), (x + size / 2, y - h)]


def text(position, string: str, color=REFERENCE) -> dict:
    """A text label centred at `position` (world coordinates, m)."""
    return {"k": "text", "p": list(position), "s": str(string), "c": color}
