"""The designer's page: a Bokeh server application around `studies.designer.Designer`.

Why Bokeh: its server keeps one Python session per browser tab and sends only
changed data over a WebSocket, so a gain change is one Python callback that
calls `Designer.update` and replaces the columns of a few data sources; its
sliders, text inputs, selects and buttons are widgets of the same document,
and its JavaScript (BokehJS) ships inside the Python package and is served by
the same server, so the page works offline with no code of ours in JavaScript
beyond the download of Export. It runs on Tornado, which the project already
has. Dash would add Flask, Plotly and a callback graph for the same result;
Panel is a layer over Bokeh that this page does not need; a hand-written
Starlette page would need its own widgets and plotting glue.

`serve(...)` binds 127.0.0.1 (a free port by default) and prints the URL.
"""

from __future__ import annotations

import errno
import json
import math
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
from bokeh.application import Application
from bokeh.application.handlers import FunctionHandler
from bokeh.layouts import column, row

# From their defining modules: bokeh.models re-exports them dynamically, which type checkers cannot follow.
from bokeh.models import ColumnDataSource, CustomJS, Range1d
from bokeh.models.annotations import Span
from bokeh.models.widgets import Button, Checkbox, Div, Select, Slider, TextInput
from bokeh.plotting import figure
from bokeh.server.server import BaseServer
from bokeh.server.tornado import BokehTornado
from bokeh.server.util import bind_sockets
from tornado.httpserver import HTTPServer
from tornado.ioloop import IOLoop

import models
from models import specs
from studies import animation, style, templates
from studies.plots import tracked_scale

from . import Designer, GainControl, Update, export_note

#: plant name -> (controller labels, label -> a new `Designer`): see `studies.designer.catalog`.
Catalog = Callable[[str], tuple[list[str], Callable[[str], Designer]]]

WIDTH = 560
HEIGHT = 230
#: The animation plays in real time, one frame every FRAME_SECONDS.
FRAME_SECONDS = 0.05

#: What the Export button downloads: the JSON the server put into the hidden Div named "export".
DOWNLOAD = """
const text = cb_obj.text;
if (!text) { return; }
const blob = new Blob([text], {type: "application/json"});
const link = document.createElement("a");
link.href = URL.createObjectURL(blob);
link.download = JSON.parse(text).file;
document.body.appendChild(link);
link.click();
link.remove();
"""


def _finite(values: np.ndarray) -> np.ndarray:
    """NaN where not finite (BokehJS leaves a gap there; inf would stretch the axes)."""
    values = np.asarray(values, dtype=float).copy()
    values[~np.isfinite(values)] = np.nan
    return values


def fragment(name: str, *values) -> str:
    """The page's HTML fragment `name` (a macro of the template ``designer.html.j2``) with `values`
    escaped: a Bokeh Div shows its text as HTML, so a label or an error message is never markup."""
    return str(templates.macro("designer.html.j2", name)(*values))


