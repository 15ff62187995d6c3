"""The index page's scatter (studies.overview.scatter_figure): the case's step specs drawn, the ∞ mark
clear of the titles (text boxes measured with the Agg renderer)."""

import math

import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg

from studies import cases, overview


def _studies(name="arm"):
    table = pd.DataFrame(
        {
            "controller": ["PD", "LQR", "nonlinear MPC"],
            "scenario": ["step"] * 3,
            "settling_time_s": [1.5, math.inf, 0.8],
            "overshoot_pct": [5.0, 20.0, 0.0],
            "verdict": ["meets specs", "violates", "meets specs"],
        }
    )
    return [(name, {"title": "Single-link arm: a very long title to reach the axes' right edge"}, table)]


def test_the_step_specs_are_dashed_lines():
    spec = cases.get("arm").specs["*"]  # the arm judges every scenario by one set of specs
    fig = overview.scatter_figure(_studies())
    ax = fig.axes[0]
    limits = [line for line in ax.get_lines() if line.get_gid() == "spec-limit"]
    vertical = [line for line in limits if line.get_xdata()[0] == line.get_xdata()[1]]
    horizontal = [line for line in limits if line.get_ydata()[0] == line.get_ydata()[1]]
    assert [line.get_xdata()[0] for line in vertical] == [spec.max_settling_time_s]
    assert [line.get_ydata()[0] for line in horizontal] == [spec.max_overshoot_pct]
    assert all(line.get_linestyle() == "--" for line in limits)
    assert ax.get_xlim()[1] > spec.max_settling_time_s  # the line is inside the axes


def test_an_unknown_plant_has_no_spec_lines():
    fig = overview.scatter_figure(_studies("not-a-registered-plant"))
    assert not [line for line in fig.axes[0].get_lines() if line.get_gid() == "spec-limit"]


def test_the_infinity_mark_stays_clear_of_the_titles():
    fig = overview.scatter_figure(_studies())
    renderer = FigureCanvasAgg(fig).get_renderer()
    ax = fig.axes[0]
    labels = ax.get_xticklabels()
    (mark,) = [t for t in labels if t.get_gid() == "not-settled"]
    assert mark.get_text() == "∞"
    box = mark.get_window_extent(renderer)
    assert not box.overlaps(ax.title.get_window_extent(renderer))
    assert not box.overlaps(fig._suptitle.get_window_extent(renderer))
    assert box.y1 <= ax.get_window_extent(renderer).y0  # under the axes, with the tick labels
    assert not any(box.overlaps(t.get_window_extent(renderer)) for t in labels if t is not mark and t.get_text())
