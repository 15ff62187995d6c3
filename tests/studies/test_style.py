"""studies.style: no two controllers of a case drawn with one marker shape (turned or mirrored).

Two markers are of one shape family when their filled outlines, each scaled to a circumradius of 1
about the marker's centre, overlap by at least 80 % (intersection over union) at the best turn and
mirroring. The measure is checked on the pairs that looked alike before: matplotlib's "X" is "P"
turned by 45°, "8" (an octagon) is nearly "o".
"""

import itertools

import numpy as np
import pytest
from matplotlib.markers import MarkerStyle
from matplotlib.transforms import Affine2D

from studies import cases, style

SAME_FAMILY = 0.8
GRID = np.linspace(-1.05, 1.05, 61)
POINTS = np.c_[np.meshgrid(GRID, GRID)[0].ravel(), np.meshgrid(GRID, GRID)[1].ravel()]
TURNS = range(0, 360, 5)


def _masks(marker) -> list:
    """The filled marker on a grid at every turn of TURNS, plain and mirrored, circumradius 1."""
    shape = MarkerStyle(marker)
    path = shape.get_path().transformed(shape.get_transform())
    radius = np.max(np.hypot(*path.vertices.T))
    masks = []
    for mirror in (1, -1):
        for turn in TURNS:
            moved = path.transformed(Affine2D().scale(mirror / radius, 1 / radius).rotate_deg(turn))
            masks.append(moved.contains_points(POINTS))
    return masks


def overlap(a, b) -> float:
    """Largest intersection over union of the filled markers a and b over turns and mirrorings of b."""
    first = _masks(a)[0]
    return max(float((first & m).sum() / (first | m).sum()) for m in _masks(b))


def test_the_measure_finds_the_lookalikes():
    assert overlap("X", "P") > 0.95
    assert overlap("o", "8") > 0.9
    assert overlap("s", "D") > 0.95
    assert overlap("o", "s") < SAME_FAMILY


@pytest.mark.parametrize("name", cases.names())
def test_no_two_controllers_of_a_case_share_a_shape(name):
    labels = [label for label in cases.get(name).controllers if label in style.TABLE]
    assert len(labels) == len(cases.get(name).controllers)
    masks = {label: _masks(style.of(label).marker) for label in labels}
    worst = max(
        (
            max(float((masks[a][0] & m).sum() / (masks[a][0] | m).sum()) for m in masks[b]),
            a,
            b,
        )
        for a, b in itertools.combinations(labels, 2)
    )
    assert worst[0] < SAME_FAMILY, worst