class Page:
    """The widgets, figures and data sources of one browser tab, bound to one `Designer`.

    Every model the tests read has a name: sources "response", "input", "bode", "locus", "poles",
    "spec_low", "spec_high"; divs "verdict", "margins", "tune_status", "export", "gain_error:KEY";
    inputs "gain:KEY" (text) and "slider:KEY"; the checkbox "envelope_box"; sources also "envelope" and "scene_*".
    The divs "title", "verdict" and "margins" show HTML, made by `fragment` (values escaped); the others
    show their text as it is (``render_as_text``), so an error message quoting a typed value stays text.
    """

    def __init__(self, catalog: Catalog, plants: list[str], plant: str, label: str | None = None):
        self.catalog = catalog
        labels, self.designers = catalog(plant)
        label = labels[0] if label is None else label
        self.plant = Select(
            title="plant", options=list[str | tuple[Any, str]](plants), value=plant, name="plant", width=260
        )
        self.plant.on_change("value", lambda attr, old, new: self._on_plant(old, new))
        self.values: dict[str, float] = {}
        self.tuning = False
        self.busy = False  # set while the page itself moves a widget: its callbacks then do nothing
        self.pending = False  # a redraw is scheduled for the gains a slider drag set
        self.scenario = "step"
        self.title = Div(text="", name="title")
        self.controller = Select(
            title="controller", options=list[str | tuple[Any, str]](labels), value=label, name="controller", width=260
        )
        self.scenario_select = Select(title="scenario", options=[], value="step", name="scenario", width=260)
        self.gains = column(name="gains")
        self.pool: dict = {}  # (kind, key) -> the row of widgets of that control, kept across designs
        self.rows: dict = {}  # the rows shown
        self.poles_header = Div(text=fragment("header", "desired poles", "rad/s; each change redesigns the gains"))
        self.gains_header = Div(text=fragment("header", "gains", ""))
        self.envelope = Checkbox(label="±5 % Monte Carlo envelope", name="envelope_box", active=False)
        self.envelope.on_change("active", lambda attr, old, new: self.refresh())
        self.tune_button = Button(label="Tune", name="tune", button_type="primary", width=80)
        self.reset_button = Button(label="Reset", name="reset", width=80)
        self.export_button = Button(label="Export", name="export_button", width=80)
        self.tune_status = Div(text="", name="tune_status", width=260, render_as_text=True)
        self.export_data = Div(text="", name="export", visible=False, render_as_text=True)
        self.export_data.js_on_change("text", CustomJS(code=DOWNLOAD))
        self.verdict = Div(text="", name="verdict", width=WIDTH)
        self.margins = Div(text="", name="margins", width=WIDTH)
        scene: dict[str, list] = {"xs": [], "ys": [], "color": [], "width": []}
        self.sources = {
            name: ColumnDataSource(name=name, data=data)
            for name, data in {
                "scene_lines": dict(scene),
                "scene_dashed": dict(scene),
                "scene_polygons": {"xs": [], "ys": [], "fill": [], "color": []},
                "scene_circles": {"x": [], "y": [], "r": [], "fill": [], "color": []},
                "scene_text": {"x": [], "y": [], "text": [], "color": []},
                "response": {"t": [], "y": [], "r": []},
                "envelope": {"t": [], "min": [], "low": [], "high": [], "max": []},
                "input": {"t": [], "u": []},
                "bode": {"omega": [], "magnitude_db": [], "phase_deg": []},
                "locus": {"re": [], "im": []},
                "poles": {"re": [], "im": []},
                "spec_low": {"omega": [], "db": []},
                "spec_high": {"omega": [], "db": []},
            }.items()
        }
        self.limit_spans = (
            Span(dimension="width", line_dash="dashed", line_color="#cf222e"),
            Span(dimension="width", line_dash="dashed", line_color="#cf222e"),
        )
        self.crossover_span = Span(dimension="height", line_dash="dotted", line_color="#8250df", visible=False)
        self.phase_span = Span(dimension="width", line_dash="dotted", line_color="#8250df", visible=False)
        self.controller.on_change("value", lambda attr, old, new: self._on_controller(old, new))
        self.scenario_select.on_change("value", self._on_scenario)
        self.tune_button.on_click(self._on_tune)
        self.reset_button.on_click(self._on_reset)
        self.export_button.on_click(self._on_export)
        self.figures = self._figures()
        self.run: models.ClosedLoopResult | None = None
        self.last = 0
        self.playing: Any = None  # the periodic callback while the animation plays
        self.anim_time = Slider(start=0, end=1, value=0, step=0.01, title="t (s)", name="anim_time", width=210)
        self.play_button = Button(label="Play", name="play", width=70)
        self.readout = Div(text="", name="readout", width=290, render_as_text=True)
        self.anim_time.on_change("value", lambda attr, old, new: self.draw_frame())
        self.play_button.on_click(self._on_play)
        self.layout = row(
            column(
                self.title,
                self.plant,
                self.controller,
                self.scenario_select,
                self.envelope,
                self.gains,
                row(self.tune_button, self.reset_button, self.export_button),
                self.tune_status,
                self.export_data,
                self.figures["scene"],
                row(self.play_button, self.anim_time),
                self.readout,
                width=300,
            ),
            column(self.verdict, self.figures["response"], self.figures["input"], self.margins),
            column(self.figures["magnitude"], self.figures["phase"], self.figures["locus"]),
        )
        self.load(label)

    # ------------------------------------------------------------- layout
    def _figures(self) -> dict:
        """The page's figures, drawn from the data sources: "response" (with the Monte Carlo envelope), "input"
        (with the actuator limit), "magnitude" and "phase" of the loop gain (with the spec's bounds), "locus"
        and "scene" (the animated drawing)."""
        s = self.sources
        response = figure(
            width=WIDTH,
            height=HEIGHT,
            title="step response of the nonlinear plant",
            x_axis_label="t (s)",
            name="response_figure",
        )
        response.varea("t", "min", "max", source=s["envelope"], fill_color="#0969da", fill_alpha=0.12)
        response.varea("t", "low", "high", source=s["envelope"], fill_color="#0969da", fill_alpha=0.25)
        response.line("t", "r", source=s["response"], line_dash="dashed", color="#6e7781", legend_label="reference")
        response.line("t", "y", source=s["response"], line_width=2, color="#0969da", legend_label="response")
        response.legend.location = "bottom_right"
        inputs = figure(
            width=WIDTH,
            height=HEIGHT - 50,
            title="commanded input (dashed: actuator limit)",
            x_axis_label="t (s)",
            x_range=response.x_range,
            name="input_figure",
        )
        inputs.line("t", "u", source=s["input"], line_width=1.5, color="#1a7f37")
        inputs.renderers.extend(self.limit_spans)
        magnitude = figure(
            width=WIDTH, height=HEIGHT, x_axis_type="log", title="loop gain |L| (dB)", name="magnitude_figure"
        )
        magnitude.line("omega", "magnitude_db", source=s["bode"], line_width=2, color="#0969da")
        magnitude.line(
            "omega", "db", source=s["spec_low"], line_dash="dashed", color="#cf222e", legend_label="spec: at least"
        )
        magnitude.line(
            "omega", "db", source=s["spec_high"], line_dash="dashed", color="#bf8700", legend_label="spec: at most"
        )
        magnitude.renderers.extend([self.crossover_span, Span(dimension="width", location=0, line_color="#6e7781")])
        magnitude.legend.location = "bottom_left"
        phase = figure(
            width=WIDTH,
            height=HEIGHT - 50,
            x_axis_type="log",
            x_range=magnitude.x_range,
            title="phase of L (deg)",
            x_axis_label="ω (rad/s)",
            name="phase_figure",
        )
        phase.line("omega", "phase_deg", source=s["bode"], line_width=2, color="#0969da")
        phase.renderers.extend([self.phase_span, Span(dimension="width", location=-180, line_color="#6e7781")])
        locus = figure(
            width=WIDTH,
            height=HEIGHT + 40,
            title="root locus (s-plane; x: closed-loop poles)",
            x_axis_label="Re s (1/s)",
            y_axis_label="Im s (rad/s)",
            name="locus_figure",
        )
        locus.scatter("re", "im", source=s["locus"], size=2, color="#6e7781")
        locus.scatter("re", "im", source=s["poles"], marker="x", size=12, line_width=2, color="#cf222e")
        locus.renderers.append(Span(dimension="height", location=0, line_color="#6e7781"))
        scene = figure(
            width=290,
            height=290,
            match_aspect=True,
            title="the run, animated",
            name="scene_figure",
            x_range=Range1d(start=-1, end=1),
            y_range=Range1d(start=-1, end=1),
        )
        scene.patches("xs", "ys", source=s["scene_polygons"], fill_color="fill", line_color="color")
        scene.multi_line("xs", "ys", source=s["scene_lines"], line_color="color", line_width="width")
        scene.multi_line(
            "xs", "ys", source=s["scene_dashed"], line_color="color", line_width="width", line_dash="dashed"
        )
        scene.circle("x", "y", radius="r", source=s["scene_circles"], fill_color="fill", line_color="color")
        scene.text(
            "x",
            "y",
            text="text",
            source=s["scene_text"],
            text_color="color",
            text_align="center",
            text_baseline="middle",
            text_font_size="12px",
        )
        scene.grid.visible = False
        return {
            "response": response,
            "input": inputs,
            "magnitude": magnitude,
            "phase": phase,
            "locus": locus,
            "scene": scene,
        }

    def _row(self, kind: str, c: GainControl):
        """Slider, typed value and message of a gain ("gain") or desired pole ("pole") control."""
        names = {"gain": ("gain", "slider", "gain_error"), "pole": ("pole", "pole_slider", "pole_error")}[kind]
        slider = Slider(
            start=c.log_low,
            end=c.log_high,
            value=math.log10(abs(c.design)),
            step=(c.log_high - c.log_low) / 400,
            title=f"{c.key} (log10 |value|)",
            show_value=False,
            name=f"{names[1]}:{c.key}",
            width=150,
        )
        text = TextInput(value=f"{c.design:.6g}", name=f"{names[0]}:{c.key}", width=100, title=c.key)
        error = Div(text="", name=f"{names[2]}:{c.key}", styles={"color": "#cf222e"}, width=260, render_as_text=True)
        # The control is looked up when the widget changes: a pole change redesigns the gains' ranges.
        key = c.key
        # A gain follows its slider while it is dragged (updates coalesced, `_dragged`); a pole, whose every
        # value is a redesign, when it is let go.
        if kind == "gain":
            slider.on_change("value", lambda attr, old, new: self._dragged(self._control(kind, key), new))
        else:
            slider.on_change(
                "value_throttled", lambda attr, old, new: self._on_slider(kind, self._control(kind, key), new)
            )
        text.on_change("value", lambda attr, old, new: self._on_text(kind, self._control(kind, key), new))
        return column(row(text, slider), error), slider, text, error

    # ------------------------------------------------------------- loading a controller
    def load(self, label: str) -> None:
        """Show controller `label` at its design."""
        self.designer = self.designers(label)
        d = self.designer
        self.scale, self.unit = tracked_scale(d.case.tracked_unit)
        self.title.text = fragment("title", d.case.plant, label)
        self.busy = True
        self.scenario_select.options = list(d.scenarios)
        if self.scenario not in d.scenarios:
            self.scenario = next(iter(d.scenarios))
        self.scenario_select.value = self.scenario
        self.busy = False
        self.pole_values = {c.key: c.design for c in d.pole_controls}
        self.rows = {}
        for c in d.pole_controls:
            self._widgets("pole", c)
        self._show_gains()
        self.figures["response"].yaxis.axis_label = f"{d.case.tracked} ({self.unit})"
        self.figures["input"].yaxis.axis_label = f"u ({d.case.input_unit})"
        self.refresh()

    def _control(self, kind: str, key: str) -> GainControl:
        """The designer's current control `key` of `kind` ("gain" or "pole")."""
        controls = self.designer.controls if kind == "gain" else self.designer.pole_controls
        return next(c for c in controls if c.key == key)

    def _widgets(self, kind: str, c: GainControl):
        """The row of control `c`, at its design: made once per name and kept (a Bokeh document holds
        one model per name), its range and value set anew."""
        key = (kind, c.key)
        if key not in self.pool:
            self.pool[key] = self._row(kind, c)
        _, slider, text, error = self.pool[key]
        self.busy = True
        slider.update(start=c.log_low, end=c.log_high, step=(c.log_high - c.log_low) / 400)
        self.busy = False
        self.rows[key] = self.pool[key]
        self._set_widgets(kind, c, c.design)
        error.text = ""
        return self.pool[key]

    def _show_gains(self) -> None:
        """Gain controls about the designer's current design (after a pole change: the new design)."""
        d = self.designer
        self.rows = {k: v for k, v in self.rows.items() if k[0] == "pole"}
        gains = [self._widgets("gain", c)[0] for c in d.controls]
        poles = [r[0] for k, r in self.rows.items() if k[0] == "pole"]
        header = [self.poles_header, *poles, self.gains_header] if poles else []
        self.gains.children = header + gains
        self.values = d.design_values()

    # ------------------------------------------------------------- callbacks
    def _on_plant(self, old: str, new: str) -> None:
        """Design the controllers of plant `new` in a thread (seconds), then show its first controller."""
        if self.busy:
            return
        doc = self.layout.document
        self.verdict.text = fragment("busy", f"designing the {new} controllers ...")
        self.plant.disabled = True

        def work():
            try:
                found = self.catalog(new)
                error = None
            except Exception as err:  # shown, never raised
                found, error = None, f"{new}: {type(err).__name__}: {err}".splitlines()[0]
            doc.add_next_tick_callback(lambda: self._designed(old, new, found, error))

        threading.Thread(target=work, name="designer-design", daemon=True).start()

    def _designed(self, old: str, new: str, found, error: str | None) -> None:
        """Back in the document's thread after `_on_plant`'s design: show plant `new`'s first controller, or
        the error and plant `old` again."""
        self.plant.disabled = False
        if found is None:
            self.verdict.text = fragment("error", error)
            self.busy = True
            self.plant.value = old
            self.busy = False
            return
        labels, self.designers = found
        self.busy = True
        self.controller.options = list(labels)
        self.controller.value = labels[0]
        self.busy = False
        self.load(labels[0])

    def _on_controller(self, old: str, new: str) -> None:
        """The controller picker changed: show controller `new` at its design (on an error, `old` stays)."""
        if self.busy:
            return
        try:
            self.load(new)
        except Exception as err:  # shown, never raised; the controller shown stays
            self.verdict.text = fragment("error", f"{new}: {type(err).__name__}: {err}")
            self.busy = True
            self.controller.value = old
            self.busy = False

    def _dragged(self, c: GainControl, exponent: float) -> None:
        """A gain slider moved: take the value now, redraw once the messages already queued are read (one
        update for a burst of drag events, not one each)."""
        if self.busy:
            return
        value = c.from_log(exponent)
        _, _, text, error = self.rows[("gain", c.key)]
        self.busy = True
        text.value = f"{value:.6g}"
        self.busy = False
        error.text = ""
        self.values[c.key] = value
        doc = self.layout.document
        if doc is None:
            self.refresh()
        elif not self.pending:
            self.pending = True
            doc.add_next_tick_callback(self._refresh_pending)

    def _refresh_pending(self) -> None:
        """The redraw `_dragged` scheduled: one update for the gains in force."""
        self.pending = False
        self.refresh()

    def _on_slider(self, kind: str, c: GainControl, exponent: float) -> None:
        """A slider was let go at log10 |value| = `exponent`: take that value."""
        if self.busy:
            return
        self._accept(kind, c, c.from_log(exponent))

    def _on_text(self, kind: str, c: GainControl, text: str) -> None:
        """A value was typed: take it if `GainControl.parse` accepts it, else show why and keep the value in force."""
        if self.busy:
            return
        error = self.rows[(kind, c.key)][3]
        try:
            value = c.parse(text)
        except ValueError as err:
            error.text = str(err)
            in_force = self.values if kind == "gain" else self.pole_values
            self._set_widgets(kind, c, in_force[c.key])  # the control keeps the value in force
            return
        error.text = ""
        self._accept(kind, c, value)

    def _accept(self, kind: str, c: GainControl, value: float) -> None:
        """Put `value` in force for control `c`: a gain, or a desired pole (the gains are then redesigned); redraw."""
        self._set_widgets(kind, c, value)
        if kind == "gain":
            self.values[c.key] = value
        else:
            self.pole_values[c.key] = value
            try:
                self.designer.place(self.pole_values)
            except Exception as err:  # a placement that fails is shown, never raised
                self.rows[(kind, c.key)][3].text = f"no design: {type(err).__name__}: {err}".splitlines()[0]
                return
            self._show_gains()
        self.refresh()

    def _set_widgets(self, kind: str, c: GainControl, value: float) -> None:
        """Show `value` on control `c`'s slider and text input without their callbacks running."""
        _, slider, text, _ = self.rows[(kind, c.key)]
        self.busy = True
        try:
            slider.value = min(max(math.log10(abs(value)), c.log_low), c.log_high)
            text.value = f"{value:.6g}"  # shown to 6 digits; the value in force is the exact one
        finally:
            self.busy = False

    def _on_scenario(self, attr, old, new) -> None:
        """The scenario picker changed: redraw on scenario `new`."""
        if self.busy:
            return
        self.scenario = new
        self.refresh()

    def _on_reset(self) -> None:
        """Back to the text's design: its poles (for a pole-placement design) and gains."""
        d = self.designer
        if d.pole_controls:
            d.place(None)
            for c in d.pole_controls:
                self._widgets("pole", c)
            self.pole_values = {c.key: c.design for c in d.pole_controls}
        self._show_gains()
        self.refresh()

    def _on_export(self) -> None:
        """Put the gains and C step (`Designer.export`) as JSON into the hidden export div, which downloads it."""
        d = self.designer
        try:
            data = d.export(self.values) | {"file": f"{d.case.plant}_{d.label}_gains.json".replace(" ", "_")}
        except Exception as err:  # shown, never raised
            self.tune_status.text = f"export failed: {type(err).__name__}: {err}".splitlines()[0]
            return
        self.export_data.text = json.dumps(data, indent=1)
        self.tune_status.text = export_note(data)

    def _on_tune(self) -> None:
        """Tune from the gains in force in a thread (`Designer.tune`), reporting progress every 5 iterations;
        `_tuned` shows the result."""
        if self.tuning:
            return
        self.tuning = True
        self.tune_button.disabled = True
        self.tune_status.text = "tuning ..."
        doc, designer, values, scenario = self.layout.document, self.designer, dict(self.values), self.scenario

        def progress(iteration, objective, seconds):
            if iteration % 5 == 0:
                doc.add_next_tick_callback(
                    lambda: setattr(
                        self.tune_status,
                        "text",
                        f"tuning: iteration {iteration}, ITAE {objective:.4g} ({seconds:.0f} s)",
                    )
                )

        def work():
            try:
                result, tuned = designer.tune(values, scenario, progress=progress)
                message = (
                    f"tuned: ITAE {result.initial_cost:.4g} -> {result.cost:.4g} ({result.status}); {result.message}"
                )
            except Exception as err:  # reported on the page; the server goes on
                tuned, message = None, f"tuning failed: {type(err).__name__}: {err}".splitlines()[0]
            doc.add_next_tick_callback(lambda: self._tuned(designer, tuned, message))

        threading.Thread(target=work, name="designer-tune", daemon=True).start()

    def _tuned(self, designer: Designer, tuned: dict | None, message: str) -> None:
        """Back in the document's thread after tuning: show `message`, and the tuned gains if this designer is
        still the one shown."""
        self.tuning = False
        self.tune_button.disabled = False
        self.tune_status.text = message
        if tuned is None or designer is not self.designer:
            return
        for c in designer.controls:
            self._set_widgets("gain", c, tuned[c.key])
        self.values = dict(tuned)
        self.refresh()

    # ------------------------------------------------------------- drawing an update
    def refresh(self) -> None:
        """Run `Designer.update` for the values in force and draw it; an error is shown, never raised."""
        try:
            update = self.designer.update(self.values, self.scenario)
        except Exception as err:  # the server never dies on a request
            self.verdict.text = fragment("error", f"{type(err).__name__}: {err}")
            return
        self.draw(update)
        self.draw_envelope()

    def draw_envelope(self) -> None:
        """The Monte Carlo envelope of the values in force when its box is ticked (else nothing)."""
        empty: dict[str, list] = {"t": [], "min": [], "low": [], "high": [], "max": []}
        if not self.envelope.active:
            self.sources["envelope"].data = empty
            return
        try:
            e = self.designer.envelope(self.values, self.scenario)
        except Exception as err:  # shown, never raised
            self.sources["envelope"].data = empty
            self.margins.text += fragment("no_envelope", f"{type(err).__name__}: {err}")
            return
        y = _finite(e["tracked"] * self.scale)
        self.sources["envelope"].data = {"t": e["t"], "min": y[0], "low": y[1], "high": y[3], "max": y[4]}
        self.margins.text += fragment("envelope", e["samples"], e["diverged"])

    def draw(self, u: Update) -> None:
        """Draw update `u`: the response (up to a divergence), the input and its limit, the verdict, the Bode
        plot with the spec's bounds, the root locus and poles, the margins line and the animation."""
        s = self.sources
        keep = np.ones(len(u.t), dtype=bool) if not u.diverged else u.t <= float(u.status.split("= ")[1].split()[0])
        s["response"].data = {
            "t": u.t[keep],
            "y": _finite(u.tracked[keep] * self.scale),
            "r": u.reference[keep] * self.scale,
        }
        keep_u = keep[:-1]
        s["input"].data = {"t": u.t[:-1][keep_u], "u": _finite(u.u[keep_u])}
        self.limit_spans[0].location, self.limit_spans[1].location = u.input_limit, -u.input_limit
        label = specs.DIVERGED if u.diverged else u.verdict.label
        color = style.verdict_color(label)
        self.verdict.text = fragment("verdict", u.verdict_text(), color, f"{1e3 * u.seconds:.0f}")
        s["bode"].data = {"omega": u.omega, "magnitude_db": _finite(u.magnitude_db), "phase_deg": _finite(u.phase_deg)}
        s["locus"].data = {"re": _finite(u.locus.real.ravel()), "im": _finite(u.locus.imag.ravel())}
        s["poles"].data = {"re": _finite(u.poles.real), "im": _finite(u.poles.imag)}
        spec = u.loop_specs[0] if u.loop_specs else {}
        for band in ("low", "high"):
            omega, db = spec.get(band, ((), ()))
            s[f"spec_{band}"].data = {"omega": np.asarray(omega, dtype=float), "db": _finite(np.asarray(db))}
        self.crossover_span.visible = bool(spec.get("crossover"))
        if spec.get("crossover"):
            self.crossover_span.location = spec["crossover"]
        self.phase_span.visible = bool(spec.get("phase_margin"))
        if spec.get("phase_margin"):
            self.phase_span.location = -180 + spec["phase_margin"]
        self.margins.text = _margins_text(u, spec)
        self.show_run(u)

    # ------------------------------------------------------------- the animation
    def show_run(self, u: Update) -> None:
        """Animate `u`'s run: the time slider spans it (up to a divergence), the view holds every frame."""
        case = self.designer.case
        self.figures["scene"].visible = case.drawing is not None
        if case.drawing is None or u.run is None:
            self.run = None
            return
        run = u.run
        last = len(run.t) - 1 if run.diverged_at is None else max(0, int(np.searchsorted(run.t, run.diverged_at)) - 1)
        self.run, self.last = run, last
        index = np.unique(np.linspace(0, last, 25).astype(int))
        shapes = [
            animation.draw(case, self.designer.plant, run.x[k], run.r[k, 0])
            for k in index
            if np.all(np.isfinite(run.x[k]))
        ]
        xmin, xmax, ymin, ymax = animation.view(shapes)
        scene = self.figures["scene"]
        side = max(xmax - xmin, ymax - ymin)
        cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
        scene.x_range.start, scene.x_range.end = cx - side / 2, cx + side / 2
        scene.y_range.start, scene.y_range.end = cy - side / 2, cy + side / 2
        self.busy = True
        self.anim_time.end = float(run.t[last]) if last else 1.0
        self.anim_time.step = float(run.t[1] - run.t[0])
        self.anim_time.value = min(self.anim_time.value, self.anim_time.end)
        self.busy = False
        self.draw_frame()

    def frame_index(self, run: models.ClosedLoopResult) -> int:
        """The run's sample at the time slider's value."""
        return min(self.last, int(np.argmin(np.abs(run.t - self.anim_time.value))))

    def draw_frame(self) -> None:
        """Draw the run's state at the time slider's value with the case's drawing (`studies.animation.draw`)."""
        if self.run is None or self.busy:
            return
        run, plant = self.run, self.designer.plant
        k = self.frame_index(run)
        shapes = animation.draw(self.designer.case, plant, run.x[k], run.r[k, 0])
        s = self.sources
        for name, dashed in (("scene_lines", False), ("scene_dashed", True)):
            lines = [p for p in shapes if p["k"] == "line" and bool(p["d"]) == dashed]
            s[name].data = {
                "xs": [[q[0] for q in p["p"]] for p in lines],
                "ys": [[q[1] for q in p["p"]] for p in lines],
                "color": [p["c"] for p in lines],
                "width": [p["w"] for p in lines],
            }
        polygons = [p for p in shapes if p["k"] == "poly"]
        s["scene_polygons"].data = {
            "xs": [[q[0] for q in p["p"]] for p in polygons],
            "ys": [[q[1] for q in p["p"]] for p in polygons],
            "fill": [p["f"] for p in polygons],
            "color": [p["c"] for p in polygons],
        }
        circles = [p for p in shapes if p["k"] == "circle"]
        s["scene_circles"].data = {
            "x": [p["p"][0] for p in circles],
            "y": [p["p"][1] for p in circles],
            "r": [p["r"] for p in circles],
            "fill": [p["f"] for p in circles],
            "color": [p["c"] for p in circles],
        }
        texts = [p for p in shapes if p["k"] == "text"]
        s["scene_text"].data = {
            "x": [p["p"][0] for p in texts],
            "y": [p["p"][1] for p in texts],
            "text": [p["s"] for p in texts],
            "color": [p["c"] for p in texts],
        }
        tracked = run.x[k, self.designer.tracked_index] * self.scale
        self.readout.text = f"t = {run.t[k]:.2f} s: {self.designer.case.tracked} = {tracked:.4g} {self.unit}"

    def _on_play(self) -> None:
        """Play the animation in real time from the slider's time (from 0 at the end), or pause it."""
        doc = self.layout.document
        if doc is None:
            return
        if self.playing is not None:
            doc.remove_periodic_callback(self.playing)
            self.playing, self.play_button.label = None, "Play"
            return
        if self.run is None:
            return
        if self.anim_time.value >= self.anim_time.end:
            self.anim_time.value = 0.0

        def advance():
            if self.run is None or self.anim_time.value >= self.anim_time.end:
                self._on_play()
                return
            self.anim_time.value = min(self.anim_time.end, self.anim_time.value + FRAME_SECONDS)

        self.playing, self.play_button.label = doc.add_periodic_callback(advance, int(1e3 * FRAME_SECONDS)), "Pause"


