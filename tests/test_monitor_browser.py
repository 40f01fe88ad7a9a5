"""The monitor page in a real headless browser (Debian's chromium): a real-time emulated run
followed live (new steps on the page within 1 s of their commit), paused, resumed and stopped from
the page; then the replay of its record shows the same plots. Skipped only where Debian's
chromium or chromedriver is not installed; selenium is a test dependency (its absence fails)."""

from __future__ import annotations

import contextlib
import os
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from hsio.monitor import browser
from hsio.recording import Run
from wire import terminate

ABSENT = [p for p in (browser.CHROMIUM, browser.CHROMEDRIVER) if not Path(p).exists()]
pytestmark = pytest.mark.skipif(bool(ABSENT), reason=f"{', '.join(ABSENT)} not installed "
                                                     "(Debian: apt-get install chromium chromium-driver)")
LATENCY_WINDOW_S = 4.0

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
RUN = """[structure]
name = "validation"
[record]
duration_s = 20.0
pga_g = 0.15
[test]
rate = 2.0
[hardware]
clock = "realtime"
[emulator]
noise_mm = 0.0
resolution_mm = 0.0
force_noise_kN = 0.0
force_resolution_kN = 0.0
[output]
plots = false
[safety]
keys = false
"""


class Lines(threading.Thread):
    """Collects a pipe's lines in the background."""

    def __init__(self, pipe):
        super().__init__(daemon=True)
        self.pipe, self.lines = pipe, []
        self.start()

    def run(self):
        with self.pipe:  # closed at its end (the process gone)
            for line in self.pipe:
                self.lines.append(line)

    def wait_for(self, text: str, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for line in list(self.lines):
                if text in line:
                    return line
            time.sleep(0.05)
        raise AssertionError(f"never printed {text!r}: {''.join(self.lines)}")


class Committed(threading.Thread):
    """Polls run.sqlite (read-only) every few ms: when each step was first seen committed."""

    def __init__(self, path: Path):
        super().__init__(daemon=True)
        self.path, self.first_seen, self.stop = path, {}, threading.Event()
        self.start()

    def run(self):
        db = None
        deadline = time.monotonic() + 120
        while not self.stop.is_set() and time.monotonic() < deadline:
            try:
                if db is None and self.path.exists():
                    db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True)
                if db is not None:
                    n = db.execute("SELECT MAX(step) FROM steps").fetchone()[0]
                    if n is not None and n not in self.first_seen:
                        self.first_seen[n] = time.monotonic()
            except sqlite3.DatabaseError:
                pass
            time.sleep(0.003)
        if db is not None:
            db.close()

    def steps(self) -> int:
        return max(self.first_seen, default=0)


# The rendered <button> with a given text, searched through Bokeh's shadow DOM, clicked.
FIND_BUTTON = """
const find = (root) => {
  for (const el of root.querySelectorAll('*')) {
    if (el.tagName === 'BUTTON' && el.textContent.trim() === arguments[0]) return el;
    if (el.shadowRoot) { const hit = find(el.shadowRoot); if (hit) return hit; }
  }
  return null;
};
const button = find(document);
if (!button) return false;
setTimeout(() => button.click(), 0);  // after this script returns: the click opens a modal dialog
return true;
"""


# The step in the status line and the newest step on the plots, as the browser holds them.
SHOWN = """
const d = Bokeh.documents[0];
const m = d.get_model_by_name('status').text.match(/hsio-step'>(\\d+)/);
const h = d.get_model_by_name('head').data.step;
return [m ? Number(m[1]) : 0, h.length ? h[0] : 0];
"""


def confirm(b, name: str, accept: bool = True) -> None:
    """Click the page's button ``name`` and answer its confirm dialog."""
    from selenium.webdriver.support.ui import WebDriverWait

    label = b.model(name, "m.label")
    clicked = b.driver.execute_script(FIND_BUTTON, label)
    assert clicked, f"no button {label!r} on the page"
    alert = WebDriverWait(b.driver, 5).until(lambda d: d.switch_to.alert)
    assert "?" in alert.text
    alert.accept() if accept else alert.dismiss()


def state(b) -> str:
    """The run's state as the page's status line shows it."""
    return b.model("status", "(m.text.match(/hsio-state'>([^<]*)</) || ['', ''])[1]") or ""


def wait_page(b, predicate, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.02)
    raise AssertionError(f"the page never showed {what}; status: {state(b)}")


