"""The monitor's page: one Bokeh document per browser tab (docs/monitor.md).

Every ``UPDATE_MS`` the page's periodic callback polls the record feed (shared by all tabs) and
sends the tab what changed: the new points of the decimated histories
(:class:`hsio.monitor.decimate.Decimation`, streamed), the newest step at full resolution (one
row), the spectrum, the margins and the status text. Nothing heavy runs on the run's side, and
nothing here waits for the run: the control socket is spoken to from worker threads
(:class:`hsio.monitor.operator.Operator`).

"Target" is the integrator's command to an actuator (the ``target_`` column of the record),
before any compensation adjusts it; the tracking error is target minus measured.
"""

from __future__ import annotations

import html
import math
import time

import numpy as np
from bokeh.layouts import column, gridplot, row
from bokeh.models import Button, ColumnDataSource, CustomJS, DataRange1d, Div, Legend, LinearAxis, Slope, TextInput
from bokeh.palettes import Category10, Category20, turbo
from bokeh.plotting import figure

from hsio.clock import CONTROLLER_RATE_HZ
from hsio.monitor.backlog import BACKLOG_BYTES, backlog_bytes
from hsio.monitor.decimate import DEFAULT_CAP, Decimation
from hsio.monitor.feed import RecordFeed
from hsio.monitor.indicators import error_spectrum, margin
from hsio.monitor.operator import ACTIONS, Operator
from hsio.recording import PHASE_CODES, being_written, column as col, without_journal

UPDATE_MS = 200  # the status: step, state, rate
PLOT_EVERY_S = 0.4  # the plots (each redraw costs the browser far more than the status)
SPECTRUM_EVERY_S = 2.0  # the spectrum of the last seconds changes slowly
PHASES = {v: k for k, v in PHASE_CODES.items()}
LEGEND_INSIDE = 6  # entries a legend may show inside its plot; more go below it, in columns
LEGEND_ROW_PX = 17
LINES_AT_FULL_RATE = 4  # channels whose plots are redrawn every PLOT_EVERY_S; more, less often
PLOT_EVERY_MAX_S = 1.0
CONFIRM = {"pause": "Pause the test? The step under way finishes, then the actuators hold.",
           "resume": "Resume the test from where it holds?",
           "ack": "Acknowledge the controller trip reported during the pause? (A controller still tripped stops "
                  "the test at its first command after the resume.)",
           "stop": "STOP the test? The actuators hold and the record is closed (hsio resume can continue it later)."}
SCROLL = {"overflow-y": "auto"}
LOST = """
const shown = (status.text.match(/hsio-state'>([^<]*)</) || ['', ''])[1];
if (!shown.startsWith('not known')) {  // said once, however often the connection is reported lost
  const at = new Date().toLocaleTimeString();
  status.text = status.text.replace(/hsio-state'>[^<]*</, "hsio-state'>not known: this page lost its connection " +
      "to the monitor at " + at + " and no longer follows the run (it showed: " + shown + "); reload it, or see " +
      "the run's terminal<");
}
for (const b of buttons) { b.disabled = true; }
"""
# Fixed borders: when the tick labels change width the page is not laid out again (a relayout
# redraws every plot, the costliest thing a browser does here).
PLOT = dict(height=260, sizing_mode="stretch_width", tools="pan,box_zoom,wheel_zoom,reset,save",
            output_backend="canvas", min_border_left=70, min_border_right=20, min_border_top=10,
            min_border_bottom=50)


def _fig(title: str, x: str, y: str, **kw) -> figure:
    p = figure(title=title, x_axis_label=x, y_axis_label=y, **{**PLOT, **kw})
    p.toolbar.logo = None
    p.title.text_font_size = "11pt"
    return p