def _margins_text(u: Update, spec: dict) -> str:
    """The margins line under the plots: the loop's gain and phase margins, the closed-loop poles in the
    right half plane and the loopshaping specs met; the notes of the update when it has no margins."""
    if not u.margins:
        return fragment("notes", "; ".join(u.notes))
    m = u.margins
    gain = (
        f"gain margin {m['gain_margin_db']:.3g} dB at {m['phase_crossover_rad_s']:.3g} rad/s"
        if math.isfinite(m["gain_margin_db"])
        else "no gain margin (the phase does not cross -180°)"
    )
    phase = (
        f"phase margin {m['phase_margin_deg']:.3g}° at {m['gain_crossover_rad_s']:.3g} rad/s"
        if math.isfinite(m["phase_margin_deg"])
        else "no phase margin (|L| does not cross 1)"
    )
    unstable = int(np.sum(u.poles.real > 0))
    poles = f"{unstable} closed-loop pole{'s' if unstable != 1 else ''} in the right half plane"
    text = f"{u.loop} loop: {gain}, {phase}; {poles}"
    checks = ", ".join(
        f"{name} {'met' if ok else 'missed' if ok is not None else 'not checked'}"
        for name, ok in (spec["checks"].items() if spec else ())
    )
    return fragment("margins", text, spec["item"] if spec else None, checks)


