"""Figures of a study, drawn with matplotlib's Agg canvas into the folder the caller names.

Time responses come from the nonlinear simulations of the table; Bode plots,
root loci and pole maps from `studies.loops` (the exact linearization of each
block about where it holds the plant at rest). Angles are drawn in degrees,
labelled so.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from models import deferred, files

from . import style

if TYPE_CHECKING:
    from matplotlib.figure import Figure

# Matplotlib is imported at the first figure, not with the writers. Each figure draws on its own Agg
# canvas (the object-oriented API): no pyplot, so no global backend to choose.
mpl_figure = deferred.module("matplotlib.figure")
backend_agg = deferred.module("matplotlib.backends.backend_agg")

#: Commands beyond this multiple of the actuator limit are cut off in input plots (and the plot says so).
INPUT_PLOT_RANGE = 3.0


def figure(width: float, height: float) -> Figure:
    """A new figure of `width` × `height` inches on its own Agg canvas."""
    fig = mpl_figure.Figure(figsize=(width, height))
    backend_agg.FigureCanvasAgg(fig)
    return fig


def legend_below(
    fig: Figure, handles, labels, ncol: int | None = None, top: float = 0.9, hspace: float = 0.25, left: float = 0.09
) -> None:
    """A figure legend under the axes, with room made for it (no layout engine: it is slow).

    `ncol` defaults to as many columns of the labels as fit across the figure (`style.legend_columns`).
    """
    ncol = ncol or style.legend_columns(labels, fig.get_figwidth())
    rows = -(-len(labels) // ncol)
    height = fig.get_figheight()
    bottom = (0.45 + 0.2 * rows) / height + 0.06
    fig.subplots_adjust(left=left, right=0.98, top=top, bottom=bottom, hspace=hspace, wspace=0.3)
    fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=7, frameon=False)


def save(fig: Figure, path: Path, dpi: int) -> Path:
    """Save a figure as PNG atomically."""
    with files.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    return path


def tracked_scale(unit: str) -> tuple[float, str]:
    """Factor and unit label for drawing the tracked coordinate: rad is drawn in degrees."""
    return (180 / np.pi, "deg") if unit == "rad" else (1.0, unit)


def responses(result, scenario: str, path: Path, dpi: int = 110) -> Path | None:
    """Tracked coordinate and commanded input of every controller in one scenario, limit drawn.

    Parameters
    ----------
    result : runner.StudyResult;  scenario : a non-Monte-Carlo scenario name
    """
    runs = [(label, run) for (label, name), run in result.runs.items() if name == scenario]
    if not runs:
        return None
    study, case = result.study, result.study
    scale, unit = tracked_scale(study.tracked_unit)
    fig = figure(9, 6.5)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 2])
    limit = float(np.max(result.plant.input_limit))
    widest = INPUT_PLOT_RANGE * max(float(np.max(run.input_limit)) for _, run in runs)
    clipped = False
    for label, run in runs:
        line = style.of(label).line()
        tag = label if run.diverged_at is None else f"{label} (diverged at {run.diverged_at:.3g} s)"
        y = run.x[:, run.state_names.index(case.tracked)] * scale
        top.plot(run.t, y, label=tag, **line)
        u = run.u[:, 0]
        clipped |= bool(np.any(np.abs(u) > widest))
        bottom.step(run.t[:-1], np.clip(u, -widest, widest), where="post", **line)
    reference = runs[0][1]
    top.plot(reference.t, reference.r[:, 0] * scale, label="reference", **style.REFERENCE)
    for sign in (1, -1):
        bottom.axhline(
            sign * limit,
            color=style.LIMIT_COLOR,
            linestyle="--",
            linewidth=1,
            label=f"actuator limit ±{limit:g} {study.input_unit}" if sign > 0 else None,
        )
    for label, run in runs:
        own = float(np.max(run.input_limit))
        if own != limit:  # a design the text gives its own actuator
            for sign in (1, -1):
                bottom.axhline(
                    sign * own,
                    color=style.of(label).color,
                    linestyle=":",
                    linewidth=1,
                    label=f"{label}: its limit ±{own:g} {study.input_unit}" if sign > 0 else None,
                )
    top.set_ylabel(f"{case.tracked} ({unit})")
    bottom.set_ylabel(f"commanded {result.plant.input_names[0]} ({study.input_unit})")
    bottom.set_xlabel("t (s)")
    title = next(s.title for s in study.scenarios if s.name == scenario)
    top.set_title(f"{result.plant.title}: {title}\nnonlinear plant simulation", fontsize=10)
    if clipped:
        bottom.set_title(f"commands beyond ±{INPUT_PLOT_RANGE:g}× the limit are cut off in this plot", fontsize=8)
    for ax in (top, bottom):
        ax.grid(True, alpha=0.3)
    bottom.legend(loc="upper right", fontsize=7)
    handles, labels = top.get_legend_handles_labels()
    legend_below(fig, handles, labels, hspace=0.12 if not clipped else 0.2)
    return save(fig, path, dpi)


def envelopes(result, path: Path, dpi: int = 110) -> Path | None:
    """Monte Carlo envelopes (min–max and 5–95 % bands, median) of every controller."""
    if not result.envelopes:
        return None
    study, case = result.study, result.study
    scale, unit = tracked_scale(study.tracked_unit)
    items = list(result.envelopes.items())
    cols = min(3, len(items))
    rows = -(-len(items) // cols)
    fig = figure(4 * cols, 2.6 * rows + 0.6)
    axes = np.atleast_1d(fig.subplots(rows, cols, sharex=True, squeeze=False)).ravel()
    for ax, (label, env) in zip(axes, items):
        t = env.t
        color = style.of(label).color
        ax.fill_between(
            t, env.tracked[0] * scale, env.tracked[-1] * scale, color=color, alpha=0.2, linewidth=0, label="min–max"
        )
        ax.fill_between(
            t, env.tracked[1] * scale, env.tracked[-2] * scale, color=color, alpha=0.4, linewidth=0, label="5–95 %"
        )
        ax.plot(t, env.tracked[2] * scale, label="median", **style.of(label).line(1.0))
        ax.plot(t, env.reference * scale, label="reference", **style.REFERENCE)
        note = f", {env.diverged} diverged" if env.diverged else ""
        ax.set_title(f"{label} ({env.samples} samples{note})", fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.set_ylabel(f"{case.tracked} ({unit})", fontsize=8)
    for ax in axes[len(items) :]:
        ax.set_visible(False)
    for ax in axes[-cols:]:
        ax.set_xlabel("t (s)")
    axes[0].legend(fontsize=7)
    rel = next((s.rel for s in study.scenarios if s.monte_carlo), study.known_rel)
    fig.suptitle(f"{result.plant.title}: step on ±{100 * rel:g} % parameter samples (nonlinear plant)", fontsize=10)
    fig.subplots_adjust(
        left=0.07,
        right=0.98,
        top=1 - 0.7 / fig.get_figheight(),
        bottom=0.5 / fig.get_figheight(),
        hspace=0.45,
        wspace=0.3,
    )
    return save(fig, path, dpi)


def _frequency_grid(loops_, spec) -> np.ndarray:
    """600 log-spaced frequencies (rad/s) from a decade below the spec's lowest mark (at most 1e-3) up to
    just under the smallest Nyquist frequency π/Ts of the loops."""
    nyquist = min(np.pi / lp.sample_period for lp in loops_)
    marks = [f for f in (spec.low_frequency, spec.high_frequency, spec.crossover) if f]
    low = min([1e-3, *(m / 10 for m in marks)])
    return np.logspace(np.log10(low), np.log10(0.999 * nyquist), 600)


def bode(result, loops: dict, spec, path: Path, checks: dict | None = None, dpi: int = 110) -> Path | None:
    """Bode plot of the loop gains named by `spec.loop`, with the loopshaping specs drawn.

    Parameters
    ----------
    loops : label -> {loop name: studies.loops.LoopGain}
    spec : studies.case.LoopSpec;  checks : label -> spec_check result, shown in the legend
    """
    chosen = [(label, found[spec.loop]) for label, found in loops.items() if spec.loop in found]
    if not chosen:
        return None
    omega = _frequency_grid([lp for _, lp in chosen], spec)
    fig = figure(9, 6.5)
    mag, phase = fig.subplots(2, 1, sharex=True)
    for label, lp in chosen:
        response = lp.frequency_response(omega)
        text = label
        if checks and label in checks:
            verdict = ", ".join(
                f"{k}: {'met' if v else 'missed' if v is not None else 'n/a'}" for k, v in checks[label].items()
            )
            text += f" ({verdict})" if verdict else ""
        line = style.of(label).line(2.2 if label == spec.design else 1.1)
        mag.semilogx(omega, 20 * np.log10(np.abs(response)), label=text, **line)
        phase.semilogx(omega, np.degrees(np.unwrap(np.angle(response))), **line)
    baseline = loops.get(spec.baseline, {}).get(spec.loop) if spec.baseline else None
    if baseline is not None:
        base = np.abs(baseline.frequency_response(omega))
        if spec.low_frequency:
            low = omega <= spec.low_frequency
            mag.semilogx(
                omega[low],
                20 * np.log10(spec.factor * base[low]),
                color="red",
                linewidth=2.5,
                alpha=0.6,
                label=f"{spec.item}: |L| ≥ {spec.factor:g}·|L {spec.baseline}| below {spec.low_frequency:g} rad/s",
            )
        if spec.high_frequency:
            high = omega >= spec.high_frequency
            mag.semilogx(
                omega[high],
                20 * np.log10(base[high] / spec.factor),
                color="darkred",
                linewidth=2.5,
                alpha=0.6,
                label=f"{spec.item}: |L| ≤ |L {spec.baseline}|/{spec.factor:g} above {spec.high_frequency:g} rad/s",
            )
    elif spec.low_frequency or spec.high_frequency:
        for f in (spec.low_frequency, spec.high_frequency):
            if f:
                mag.axvline(f, color="red", linestyle=":", linewidth=1)
        mag.text(
            0.01,
            0.03,
            f"{spec.item}: baseline {spec.baseline!r} not available, so the relative specs are "
            f"only marked by their frequencies",
            transform=mag.transAxes,
            fontsize=8,
            color="red",
        )
    if spec.crossover:
        for ax in (mag, phase):
            ax.axvline(spec.crossover, color="red", linestyle="--", linewidth=1)
        mag.plot([], [], color="red", linestyle="--", label=f"{spec.item}: crossover {spec.crossover:g} rad/s")
    if spec.phase_margin:
        phase.axhline(
            -180 + spec.phase_margin,
            color="red",
            linestyle="--",
            linewidth=1,
            label=f"{spec.item}: phase margin {spec.phase_margin:g} deg",
        )
        phase.legend(fontsize=7)
    mag.axhline(0, color="gray", linewidth=0.8)
    phase.axhline(-180, color="gray", linewidth=0.8)
    where = {
        "input": "at the plant input",
        "outer": "outer loop (at the inner reference)",
        "inner": "inner loop (outer loop open)",
    }[spec.loop]
    mag.set_title(
        f"{result.plant.title}: loop gain L(z) {where}, exact linearization, Ts = {chosen[0][1].sample_period:g} s",
        fontsize=10,
    )
    mag.set_ylabel("|L| (dB)")
    phase.set_ylabel("∠L (deg)")
    phase.set_xlabel("ω (rad/s)")
    for ax in (mag, phase):
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = mag.get_legend_handles_labels()
    legend_below(fig, handles, labels, top=0.94, hspace=0.12)
    return save(fig, path, dpi)


def _focus(points: np.ndarray, sample_period: float) -> float:
    """Half-width of a square view holding the dominant poles (those slower than a fifth of Nyquist)."""
    points = points[np.isfinite(points)]
    slow = points[np.abs(points) < 0.2 * np.pi / sample_period]
    reach = np.max(np.abs(slow)) if slow.size else 1.0
    return 1.3 * max(reach, 1e-3)


def root_loci(result, loops: dict, path: Path, dpi: int = 110, gains: int = 300) -> Path | None:
    """Root locus of k·L(z) at the plant input for every block, k from 0.01 to 100, in the s-plane.

    Discrete poles z are shown as s = ln(z)/Ts; × marks the design (k = 1), ○ the
    open loop (k → 0).
    """
    chosen = [(label, found["input"]) for label, found in loops.items()]
    if not chosen:
        return None
    cols = min(3, len(chosen))
    rows = -(-len(chosen) // cols)
    fig = figure(4 * cols, 3.4 * rows + 0.5)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    for ax, (label, lp) in zip(axes, chosen):
        locus = np.concatenate([lp.s_plane(lp.closed_loop_poles(k)) for k in np.logspace(-2, 2, gains)])
        design = lp.s_plane(lp.closed_loop_poles(1.0))
        open_loop = lp.s_plane(np.linalg.eigvals(lp.A))
        ax.plot(locus.real, locus.imag, ".", markersize=1.5, color="tab:blue", alpha=0.5)
        ax.plot(open_loop.real, open_loop.imag, "o", markerfacecolor="none", markeredgecolor="black", markersize=6)
        ax.plot(design.real, design.imag, "x", color="red", markersize=7)
        half = _focus(design, lp.sample_period)
        ax.set_xlim(-half, 0.3 * half)
        ax.set_ylim(-half, half)
        ax.axvline(0, color="gray", linewidth=0.8)
        ax.set_title(label, fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("Re s (1/s)", fontsize=8)
        ax.set_ylabel("Im s (rad/s)", fontsize=8)
    for ax in axes[len(chosen) :]:
        ax.set_visible(False)
    fig.suptitle(
        f"{result.plant.title}: root locus of k·L at the plant input (k = 0.01…100; × design k = 1, "
        "○ open loop), s = ln(z)/Ts",
        fontsize=10,
    )
    fig.subplots_adjust(
        left=0.08,
        right=0.98,
        top=1 - 0.7 / fig.get_figheight(),
        bottom=0.6 / fig.get_figheight(),
        hspace=0.5,
        wspace=0.35,
    )
    return save(fig, path, dpi)


def pole_map(result, loops: dict, path: Path, dpi: int = 110) -> Path | None:
    """Closed-loop poles (s = ln(z)/Ts) of every block controller and the plant's open-loop poles."""
    if not loops:
        return None
    fig = figure(8, 6.5)
    ax = fig.subplots()
    everything = []
    for label, found in loops.items():
        lp = found["input"]
        poles = lp.s_plane(lp.closed_loop_poles(1.0))
        everything.append((poles, lp.sample_period))
        look = style.of(label)
        ax.scatter(poles.real, poles.imag, marker=look.marker, color=look.color, s=36, label=label)
    plant_poles = np.linalg.eigvals(result.plant.linearize().A)
    ax.scatter(
        plant_poles.real,
        plant_poles.imag,
        marker="o",
        facecolors="none",
        edgecolors="black",
        s=60,
        label="plant (open loop)",
    )
    half = max(_focus(p, ts) for p, ts in everything)
    ax.set_xlim(-half, 0.3 * half)
    ax.set_ylim(-half, half)
    ax.axvline(0, color="gray", linewidth=0.8)
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("Re s (1/s)")
    ax.set_ylabel("Im s (rad/s)")
    ax.set_title(f"{result.plant.title}: closed-loop poles, exact linearization at rest, s = ln(z)/Ts", fontsize=10)
    handles, labels = ax.get_legend_handles_labels()
    legend_below(fig, handles, labels, top=0.94)
    return save(fig, path, dpi)
