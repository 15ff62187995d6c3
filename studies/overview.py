"""The pictures at the top of index.html: every controller on every plant at a glance.

- a heat map, controllers × plants, of the step's ITAE relative to the best
  on that plant, each cell marked with its verdict (an HTML table, so its
  labels are text);
- per plant, settling time against overshoot of the step, one marker per
  controller, filled where the row meets its specs (an inline SVG);
- per plant, the Monte Carlo spread of the ITAE as box plots per controller
  (an inline SVG).

Everything is read back from the written tables (``OUT/<plant>/table.csv``
and ``monte_carlo.csv``), so the pictures show exactly what the tables hold.
Colours, line styles and markers come from `studies.style`.
"""

from __future__ import annotations

import io
import math
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from models import deferred, specs

from . import cases, judging, style, templates

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure
else:
    pd = deferred.module("pandas")

# Matplotlib is imported at the first picture, not with the writers; the figures are drawn on an SVG
# canvas of their own (no pyplot, no global backend).
matplotlib = deferred.module("matplotlib")
mpl_figure = deferred.module("matplotlib.figure")
mpl_lines = deferred.module("matplotlib.lines")
backend_svg = deferred.module("matplotlib.backends.backend_svg")


def _horizontal() -> dict:
    """Keywords of a horizontal box plot: `orientation` from matplotlib 3.10 on, `vert` before
    (deprecated since)."""
    version = tuple(int(v) for v in matplotlib.__version__.split(".")[:2])
    return {"orientation": "horizontal"} if version >= (3, 10) else {"vert": False}


#: Relative ITAE at which the heat map's colour is fully "bad" (ten times the best on the plant).
WORST_RATIO = 10.0


def controller_order(tables) -> list:
    """Every controller label of the tables: the style table's order first, then others as they appear."""
    seen = []
    for table in tables:
        seen += [str(c) for c in table.controller.unique() if str(c) not in seen]
    known = [label for label in style.TABLE if label in seen]
    return known + [label for label in seen if label not in known]


def step_rows(table):
    """The step scenario's rows of a study table, one per controller."""
    return table[table.scenario == "step"].drop_duplicates("controller").set_index("controller")


def relative_itae(table) -> dict:
    """controller -> step ITAE divided by the smallest finite step ITAE on that plant among the controllers
    whose every row is "ok" and meets its specs (the best, 1×, `judging.meets_everywhere`); NaN everywhere
    when none does (no row is called best) and where a row has no number."""
    rows = step_rows(table)
    itae = rows.itae.astype(float)
    meets = judging.meets_everywhere(table).loc[rows.index]
    finite = itae[np.isfinite(itae) & (itae > 0) & meets]
    best = float(finite.min()) if len(finite) else math.nan
    return {
        label: float(value) / best if np.isfinite(value) and best > 0 else math.nan for label, value in itae.items()
    }


def _ratio_color(ratio: float) -> str:
    """Green at 1x through yellow to red at `WORST_RATIO` x and beyond (log scale); grey without a number."""
    if not np.isfinite(ratio):
        return "#e8e8e8"
    f = min(1.0, max(0.0, math.log10(ratio) / math.log10(WORST_RATIO)))
    stops = [(0.0, (198, 239, 206)), (0.5, (255, 235, 156)), (1.0, (255, 179, 171))]
    for (f0, c0), (f1, c1) in zip(stops, stops[1:]):
        if f <= f1:
            w = (f - f0) / (f1 - f0)
            return "#" + "".join(f"{round(a + w * (b - a)):02x}" for a, b in zip(c0, c1))
    return "#ffb3ab"


def heat_map(studies) -> str:
    """HTML table: rows controllers, columns plants; cell = verdict symbol and step ITAE / best ITAE on the plant.

    Parameters
    ----------
    studies : list of (plant name, run.json dict, table DataFrame)

    Returns
    -------
    The table as one line of HTML (template ``heatmap.html.j2``), every label and title escaped.
    """
    labels = controller_order([t for _, _, t in studies])
    ratios = {name: relative_itae(table) for name, _, table in studies}
    rows = {name: step_rows(table) for name, _, table in studies}
    return templates.render(
        "heatmap.html.j2",
        worst_ratio=f"{WORST_RATIO:g}",
        legend=[
            {"label": label, "symbol": symbol, "color": color} for label, (symbol, color) in style.VERDICTS.items()
        ],
        titles=[info["title"] for _, info, _ in studies],
        rows=[
            {
                "label": label,
                "color": style.of(label).color,
                "cells": [_heat_cell(label, name, rows[name], ratios[name]) for name, _, _ in studies],
            }
            for label in labels
        ],
    )