def application(catalog: Catalog, plants: list[str], plant: str, label: str | None = None):
    """A Bokeh `Application` whose every session is a `Page` of `plant`'s controller `label` (default its first)."""

    def make(doc):
        page = Page(catalog, plants, plant, label)
        doc.add_root(page.layout)
        doc.title = f"designer: {page.designer.case.plant}"

    return Application(FunctionHandler(make))


def listen(port: int = 0) -> tuple[list, int]:
    """(sockets listening on 127.0.0.1:`port`, the port; 0: one the system chooses) for `serve`, bound before
    any design; OSError saying "127.0.0.1:PORT is in use" (or why else it cannot listen there)."""
    try:
        return bind_sockets("127.0.0.1", port)
    except OSError as err:
        reason = "is in use" if err.errno == errno.EADDRINUSE else f"cannot be listened on ({err.strerror or err})"
        raise OSError(err.errno, f"127.0.0.1:{port} {reason}") from None


def serve(
    catalog: Catalog,
    plants: list[str],
    plant: str,
    label: str | None = None,
    port: int = 0,
    ready: Callable[[str], None] | None = None,
    listening: tuple[list, int] | None = None,
) -> None:
    """Serve the page on 127.0.0.1:`port` (0: a free port) until interrupted; print its URL.

    Parameters
    ----------
    catalog : plant name -> (controller labels, label -> `Designer`), as `studies.designer.catalog`;
        a user's own gives its own plant and blocks
    plants : the plant picker's names;  plant, label : what the page opens with
    ready : called with the URL once the server listens (default: print it)
    listening : (sockets, port) from `listen`, when the caller checked the port before designing;
        default: `listen(port)` here
    """
    # Bound first, so that the page's own origin (with the port the system chose) is the one allowed.
    sockets, port = listening if listening is not None else listen(port)
    tornado_app = BokehTornado(
        {"/": application(catalog, plants, plant, label)},
        extra_websocket_origins=[f"127.0.0.1:{port}", f"localhost:{port}"],
    )
    http = HTTPServer(tornado_app)
    http.add_sockets(sockets)
    loop = IOLoop.current()
    server = BaseServer(loop, tornado_app, http)
    server.start()
    url = f"http://127.0.0.1:{port}/"
    (ready or (lambda u: print(f"designer running at {u} (Ctrl-C stops it)", flush=True)))(url)
    try:
        loop.start()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