def ended(proc: subprocess.Popen) -> None:
    """The run ended (its pipes are closed by their readers)."""
    terminate(proc, 20.0)


def test_live_run_paused_resumed_and_stopped_from_the_page_then_replayed(tmp_path):
    import selenium  # noqa: F401  (a test dependency: missing, the test fails)

    (tmp_path / "run.toml").write_text(RUN)
    out = tmp_path / "o"
    with contextlib.ExitStack() as cleanup:  # whatever fails, nothing is left running
        proc = subprocess.Popen([sys.executable, "-m", "hsio.cli", "run", "run.toml", "--out", str(out), "--monitor",
                                 "--monitor-port", "0"], cwd=tmp_path, env=ENV, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        cleanup.callback(ended, proc)
        err = Lines(proc.stderr)
        b = cleanup.enter_context(browser.Browser())  # starts while the run does its dry run
        url = err.wait_for("monitor at http://127.0.0.1:", 60).rpartition(" at ")[2].strip()
        committed = Committed(out / "run.sqlite")
        cleanup.callback(committed.stop.set)
        b.driver.get(url)
        # 1. New steps reach the page within 1 s of their commit: the step in the status line,
        # and the newest step drawn on the plots (the red dot); the median over a few seconds
        # (one late update on a busy machine is not what this measures).
        wait_page(b, lambda: b.model("head", "m.data.step.length ? m.data.step[0] : 0"), 60, "a step")
        shown: dict[str, dict[int, float]] = {"status": {}, "plots": {}}
        end = time.monotonic() + LATENCY_WINDOW_S
        while time.monotonic() < end:
            for where, k in zip(("status", "plots"), b.driver.execute_script(SHOWN)):
                if k and int(k) not in shown[where]:
                    shown[where][int(k)] = time.monotonic()
            time.sleep(0.01)
        for where, seen in shown.items():
            lags = [t - committed.first_seen[k] for k, t in seen.items() if k in committed.first_seen]
            assert len(lags) >= 3, (where, seen)
            print(f"{where}: new steps shown {np.median(lags) * 1e3:.0f} ms after their commit (median), "
                  f"{np.percentile(lags, 90) * 1e3:.0f} ms (90th percentile), {max(lags) * 1e3:.0f} ms at most, "
                  f"over {len(lags)} updates")
            assert np.median(lags) < 1.0, where
        # every asset from the local server (the sources the page loads, not its data, which is
        # base64 and may spell anything)
        sources = b.driver.execute_script(
            "return Array.from(document.querySelectorAll('script[src], link[href], img[src]'))"
            ".map(e => e.src || e.href)")
        assert sources and all(src.startswith(url.split("?")[0].rsplit("/", 1)[0]) or src.startswith("/")
                               for src in sources), sources

        # 2. A pause dismissed at its confirmation does nothing; a confirmed one holds the actuators.
        confirm(b, "pause_button", accept=False)
        time.sleep(0.3)
        assert not (out / "operator.log").exists() and "running" in state(b)
        confirm(b, "pause_button")
        wait_page(b, lambda: "paused" in state(b), 10, "the pause")
        held_at = committed.steps()
        time.sleep(1.0)
        assert committed.steps() == held_at  # not a step while paused
        assert "paused" in state(b)
        assert b.model("stop_button", "m.disabled") is False

        # 3. Resume continues.
        confirm(b, "resume_button")
        wait_page(b, lambda: committed.steps() > held_at + 5, 10, "steps after the resume")
        wait_page(b, lambda: "running" in state(b), 5, "running again")

        # 4. Stop ends the run, the record closed, and the page says so.
        confirm(b, "stop_button")
        proc.wait(timeout=60)
        wait_page(b, lambda: "the record is closed" in state(b), 5, "the closed record")
        live = {k: b.model("steps", f"Array.from(m.data[{k!r}])") for k in ("step", "t", "u_C1", "force_C2")}
        # The replay's server starts while the record is checked.
        mon = subprocess.Popen([sys.executable, "-m", "hsio.cli", "monitor", str(out), "--port", "0"], env=ENV,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        cleanup.callback(ended, mon)
        assert proc.returncode == 5, "".join(err.lines)

        run = Run(out / "run.sqlite")
        assert run.summary["exit_status"] == 5 and run.summary["outcome"] == "stopped by the operator"
        events = run.events()
        kinds = [e["kind"] for e in events]
        assert kinds.count("pause") == 1 and kinds.count("resume") == 1 and kinds[-1] == "stop"
        pause = events[kinds.index("pause")]
        assert "the actuators hold (confirmed by read-back)" in pause["message"]
        assert "control socket" in events[-1]["message"]
        # No motion while paused. With no noise and no quantisation in the emulator: from the last
        # sample before the pause to the first after the resume (lab time, over a second apart) a
        # rod moves no further than the rest of its approach to its last command plus the one
        # controller period that follows (it starts again in that period); a rod that crept
        # during the pause would be far out.
        samples, resume = run.samples(), events[kinds.index("resume")]
        lab = samples["lab_time_s"]
        held, again = lab <= pause["time_s"], lab >= resume["time_s"]
        assert held.any() and again.sum() >= 2 and lab[again][0] - lab[held][-1] > 0.5
        for c in ("C1", "C2"):
            before, (after, next_) = samples[f"disp_{c}"][held][-1], samples[f"disp_{c}"][again][:2]
            command = samples[f"cmd_{c}"][held][-1]
            assert abs(after - before) <= abs(command - before) + 2.0 * abs(next_ - after) + 1e-6, \
                (c, before, after, next_, command)
        log = (out / "operator.log").read_text().splitlines()
        assert [line.split()[1] for line in log] == ["pause", "resume", "stop"]
        assert all(line[:4].isdigit() and line[19] == "Z" for line in log)  # each with its UTC time
        assert log[-1].endswith("ok stopping")

        # The page had every recorded step (a short run: no decimation).
        assert live["step"] == [float(x) for x in run.steps["step"]]
        np.testing.assert_allclose(live["u_C1"], run.steps["u_C1"])

        # 5. The replay of the record shows the same plots.
        url = Lines(mon.stdout).wait_for("serving", 60).rpartition(" at ")[2].strip()
        b.driver.get(url)
        wait_page(b, lambda: "the record is closed" in state(b), 30, "the replay")
        replay = {k: b.model("steps", f"Array.from(m.data[{k!r}])") for k in live}
        assert all(b.model(f"{a}_button", "m.disabled") is True for a in ("pause", "resume", "stop"))
        assert replay == live


def test_a_page_that_loses_its_monitor_says_the_state_is_not_known(tmp_path):
    """A run answering on its socket (the page: running, Stop enabled); then the page's server
    goes (a run killed takes its monitor with it): the page must not go on showing its last
    state, say a hold, as if it still followed the run."""
    import selenium  # noqa: F401

    from hsio.monitor.server import READY
    from hsio.safety.control import RunControl
    from hsio.safety.socket import ControlServer
    from test_monitor import write_record

    rec = write_record(tmp_path, 30)
    with contextlib.ExitStack() as cleanup:
        server = ControlServer(tmp_path, RunControl())
        cleanup.callback(server.close)
        rec.write_meta({"control_socket": str(server.path)})
        rec.close()
        mon = subprocess.Popen([sys.executable, "-m", "hsio.cli", "monitor", str(tmp_path), "--port", "0"], env=ENV,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        cleanup.callback(ended, mon)
        b = cleanup.enter_context(browser.Browser())
        b.driver.get(Lines(mon.stdout).wait_for(READY, 60).rpartition(" at ")[2].strip())
        wait_page(b, lambda: state(b).startswith("running"), 30, "the run answering")
        assert b.model("stop_button", "m.disabled") is False
        mon.terminate()
        mon.wait(timeout=20)
        wait_page(b, lambda: "lost its connection" in state(b), 20, "the lost connection")
        time.sleep(1.0)  # said once, not again over itself
        # what it showed last: running, or (on a loaded machine) the socket slow to answer
        assert state(b).startswith("not known") and state(b).count("(it showed: ") == 1, state(b)
        assert all(b.model(f"{a}_button", "m.disabled") is True for a in ("pause", "resume", "stop"))


# The element that holds the status (its shadow root shows the state), as the browser lays it out.
STATUS_BOX = """
const find = (root) => {
  for (const el of root.querySelectorAll('*')) {
    if (!el.shadowRoot) continue;
    if (el.shadowRoot.innerHTML.includes("hsio-state")) return el;
    const hit = find(el.shadowRoot);
    if (hit) return hit;
  }
  return null;
};
const box = find(document);
return box ? [box.scrollHeight, box.clientHeight, getComputedStyle(box).overflowY] : null;
"""


def replayed_page(cleanup: contextlib.ExitStack, tmp_path, names: list[str]):
    """A finished record of 20 steps with one DOF and one actuator per name, replayed by `hsio
    monitor` in a headless browser (closed by ``cleanup``): the browser, once the page shows the
    record closed."""
    from hsio.monitor.server import READY
    from hsio.recording import Recorder

    rec = Recorder(tmp_path / "run.sqlite", names, names, {"structure": "chain", "record": "sine", "dt": 0.01,
                                                           "test_rate": 2.0, "config": {}})
    for k in range(1, 21):
        u = [np.sin(0.1 * k + j) for j in range(len(names))]
        rec.write_step(k, 0.01 * k, u, u, u, u, u, ["displacement"] * len(names), u, u, u, u)
    rec.write_summary({"steps": 20, "outcome": "finished"})
    rec.close()
    mon = subprocess.Popen([sys.executable, "-m", "hsio.cli", "monitor", str(tmp_path), "--port", "0"], env=ENV,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    cleanup.callback(ended, mon)
    b = cleanup.enter_context(browser.Browser())
    b.driver.get(Lines(mon.stdout).wait_for(READY, 60).rpartition(" at ")[2].strip())
    wait_page(b, lambda: "the record is closed" in state(b), 30, "the replay")
    return b


def test_the_status_of_many_dofs_scrolls_in_its_box_not_under_the_plots(tmp_path):
    """Twelve DOFs and actuators: the status is longer than its fixed box; the rest is reached by
    scrolling it, not drawn under the plots, where the last DOFs could not be read."""
    import selenium  # noqa: F401

    with contextlib.ExitStack() as cleanup:
        b = replayed_page(cleanup, tmp_path, [f"floor_{i:02d}_lateral_x" for i in range(1, 13)])
        wait_page(b, lambda: "floor_12_lateral_x DC" in (b.model("status", "m.text") or ""), 10, "the last DOF")
        scroll, client, overflow = b.driver.execute_script(STATUS_BOX)
        assert scroll > client  # longer than its box (else this test shows nothing)
        assert overflow in ("auto", "scroll"), overflow


# Every legend of the page as the browser lays it out: its entries, its box and its plot's canvas
# (both in the canvas's pixels), and the colour of each entry's first line.
LEGENDS = """
const seen = new Set(), found = [];
const walk = (v) => {
  if (!v || seen.has(v)) return;
  seen.add(v);
  if (v.model && v.model.type === 'Legend') found.push(v);
  let kids = [];
  try { kids = [...(v.children ? v.children() : [])]; } catch (e) {}
  for (const k of kids) walk(k);
  for (const k of (v.child_views || [])) walk(k);
  if (v.renderer_views) for (const k of v.renderer_views.values()) walk(k);
};
for (const r of Bokeh.index.roots) walk(r);
return found.map(v => {
  const b = v.bbox, c = v.parent.canvas_view.bbox;
  return {entries: v.model.items.length, box: [b.left, b.top, b.right, b.bottom],
          canvas: [c.left, c.top, c.right, c.bottom],
          colors: v.model.items.map(i => JSON.stringify(i.renderers[0].glyph.line_color))};
});
"""


def test_sixteen_channels_have_distinct_colours_and_legends_that_show_every_entry(tmp_path):
    """Sixteen channels: each plot's legend holds all sixteen, inside its plot's canvas (none cut
    off at the plot's edge), and the sixteen lines of a plot are of sixteen colours."""
    import selenium  # noqa: F401

    with contextlib.ExitStack() as cleanup:
        b = replayed_page(cleanup, tmp_path, [f"floor_{i:02d}_x" for i in range(1, 17)])
        legends = wait_page(b, lambda: (lambda got: got if len(got) == 7 else None)(b.driver.execute_script(LEGENDS)),
                            10, "the plots' legends")
        for legend in legends:  # seven plots: one per DOF or per channel (the margins have none)
            assert legend["entries"] == 16, legend
            assert len(set(legend["colors"])) == 16, legend["colors"]
            (left, top, right, bottom), (c_left, c_top, c_right, c_bottom) = legend["box"], legend["canvas"]
            assert c_left <= left and c_top <= top and right <= c_right and bottom <= c_bottom, legend