def _heat_cell(label: str, plant: str, rows, ratios: dict) -> dict:
    """What the heat map shows of controller `label` on `plant` (`rows`: its step rows by controller;
    `ratios`: `relative_itae` of the plant): {"absent": True} when the plant has no such controller."""
    if label not in rows.index:
        return {"absent": True, "plant": plant}
    row = rows.loc[label]
    verdict = str(row.get("verdict", "")) if isinstance(row.get("verdict", ""), str) else ""
    ratio = ratios.get(label, math.nan)
    detail = str(row.get("verdict_detail", "")) if isinstance(row.get("verdict_detail"), str) else ""
    return {
        "absent": False,
        "plant": plant,
        "verdict": verdict,
        "title": f"{label} on {plant}: {verdict}" + (f" ({detail})" if detail else ""),
        "background": _ratio_color(ratio),
        "color": style.verdict_color(verdict),
        "symbol": style.verdict_symbol(verdict),
        "number": f"{ratio:.3g}×" if np.isfinite(ratio) else "",
    }


def _svg(fig: Figure, salt: str) -> str:
    """The figure as an inline SVG element: text kept as text, no date, ids salted per figure."""
    buffer = io.StringIO()
    with matplotlib.rc_context({"svg.fonttype": "none", "svg.hashsalt": salt}):
        backend_svg.FigureCanvasSVG(fig).print_svg(buffer, metadata={"Date": None})
    text = buffer.getvalue()
    text = text[text.index("<svg") :]
    return re.sub(r'<svg([^>]*?) width="[^"]*" height="[^"]*"', r'<svg\1 style="width:100%;height:auto"', text, count=1)