def cap_for(lines: int) -> int:
    """The points per history for plots of ``lines`` lines each: DEFAULT_CAP up to four, then
    fewer in proportion, never under 1000 (about three per pixel of a plot 300 px wide)."""
    return max(1000, DEFAULT_CAP * LINES_AT_FULL_RATE // max(lines, LINES_AT_FULL_RATE))


def plot_every_for(lines: int) -> float:
    """Seconds between redraws of plots of ``lines`` lines each: PLOT_EVERY_S up to four, then
    longer in proportion, at most PLOT_EVERY_MAX_S."""
    return min(PLOT_EVERY_MAX_S, PLOT_EVERY_S * max(lines, LINES_AT_FULL_RATE) / LINES_AT_FULL_RATE)


def colors(n: int) -> list[str]:
    """Distinct colours for ``n`` lines: Category10 up to 10; up to 20, the ten of Category10 and
    then, for lines 11 to 20, the light tone of the same ten hues (Category20's); past 20, the
    turbo map sampled at ``n`` points."""
    if n <= 10:
        return list(Category10[10][:n])
    if n <= 20:
        return (list(Category20[20][0::2]) + list(Category20[20][1::2]))[:n]
    return list(turbo(n))


def _legend(p, items) -> None:
    """A legend that shows every entry: inside the plot's corner when there are few, else below
    the plot in as many columns as its width allows, the plot made taller by its rows."""
    if not items:
        return
    if len(items) <= LEGEND_INSIDE:
        p.add_layout(Legend(items=items, location="top_left", label_text_font_size="8pt", spacing=0, padding=2))
        p.legend.background_fill_alpha = 0.6
    else:
        longest = max(len(label) for label, _ in items)
        ncols = max(1, min(4, 280 // (6 * longest + 30)))  # a plot about 300 px wide (four to a row)
        rows = -(-len(items) // ncols)
        p.add_layout(Legend(items=items, ncols=ncols, label_text_font_size="8pt", spacing=0, padding=2,
                            label_height=LEGEND_ROW_PX - 2, glyph_height=LEGEND_ROW_PX - 2, margin=4), "below")
        p.height += rows * LEGEND_ROW_PX + 12
    p.legend.click_policy = "hide"


class MonitorPage:
    """The document of one browser tab, fed by ``feed`` and sending requests by ``operator``."""

    def __init__(self, doc, feed: RecordFeed, operator: Operator, cap: int | None = None):
        self.doc, self.feed, self.operator = doc, feed, operator
        if cap and cap > feed.cap:  # the feed keeps the rows of caps up to its own (hsio.monitor.history)
            raise ValueError(f"a page of {cap} points per history needs a feed that keeps as many, not {feed.cap}")
        self._cap_given = bool(cap)
        self.decimation = Decimation(cap) if cap else Decimation()
        self.built = False
        self._plotted = 0.0
        self._spectrum_at = 0.0
        self.plot_every_s = PLOT_EVERY_S
        self.held_back = 0  # plot updates not sent: the tab had not read the ones before
        self._sent_state = ""
        # Fixed sizes: new text never re-lays out the page (which would redraw every plot); text
        # longer than its box (many DOFs, long events) scrolls in it instead of running under the plots.
        self.status = Div(text="<b>hsio monitor</b>: waiting for the record ...", name="status",
                          width=1000, height=170, styles=SCROLL)
        self.actions = Div(text="", name="actions", width=380, height=130, styles=SCROLL)
        self.events = Div(text="", name="events", width=1500, height=190, styles=SCROLL)
        self.request = TextInput(value="", visible=False, name="request")
        self.request.on_change("value", self._on_request)
        self.buttons = []
        labels = {"ack": "Acknowledge trip"}
        for action, kind in zip(ACTIONS, ("warning", "success", "default", "danger")):
            b = Button(label=labels.get(action, action.capitalize()), button_type=kind, width=130 if action == "ack" else 90,
                       name=f"{action}_button")
            b.js_on_click(CustomJS(args=dict(req=self.request, action=action, text=CONFIRM[action]), code="""
                if (window.confirm(text)) { req.value = action + ' ' + Date.now(); }"""))
            self.buttons.append(b)
        controls = column(row(*self.buttons), self.actions, width=380, height=170)
        self.head = row(self.status, controls, height=175)
        # Three roots, each laid out on its own: new status text never re-lays out the plots.
        self.root = column(self.head, self.request, name="root")
        # A page that lost its server (the run ended and its monitor with it, killed, or the
        # network) would go on showing its last state, a hold or "running": say it is not known.
        doc.js_on_event("connection_lost", CustomJS(args=dict(status=self.status, buttons=self.buttons), code=LOST))
        doc.title = f"hsio monitor: {feed.run_dir}"
        doc.add_root(self.root)
        self.update()
        doc.add_periodic_callback(self.update, UPDATE_MS)

    # -- building the plots once the record names its DOFs and channels ------------------------
    def _build(self) -> None:
        f = self.feed
        # Many channels, many lines: fewer points per line and fewer redraws (section 4).
        lines = max(len(f.channels), len(f.dofs))
        if not self._cap_given:
            self.decimation = Decimation(cap_for(lines))
        self.plot_every_s = plot_every_for(lines)
        color, dof_color = colors(len(f.channels)), colors(len(f.dofs))
        names = ["step", "t", "late"] + [col(p, d) for d in f.dofs for p in ("u", "fc")] + \
                [col(p, c) for c in f.channels for p in ("target", "disp", "force", "error", "ti", "tif")]
        empty = {k: np.zeros(0) for k in names}
        self.steps = ColumnDataSource(dict(empty), name="steps")
        self.last = ColumnDataSource(dict(empty), name="head")
        self.ns = ColumnDataSource({"t": np.zeros(0), **{col("u", d): np.zeros(0) for d in f.dofs}}, name="ns")
        self.spectrum = ColumnDataSource({"f": np.zeros(0), **{col("a", c): np.zeros(0) for c in f.channels}},
                                         name="spectrum")
        self.margins = ColumnDataSource(dict(label=[], value=[], color=[], text=[]), name="margins")
        figs = []
        p = _fig("Displacement: HS (solid), NS (dashed)", "time (s)", "mm (rad for a rotation)" if self._rotations() else "mm")
        items = []
        for k, d in enumerate(f.dofs):
            a = p.line("t", col("u", d), source=self.steps, color=dof_color[k], line_width=1.5)
            b = p.line("t", col("u", d), source=self.ns, color=dof_color[k], line_dash="dashed", line_alpha=0.8)
            p.scatter("t", col("u", d), source=self.last, color="red", size=7)
            items.append((self._named(d, f.dof_unit), [a, b]))
        _legend(p, items)
        figs.append(p)
        p = _fig("Force-displacement per element", "measured displacement (mm)", "measured force (kN)")
        items = []
        for k, c in enumerate(f.channels):
            named = f"{c} (rad, kN mm)" if f.channel_unit.get(c) == "rad" else c
            items.append((named, [p.line(col("disp", c), col("force", c), source=self.steps, color=color[k])]))
            p.scatter(col("disp", c), col("force", c), source=self.last, color="red", size=7)
        _legend(p, items)
        figs.append(p)
        p = _fig("Tracking error (target - measured)", "time (s)", "mm (kN in force control)")
        _legend(p, [(self._named(c, f.channel_unit), [p.line("t", col("error", c), source=self.steps, color=color[k])])
                    for k, c in enumerate(f.channels)])
        figs.append(p)
        p = _fig("Tracking error spectrum", "frequency (Hz)", "amplitude", y_axis_type="log")
        _legend(p, [(c, [p.line("f", col("a", c), source=self.spectrum, color=color[k])])
                    for k, c in enumerate(f.channels)])
        figs.append(p)
        p = _fig("Measured vs target displacement", "target: the integrator's command (mm)", "measured (mm)")
        p.add_layout(Slope(gradient=1, y_intercept=0, line_color="gray", line_dash="dotted"))
        _legend(p, [(self._named(c, f.channel_unit), [p.line(col("target", c), col("disp", c), source=self.steps,
                                                             color=color[k])])
                    for k, c in enumerate(f.channels)])
        figs.append(p)
        p = _fig("Tracking indicator (falling: toward instability)", "time (s)", "TI, displacement control (mm^2)")
        ti_lines = [p.line("t", col("ti", c), source=self.steps, color=color[k]) for k, c in enumerate(f.channels)]
        # force control's own TI (kN^2) on the right axis, dashed: it moves only over FC steps
        force_lines = [p.line("t", col("tif", c), source=self.steps, color=color[k], line_dash="dashed",
                              y_range_name="force") for k, c in enumerate(f.channels)]
        p.extra_y_ranges = {"force": DataRange1d(renderers=force_lines)}
        p.add_layout(LinearAxis(y_range_name="force", axis_label="TI, force control (kN^2), dashed"), "right")
        # one entry per channel, for both of its lines (a click hides both)
        _legend(p, [(f"{c} (rad^2)" if f.channel_unit.get(c) == "rad" else c, [a, b])
                    for c, a, b in zip(f.channels, ti_lines, force_lines)])
        figs.append(p)
        p = _fig("Control mode (1 force, 0 displacement)", "time (s)", "mode", y_range=(-0.1, 1.1))
        _legend(p, [(d, [p.step("t", col("fc", d), source=self.steps, color=dof_color[k], mode="after")])
                    for k, d in enumerate(f.dofs)])
        figs.append(p)
        labels = [f"{c} {what}" for c in reversed(f.channels) for what in ("following", "force", "stroke")]
        p = _fig("Margins (% of the limit left)", "% left", "", y_range=labels,
                 x_range=(-10, 100), height=max(160, 22 * len(labels) + 60))
        p.hbar(y="label", right="value", height=0.7, color="color", source=self.margins)
        p.text(x=2, y="label", text="text", source=self.margins, text_font_size="8pt", text_baseline="middle")
        figs.append(p)
        grid = gridplot(figs, ncols=4, sizing_mode="stretch_width", merge_tools=False)
        self.doc.add_root(grid)
        self.doc.add_root(self.events)
        self.built = True

    def _rotations(self) -> bool:
        return "rad" in self.feed.dof_unit.values() or "rad" in self.feed.channel_unit.values()

    @staticmethod
    def _named(name: str, units: dict) -> str:
        """A legend's name, with "(rad)" for a rotation (the plot's axis reads mm)."""
        return f"{name} (rad)" if units.get(name) == "rad" else name

    # -- the periodic update -------------------------------------------------------------------
    def update(self) -> None:
        f = self.feed
        f.poll()
        if not f.opened:
            text = f"<b>hsio monitor</b>: waiting for {html.escape(str(f.path))} ..."
            if f.path.is_file() and being_written(f.path) is False:  # no run is creating it: none will
                text = (f"<b>hsio monitor</b>: {html.escape(str(f.path))} holds no run and no run is writing it"
                        f"{html.escape(without_journal(f.path))}")
            if self.status.text != text:
                self.status.text = text
            return
        if not self.built:
            self._build()
        if f.ns and len(self.ns.data["t"]) == 0:
            ns = f.ns_points(Decimation(self.decimation.cap).stride_for(f.ns_steps + 1))
            self.ns.data = {"t": ns["time_s"], **{col("u", d): ns[col("u", d)] for d in f.dofs}}
        n = f.n
        now = time.monotonic()
        lagging = backlog_bytes(self.doc) > BACKLOG_BYTES
        if n and now - self._plotted >= self.plot_every_s and (
                len(self.last.data["step"]) == 0 or self.last.data["step"][0] != f.last("step")):
            self._plotted = now
            if lagging:  # the tab has not read what it was sent: the plots wait, their points kept
                self.held_back += 1
                self._status(notices_only=True)
                return
            how, idx = self.decimation.update(n)
            if how == "replace":
                self.steps.data = self._rows(idx)
            elif len(idx):
                self.steps.stream(self._rows(idx))
            self.last.data = self._rows(np.array([n - 1]))
            if now - self._spectrum_at >= SPECTRUM_EVERY_S:
                self._spectrum_at = now
                self._spectrum()
            self._margins()
        self._status(notices_only=lagging)

    def _rows(self, idx: np.ndarray) -> dict:
        out = self.feed.rows(idx)
        out["t"], out["late"] = out.pop("time_s"), out.pop("late_steps")
        if len(idx) < 64:  # a few rows travel lighter as JSON numbers than as binary buffers
            out = {k: [None if not math.isfinite(x) else x for x in v.tolist()] for k, v in out.items()}
        return out

    def _spectrum(self) -> None:
        f = self.feed
        s = f.read_samples()
        out: dict = {}
        for c in f.channels:
            if s and col("cmd", c) in s and len(s[col("cmd", c)]) >= 64:
                # in force control the command is a force: its error is against the measured force
                measured = np.where(self._in_fc(c, s["step"]), s[col("force", c)], s[col("disp", c)])
                freq, amp = error_spectrum(s[col("cmd", c)] - measured, CONTROLLER_RATE_HZ)
            else:  # no controller samples recorded: the end-of-step errors at the lab's step rate
                step_s = float(f.meta.get("dt", 0.01)) * float(f.meta.get("test_rate", 1.0))
                freq, amp = error_spectrum(f[col("error", c)][-1024:], 1.0 / step_s)
            out.setdefault("f", freq)
            n = min(len(out["f"]), len(amp))
            out["f"] = out["f"][:n]
            out[col("a", c)] = np.maximum(amp[:n], 1e-9)
        for key in out:  # single precision: half the bytes, more than a plot can show
            out[key] = out[key][: len(out["f"])].astype(np.float32)
        self.spectrum.data = out

    def _in_fc(self, channel: str, steps: np.ndarray) -> np.ndarray:
        """Whether ``channel`` was in force control at each of ``steps`` (a step not read yet:
        as at the newest step read)."""
        f = self.feed
        dof = f.channel_dof.get(channel)
        if dof is None or not f.n:
            return np.zeros(len(steps), bool)
        recent = f["step"]  # the recent steps (the controller samples are of the last few)
        at = np.clip(np.searchsorted(recent, steps, side="right") - 1, 0, len(recent) - 1)
        return f[col("fc", dof)][at] > 0

    def limits(self) -> dict:
        """Half stroke (mm), force capacity (kN), following-error thresholds (mm, kN)."""
        meta = self.feed.meta
        lim = (meta.get("dry_run") or {}).get("limits") or {}
        safety = (meta.get("config") or {}).get("safety") or {}
        stroke = lim.get("stroke_mm")
        return {"half_stroke_mm": stroke / 2.0 if stroke else None, "force_kN": lim.get("force_kN"),
                "following_error_mm": safety.get("following_error_mm", 10.0),
                "following_error_kN": safety.get("following_error_kN", 25.0),
                "warning_fraction": safety.get("warning_fraction", 0.9)}

    def _margins(self) -> None:
        f, lim = self.feed, self.limits()
        warn = 1.0 - lim["warning_fraction"]
        labels, values, colors, texts = [], [], [], []
        for c in f.channels:
            dof = f.channel_dof.get(c)
            in_fc = dof is not None and f.last(col("fc", dof)) > 0
            actuator = "." not in c  # an element on a setup records its basic DOFs, not strokes
            stroke = lim["half_stroke_mm"] if actuator else None
            force = lim["force_kN"] if actuator else None
            # the least margin so far from the peaks of the whole run; the following error of each
            # step against its own mode's threshold (kN in force control, else mm)
            peak_dc, peak_fc = f.peak_error[c]
            if f.channel_unit.get(c) == "rad":  # a rotation: its actuators' strokes carry the interlock's mm
                follow, least_follow = None, float("nan")
            else:
                follow = lim["following_error_kN"] if in_fc else lim["following_error_mm"]
                least_follow = _least(margin(peak_dc, lim["following_error_mm"]), margin(peak_fc, lim["following_error_kN"]))
            for what, name, limit, least in (
                    ("stroke", col("disp", c), stroke, margin(f.peak[col("disp", c)], stroke)),
                    ("force", col("force", c), force, margin(f.peak[col("force", c)], force)),
                    ("following", col("error", c), follow, least_follow)):
                m = float(margin(f.last(name), limit))
                least = float(least)
                labels.append(f"{c} {what}")
                ok = math.isfinite(m)
                values.append(100.0 * m if ok else 0.0)
                colors.append("gray" if not ok else "crimson" if m < warn else "orange" if m < 2 * warn else "seagreen")
                if ok:
                    texts.append(f"{100 * m:.0f} % (least {100 * least:.0f} %)")
                elif limit is None or not float(limit) > 0:
                    texts.append("limit not known")
                else:  # the limit is known, the newest step has no number (a sensor that read NaN)
                    texts.append("no reading at the newest step" + (f" (least {100 * least:.0f} %)"
                                                                    if math.isfinite(least) else ""))
        self.margins.data = dict(label=labels, value=values, color=colors, text=texts)

    def _status(self, notices_only: bool = False) -> None:
        """The status, events and operator's requests. ``notices_only`` (a tab that lags): the
        status only if the run's state changed since the tab was last sent it; the events and
        the requests' replies whenever they change, as always."""
        f = self.feed
        n = f.n
        total = f.total_steps
        meta = f.meta
        line = self.operator.status()
        answers = self.operator.answers  # True, False, or None: not known yet / no answer in time
        running = answers is True and line.startswith("ok ")
        over = f.finished and answers is not True  # a run answering on its socket is never over
        if running:
            words = line.split()
            state = f"{words[1]} (phase {words[3]})" if len(words) >= 4 else line[3:]
            if len(words) >= 2 and words[1] == "paused":  # the hold as the run read it back, never assumed
                state += f": {self._pause_hold(words[-1])}"
        elif answers is True:
            state = f"the run answers: {line}"
        elif over:
            state = f"run over ({f.summary.get('outcome', 'ended')}); the record is closed"
            if f.summary.get("stopped"):
                state += f" ({f.summary['stopped']})"
            if f.summary.get("final_hold"):  # as the run read it back at its end
                state += f"; {f.summary['final_hold']}"
        elif answers is None:
            state = "waiting for the run's control socket to answer (the run busy, or hung)"
        elif not _has_control_socket(meta):
            state = ("the run has no control socket ([safety] control_socket = false): this page watches only; "
                     "pause or stop it where it runs")
        else:
            writing = being_written(f.path)  # the run's lock on its record: it is still there
            state = ("no answer from the run's control socket, though a run still writes the record" if writing else
                     "no answer from the run's control socket and no run writes the record: the run ended "
                     "without its summary (killed, or failed)" if writing is False else
                     "no answer from the run's control socket (a run killed, or started without one)")
        # Stop stays available unless no run can hear it: a run that answers, or may be there.
        trip = self._trip_to_acknowledge()
        if running and trip:
            state += f"; a controller tripped during the pause ({trip[:200]}): acknowledge it before resuming"
        run_state = line.split()[1] if running and len(line.split()) >= 2 else ""
        disabled = {"pause": run_state != "running", "resume": run_state not in ("pausing", "paused"),
                    "ack": not (running and trip),
                    "stop": over or answers is False}
        for action, b in zip(ACTIONS, self.buttons):
            if b.disabled != disabled[action]:
                b.disabled = disabled[action]
        last_step = int(f.last("step")) if n else 0
        t_now = f.last("time_s") if n else 0.0
        dt, tr = float(meta.get("dt", 0.0)), float(meta.get("test_rate", 0.0))
        rate = f.steps_per_second()
        items = [("run", f"{html.escape(str(meta.get('structure', '')))} under {html.escape(str(meta.get('record', '')))}, "
                         f"{html.escape(str(f.run_dir))}"),
                 ("state", f"<span id='hsio-state'>{html.escape(state)}</span>"),
                 ("step", f"<span id='hsio-step'>{last_step}</span>" + (f" of {total} ({100.0 * last_step / total:.1f} %)"
                                                                       if total else "") + f", t = {t_now:.3f} s")]
        if rate and not over and dt > 0:
            items.append(("test rate", f"TR {tr:g} configured, {1.0 / (rate * dt):.2f} measured ({rate:.1f} steps/s)"))
            if total:
                items.append(("time to finish", f"{max(total - last_step, 0) / rate:.1f} s"))
        else:
            items.append(("test rate", f"TR {tr:g} configured"))
        if n:
            late = int(f.last("late_steps")) if np.isfinite(f.last("late_steps")) else 0
            codes = f.phases()
            if not codes and ((meta.get("config") or {}).get("output") or {}).get("samples") is False:
                phase = "not recorded ([output] samples = false: no controller samples)"
            else:
                phase = ", ".join(f"{html.escape(c)} {PHASES.get(int(codes[c]) if c in codes else None, 'n/a')}"
                                  for c in f.channels)
            items.append(("command generator", f"{late} late steps; phase {phase}"))
            modes = []
            for d in f.dofs:
                switches = f.switches[d]
                unit = f.dof_unit.get(d, "mm")
                shown = (lambda x: f"{x:.2f}") if unit == "mm" else (lambda x: f"{x:.5f}")
                peak = f.peak[col("u", d)]
                ns_peak = f" (NS {shown(f.ns_peak[d])})" if f.ns else ""
                modes.append(f"{html.escape(d)} {'FC' if f.last(col('fc', d)) > 0 else 'DC'}, {switches} switches, "
                             f"peak |u| {shown(peak)} {unit}{ns_peak}")
            items.append(("DOFs", "; ".join(modes)))
        every = "every step" if self.decimation.stride == 1 else f"every {self.decimation.stride}th step"
        held = (f"; <span id='hsio-held'>{self.held_back}</span> updates held back while this page did not "
                "keep up (its plots then got the latest points at once)") if self.held_back else ""
        items.append(("plots", f"{every} "
                               f"({len(self.steps.data['t']) if self.built else 0} points); red dot: the newest step"
                               + held))
        text = "<table style='font-size:10pt'>" + "".join(
            f"<tr><td><b>{k}</b></td><td>{v}</td></tr>" for k, v in items) + "</table>"
        if self.status.text != text and (not notices_only or state != self._sent_state):
            self.status.text = text
            self._sent_state = state
        if f.events:
            rows = "".join(f"<tr><td>{'' if e['time_s'] is None else format(e['time_s'], '.2f')}</td>"
                           f"<td>{e['step'] if e['step'] is not None else ''}</td><td>{html.escape(str(e['kind']))}</td>"
                           f"<td>{html.escape(str(e['actuator'] or ''))}</td>"
                           f"<td>{html.escape(str(e['message'])[:300])}</td></tr>" for e in f.events[-8:])
            text = ("<b>Events of the run</b> (lab time s, step, kind, actuator, message)"
                    f"<table style='font-size:9pt'>{rows}</table>")
            if self.events.text != text:
                self.events.text = text
        log = self.operator.log[-6:]
        text = "<br>".join(html.escape(x) for x in log) if log else "operator requests are logged here and in operator.log"
        text = f"<span style='font-size:9pt' id='hsio-actions'>{text}</span>"
        if self.actions.text != text:
            self.actions.text = text

    def _trip_to_acknowledge(self) -> str:
        """The newest controller trip of the record not yet acknowledged nor followed by a resume
        (its message), or ''."""
        for e in reversed(self.feed.marks):
            if e["kind"] in ("acknowledge", "resume"):
                return ""
            if e["kind"] == "controller_trip":
                return str(e["message"])
        return ""

    def _pause_hold(self, step: str) -> str:
        """What the run read back of the actuators' hold when it paused after ``step`` (its
        ``pause`` event), or that it is not in the record yet: the newest pause or resume of the
        record must be that pause (a ramp of the static preloads pauses at the same step again)."""
        for e in reversed(self.feed.marks):
            if e["kind"] in ("pause", "resume"):
                if e["kind"] == "resume":
                    break
                if str(e["step"]) == step:
                    return str(e["message"]).partition(": ")[2] or str(e["message"])
                break
        return "the hold's read-back is not in the record yet"

    # -- the operator --------------------------------------------------------------------------
    def _on_request(self, attr, old, new) -> None:
        action = new.split(" ")[0] if new else ""
        if not action:
            return
        request = self.doc.session_context.request if self.doc.session_context else None
        who = f"the monitor page ({request.remote_ip})" if request is not None and getattr(request, "remote_ip", None) \
            else "the monitor page"
        doc = self.doc

        def answered(_future) -> None:  # in the worker thread: the page is changed on its own loop
            try:
                doc.add_next_tick_callback(self._status)
            except Exception:  # the tab closed meanwhile
                pass

        self.operator.submit(action, who).add_done_callback(answered)


def _least(*margins: float) -> float:
    """The least of ``margins`` that is known (NaN if none is)."""
    known = [float(m) for m in margins if math.isfinite(m)]
    return min(known) if known else float("nan")


def _has_control_socket(meta: dict) -> bool:
    """Whether the run was started with a control socket ([safety] control_socket, on unless its
    recorded configuration says otherwise)."""
    safety = (meta.get("config") or {}).get("safety") if isinstance(meta.get("config"), dict) else None
    return not (isinstance(safety, dict) and safety.get("control_socket") is False)