def _grid(count: int, columns: int, width: float, height: float) -> tuple[Figure, list]:
    """A figure `width` inches wide of `count` axes in rows of `columns`, each row `height` inches (plus
    1.2 in for the title and legend); the unused axes of the last row hidden."""
    rows = -(-count // columns)
    fig = mpl_figure.Figure(figsize=(width, height * rows + 1.2))
    axes = np.atleast_1d(fig.subplots(rows, columns, squeeze=False)).ravel()
    for ax in axes[count:]:
        ax.set_visible(False)
    return fig, list(axes[:count])


def _legend(fig: Figure, labels: list, marker: bool = True) -> None:
    """One legend of `labels` (markers, or line styles when `marker` is False) under the axes, with room
    made for its rows; each label's text gets the id ``legend-label-<i>`` in the SVG."""
    handles = [
        mpl_lines.Line2D(
            [],
            [],
            color=style.of(label).color,
            marker=style.of(label).marker if marker else None,
            linestyle="none" if marker else style.of(label).linestyle,
            markersize=7,
        )
        for label in labels
    ]
    ncol = style.legend_columns(labels, fig.get_figwidth(), fontsize=8)
    legend = fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=8, frameon=False)
    for i, text in enumerate(legend.get_texts()):
        text.set_gid(f"legend-label-{i}")  # found by the browser test, and by anyone scripting the page
    rows = -(-len(labels) // ncol)
    below, height = 0.35 + 0.22 * rows, fig.get_figheight()  # inches the legend needs under the axes
    above = height * (1 - fig.subplotpars.top)
    if below + above > 0.6 * height:  # long labels (an infeasibility's text): a taller figure, same axes room
        height = (below + above) / 0.6
        fig.set_figheight(height)
    fig.subplots_adjust(top=1 - above / height, bottom=below / height)


def step_specs(name: str) -> specs.Specs | None:
    """The registered case `name`'s specs of the step (None for a plant the registry does not know)."""
    if name not in cases.names():
        return None
    chosen = cases.get(name).specs
    return chosen.get("step", chosen.get("*"))


def scatter(studies) -> str | None:
    """Inline SVG of `scatter_figure` (None without studies)."""
    fig = scatter_figure(studies)
    return None if fig is None else _svg(fig, "scatter")


def scatter_figure(studies) -> Figure | None:
    """Per plant, settling time (s) against overshoot (%) of the step for every controller.

    Filled markers meet their specs, hollow ones do not; a run that never settles sits on the
    right edge past a dashed grey line, its tick marked ∞ (under the axes, clear of the titles); the case's
    step specs (largest settling time and overshoot) are dashed red lines; rows without numbers
    (skipped, failed, diverged) are left out.
    """
    if not studies:
        return None
    labels = controller_order([t for _, _, t in studies])
    fig, axes = _grid(len(studies), 3, 13.0, 3.6)
    for ax, (name, info, table) in zip(axes, studies):
        rows = step_rows(table)
        settling = rows.settling_time_s.astype(float)
        finite = settling[np.isfinite(settling)]
        spec = step_specs(name)
        limit_s = spec.max_settling_time_s if spec is not None else None
        edge = 1.15 * max(float(finite.max()) if len(finite) else 0.0, limit_s or 0.0) or 1.0
        for label, row in rows.iterrows():
            overshoot, time_ = float(row.overshoot_pct), float(row.settling_time_s)
            if math.isnan(overshoot) or math.isnan(time_):
                continue
            look = style.of(str(label))
            meets = row.get("verdict") == specs.MEETS
            ax.plot(
                [edge if math.isinf(time_) else time_],
                [overshoot],
                linestyle="none",
                marker=look.marker,
                markersize=8,
                markeredgecolor=look.color,
                markerfacecolor=look.color if meets else "none",
                markeredgewidth=1.5,
            )
        limits = {"color": style.LIMIT_COLOR, "linestyle": "--", "linewidth": 0.9, "gid": "spec-limit"}
        if limit_s is not None:
            ax.axvline(limit_s, **limits)
        if spec is not None and spec.max_overshoot_pct is not None:
            ax.axhline(spec.max_overshoot_pct, **limits)
        if len(finite) < len(settling.dropna()):
            cut = edge / 1.15 * 1.075
            ax.axvline(cut, color="#999", linestyle="--", linewidth=0.8)
            low, high = ax.get_xlim()
            ticks = [t for t in ax.get_xticks() if low <= t < cut - 0.04 * (high - low)]
            ax.set_xticks([*ticks, edge], [f"{t:g}" for t in ticks] + ["∞"])  # ∞ among the ticks, under the axes
            ax.set_xlim(low, high)
            ax.get_xticklabels()[-1].set_gid("not-settled")
        ax.set_title(info["title"], fontsize=10)
        ax.set_xlabel("settling time, 2 % (s)", fontsize=8)
        ax.set_ylabel("overshoot (%)", fontsize=8)
        ax.grid(True, alpha=0.3)
        ax.tick_params(labelsize=8)
    fig.suptitle(
        "The text's step: settling time against overshoot (filled: meets its specs; hollow: misses them; "
        "dashed red: the specs' largest settling time and overshoot)",
        fontsize=11,
    )
    fig.subplots_adjust(left=0.05, right=0.98, top=1 - 0.85 / fig.get_figheight(), hspace=0.45, wspace=0.25)
    _legend(fig, labels)
    return fig


def boxplots(out: Path, studies) -> str | None:
    """Inline SVG: per plant, box plots of the Monte Carlo samples' ITAE per controller (diverged samples left out).

    Boxes span the quartiles, whiskers 1.5 IQR, the line is the median; read from
    ``OUT/<plant>/monte_carlo.csv``. Controllers without samples on a plant are not drawn there.
    """
    found = []
    for name, info, _ in studies:
        path = Path(out) / name / "monte_carlo.csv"
        if path.exists():
            samples = pd.read_csv(path)
            if len(samples) and "itae" in samples:
                found.append((name, info, samples))
    if not found:
        return None
    labels = controller_order([s for _, _, s in found])
    fig, axes = _grid(len(found), 2, 13.0, 4.4)
    for ax, (name, info, samples) in zip(axes, found):
        present = [label for label in labels if label in set(samples.controller)]
        data, kept = [], []
        for label in present:
            values = samples[samples.controller == label].itae.astype(float).to_numpy()
            values = values[np.isfinite(values)]
            if values.size:
                data.append(values)
                kept.append(label)
        if not data:
            ax.set_visible(False)
            continue
        parts = ax.boxplot(data, patch_artist=True, widths=0.6, flierprops={"markersize": 3}, **_horizontal())
        for patch, label in zip(parts["boxes"], kept):
            look = style.of(label)
            patch.set_facecolor(look.color)
            patch.set_alpha(0.55)
            patch.set_edgecolor(look.color)
        for median in parts["medians"]:
            median.set_color("black")
        ax.set_yticks(range(1, len(kept) + 1), kept, fontsize=8)
        for i, tick in enumerate(ax.get_yticklabels()):
            tick.set_gid(f"box-label-{name}-{i}")
        ax.invert_yaxis()
        if max(float(np.max(v)) for v in data) > 20 * min(float(np.min(v)) for v in data if np.min(v) > 0):
            ax.set_xscale("log")
        unit = {"rad": "rad", "m": "m"}.get(str(info.get("tracked_unit")), str(info.get("tracked_unit")))
        ax.set_xlabel(f"ITAE ({unit} s²), per sample", fontsize=8)
        ax.set_title(f"{info['title']}: {int(samples.groupby('controller').size().max())} samples", fontsize=9)
        ax.grid(True, axis="x", alpha=0.3)
        ax.tick_params(axis="x", labelsize=8)
    fig.suptitle("Monte Carlo on the ±5 % parameter box: spread of the step's ITAE per controller", fontsize=11)
    fig.subplots_adjust(
        left=0.17,
        right=0.98,
        top=1 - 0.9 / fig.get_figheight(),
        bottom=0.6 / fig.get_figheight(),
        hspace=0.4,
        wspace=0.55,
    )
    return _svg(fig, "boxplots")
