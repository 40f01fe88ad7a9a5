"""The monitor without a browser: the error monitors against closed forms, the decimation's
invariants, the record feed against the recorded run, the page's update payload with 20,000
steps recorded, the token off the loopback, and clear errors."""

from __future__ import annotations

import html
import os
import re
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hsio.monitor.decimate import Decimation
from hsio.monitor.feed import RecordFeed
from hsio.monitor.indicators import error_spectrum, margin, tracking_indicator
from hsio.monitor.operator import LOG_FILE, Operator
from hsio.recording import Recorder, Run

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


# -- the error monitors ---------------------------------------------------------------------------
@pytest.mark.parametrize("phi", [0.05, 0.3, -0.2])
def test_tracking_indicator_of_a_lagging_sine_is_minus_pi_a_squared_sin_phi_per_cycle(phi):
    """d_c = A sin(wt), d_m = A sin(wt - phi): the measured-vs-command loop encloses pi A^2 sin(phi)
    counter-clockwise each cycle, so TI falls by that much (rises for a lead, phi < 0)."""
    A, cycles, n = 3.0, 4, 4000
    theta = np.linspace(0.0, 2 * np.pi * cycles, n * cycles + 1)
    ti = tracking_indicator(A * np.sin(theta), A * np.sin(theta - phi))
    expected = -np.pi * A ** 2 * np.sin(phi) * cycles
    assert ti[-1] == pytest.approx(expected, rel=1e-4)
    assert np.sign(ti[-1]) == -np.sign(phi)  # negative when the measurement lags: toward instability


def test_tracking_indicator_of_perfect_tracking_is_zero():
    d = np.sin(np.linspace(0, 20, 999)) * 5
    np.testing.assert_allclose(tracking_indicator(d, d), 0.0, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(1, 50), min_size=1, max_size=8))
def test_tracking_indicator_continued_in_chunks_equals_the_whole(chunks):
    rng = np.random.default_rng(len(chunks))
    n = sum(chunks)
    dc, dm = rng.normal(size=n), rng.normal(size=n)
    whole = tracking_indicator(dc, dm)
    parts, start, previous, i = [], 0.0, None, 0
    for m in chunks:
        ti = tracking_indicator(dc[i:i + m], dm[i:i + m], start, previous)
        parts.append(ti)
        start, previous, i = ti[-1], (dc[i + m - 1], dm[i + m - 1]), i + m
    np.testing.assert_allclose(np.concatenate(parts), whole, atol=1e-9)


def test_error_spectrum_reads_a_sine_at_its_frequency_and_amplitude():
    rate, f0, a = 1024.0, 12.0, 0.037
    t = np.arange(4096) / rate
    f, amp = error_spectrum(0.5 + a * np.sin(2 * np.pi * f0 * t), rate)
    assert f[-1] <= 100.0 and f[np.argmax(amp)] == pytest.approx(f0, abs=rate / 4096)
    assert amp.max() == pytest.approx(a, rel=0.02)  # the mean (0.5) is removed


def test_margin_is_the_fraction_of_the_limit_left():
    assert margin(-90.0, 100.0) == pytest.approx(0.1)
    assert margin(120.0, 100.0) == pytest.approx(-0.2)
    assert np.isnan(margin(1.0, None))


# -- decimation -------------------------------------------------------------------------------------
@settings(max_examples=30, deadline=None)
@given(st.integers(10, 400), st.lists(st.integers(0, 900), min_size=1, max_size=60))
def test_decimation_keeps_the_page_equal_to_every_stride_th_step_and_under_the_cap(cap, increments):
    d = Decimation(cap)
    page: list[int] = []
    n, sent = 0, 0
    for inc in increments:
        n += inc
        how, idx = d.update(n)
        page = list(idx) if how == "replace" else page + list(idx)
        sent += len(idx)
        assert page == list(range(0, n, d.stride))
        assert len(page) <= cap
    # What was sent in all: the final page plus one rebuild per doubling of the stride.
    doublings = int(np.log2(d.stride))
    assert sent <= len(page) + doublings * cap


def test_decimation_of_20000_steps_streams_only_new_points():
    d = Decimation(3000)
    sizes = []
    for n in range(0, 20001, 7):
        how, idx = d.update(n)
        sizes.append((how, len(idx)))
    assert d.stride == 8 and -(-20000 // 8) <= 3000
    assert max(k for how, k in sizes if how == "stream") <= 7  # at most the new steps
    assert sum(1 for how, _ in sizes if how == "replace") <= 4


# -- the feed and the page on a record ---------------------------------------------------------------
def write_record(folder: Path, steps: int, ns: bool = True, commit_every: int | None = None) -> Recorder:
    """A record of a sine test on two channels (C1, C2 on DOFs C1, C2), ``steps`` steps, in bulk."""
    meta = {"structure": "validation", "record": "sine", "dt": 0.01, "test_rate": 2.0,
            "config": {"structure": {"name": "validation", "file": ""},
                       "safety": {"following_error_mm": 10.0, "following_error_kN": 25.0, "warning_fraction": 0.9}},
            "dry_run": {"limits": {"stroke_mm": 254.0, "force_kN": 250.0, "velocity_mm_s": 500.0}}}
    rec = Recorder(folder / "run.sqlite", ["C1", "C2"], ["C1", "C2"], meta)
    rec.db.execute("PRAGMA synchronous=OFF")
    t = np.arange(steps + 1) * 0.01
    u = np.column_stack([10 * np.sin(2 * np.pi * 0.5 * t), 8 * np.sin(2 * np.pi * 0.7 * t)])
    if ns:
        rec.write_ns(t, u * 1.01)
    rows = []
    for k in range(1, steps + 1):
        lag = u[k - 1] + 0.9 * (u[k] - u[k - 1])  # the measurement lags its command
        row = [k, t[k]]
        for j in range(2):
            row += [u[k, j], 0.0, 0.0, u[k, j], 0.5 * u[k, j]]
        row += ["displacement", "displacement"]
        for j in range(2):
            row += [u[k, j], u[k, j], lag[j], 0.5 * lag[j]]
        row += [0, ""]
        rows.append(row)
        if commit_every and k % commit_every == 0:
            rec.db.executemany(rec._insert_step, rows)
            rec.db.commit()
            rows = []
    if rows:
        rec.db.executemany(rec._insert_step, rows)
        rec.db.commit()
    return rec


def test_the_feed_reads_a_growing_record_step_for_step(tmp_path):
    rec = write_record(tmp_path, 0)
    feed = RecordFeed(tmp_path)
    assert feed.poll(force=True) == 0 and feed.opened and feed.n == 0 and feed.total_steps == 0
    t = np.arange(1, 501) * 0.01
    got = []
    for k in range(1, 501):
        rec.write_step(k, t[k - 1], [k, 2 * k], [0, 0], [0, 0], [k, 2 * k], [0, 0], ["displacement"] * 2,
                       [k, 2 * k], [k, 2 * k], [k - 0.5, 2 * k - 1], [0.1, 0.2])
        if k % 37 == 0 or k == 500:
            got.append(feed.poll(force=True))
    rec.write_event(1.0, 500, "warning", "C1", "a warning")
    feed.poll(force=True)
    rec.write_summary({"steps": 500, "outcome": "finished"})
    feed.poll(force=True)
    rec.close()
    run = Run(tmp_path / "run.sqlite")
    assert sum(got) == 500 and feed.n == 500 and feed.finished
    np.testing.assert_array_equal(feed["u_C2"], run.steps["u_C2"])
    np.testing.assert_array_equal(feed["error_C1"], run.steps["target_C1"] - run.steps["disp_C1"])
    np.testing.assert_allclose(feed["ti_C1"], tracking_indicator(run.steps["target_C1"], run.steps["disp_C1"]))
    assert feed.events[-1]["message"] == "a warning"
    assert feed.channel_dof == {"C1": "C1", "C2": "C2"}


class CountingConnection:
    """The feed's SQLite connection, counting the reads of the summary table."""

    def __init__(self, db):
        self.db, self.summary_reads = db, 0

    def execute(self, sql, *args):
        self.summary_reads += "FROM summary" in sql
        return self.db.execute(sql, *args)

    def close(self):
        self.db.close()


def test_the_summary_is_read_again_only_after_a_commit(tmp_path):
    """Polls of an unchanged record read the summary once; a commit of the run (a step, the
    summary, a resume's new summary) makes the next poll read it again. The summary's commit
    leaves run.sqlite's size and mtime as they were (WAL), yet the feed sees it."""
    rec = write_record(tmp_path, 20)
    feed = RecordFeed(tmp_path)
    assert feed.poll(force=True) == 20 and feed.summary == {}
    feed.db = counting = CountingConnection(feed.db)
    for _ in range(5):
        assert feed.poll(force=True) == 0
    assert counting.summary_reads == 0  # read at the first poll; nothing committed since
    stat = (tmp_path / "run.sqlite").stat()
    rec.write_summary({"steps": 20, "outcome": "finished"})
    after = (tmp_path / "run.sqlite").stat()
    assert (after.st_size, after.st_mtime_ns) == (stat.st_size, stat.st_mtime_ns)  # in the WAL, not the file
    assert feed.poll(force=True) == 0 and counting.summary_reads == 1
    assert feed.summary == {"steps": 20, "outcome": "finished"} and feed.finished
    for _ in range(5):
        feed.poll(force=True)
    assert counting.summary_reads == 1
    rec.write_event(None, 20, "resume", "", "resumed after step 20")
    rec.write_step(21, 0.21, [0, 0], [0, 0], [0, 0], [0, 0], [0, 0], ["displacement"] * 2,
                   [0, 0], [0, 0], [0, 0], [0, 0])
    assert feed.poll(force=True) == 1 and counting.summary_reads == 2 and not feed.finished  # open again
    rec.write_summary({"steps": 21, "outcome": "finished", "resumed_from": 20})
    feed.poll(force=True)
    assert counting.summary_reads == 3 and feed.summary["steps"] == 21 and feed.finished
    rec.close()
    assert feed.poll(force=True) == 0 and feed.summary["steps"] == 21
    reads = counting.summary_reads
    feed.poll(force=True)
    assert counting.summary_reads == reads


def test_force_control_steps_have_their_own_tracking_indicator(tmp_path):
    """C1 runs one cycle in DC and then one in FC, its loop lagging by phi in each: the DC
    indicator falls by pi A^2 sin phi (mm^2) over the DC cycle and stays put over the FC one; the
    FC indicator does the opposite in kN^2 (before: the FC steps were invisible)."""
    meta = {"structure": "validation", "record": "sine", "dt": 0.01, "test_rate": 2.0,
            "config": {"structure": {"name": "validation", "file": ""}}}
    rec = Recorder(tmp_path / "run.sqlite", ["C1"], ["C1"], meta)
    n, phi, A_mm, A_kN = 400, 0.2, 5.0, 3.0
    theta = 2 * np.pi * np.arange(1, 2 * n + 1) / n
    for k in range(1, 2 * n + 1):
        th = theta[k - 1]
        if k <= n:  # DC: target and measured displacement; the force follows the specimen
            mode, target, disp, force = "displacement", A_mm * np.sin(th), A_mm * np.sin(th - phi), 0.6 * A_mm * np.sin(th - phi)
        else:  # FC: target and measured force
            mode, target, force, disp = "force", A_kN * np.sin(th), A_kN * np.sin(th - phi), A_kN * np.sin(th - phi) / 0.6
        rec.write_step(k, 0.01 * k, [disp], [0], [0], [disp], [force], [mode], [target], [target], [disp], [force])
    rec.close()
    feed = RecordFeed(tmp_path)
    feed.poll(force=True)
    ti, tif = feed["ti_C1"], feed["tif_C1"]
    assert feed.n == 2 * n
    # the first point opens the curve; a whole cycle of the lagging loop sweeps -pi A^2 sin(phi)
    assert ti[n - 1] == pytest.approx(-np.pi * A_mm ** 2 * np.sin(phi), rel=0.02)
    assert abs(ti[-1] - ti[n]) < 0.02 * abs(ti[n - 1])  # nothing over the FC cycle
    assert tif[-1] - tif[n] == pytest.approx(-np.pi * A_kN ** 2 * np.sin(phi), rel=0.02)
    assert abs(tif[n - 1]) < 0.02 * np.pi * A_kN ** 2 * np.sin(phi)  # nothing over the DC cycle


def patch_bytes(events) -> int:
    """The bytes of the PATCH-DOC message that carries ``events`` to a browser."""
    from bokeh.protocol import Protocol

    if not events:
        return 0
    msg = Protocol().create("PATCH-DOC", events)
    return (len(msg.header_json) + len(msg.metadata_json) + len(msg.content_json)
            + sum(len(b.to_bytes()) for b in msg.buffers))


def test_the_page_sends_a_few_kilobytes_per_update_with_20000_steps_recorded(tmp_path):
    from bokeh.document import Document

    from hsio.monitor import page as page_mod

    rec = write_record(tmp_path, 20_000)
    feed = RecordFeed(tmp_path)
    doc = Document()
    page = page_mod.MonitorPage(doc, feed, Operator(tmp_path))
    assert page.built and feed.n == 20_000
    shown = len(page.steps.data["t"])
    assert shown <= page.decimation.cap and page.decimation.stride == 8
    np.testing.assert_array_equal(page.steps.data["step"], np.arange(1, 20_001, 8))
    assert np.max(np.abs(page.steps.data["u_C1"])) == pytest.approx(10.0, rel=1e-3)
    assert page.ns.data["t"].size <= page.decimation.cap
    events = []
    doc.on_change(lambda e: events.append(e))
    sizes, times = [], []
    t = np.arange(20_001, 20_101) * 0.01
    for i in range(10):  # ten more steps at a time, as a running test commits them
        for k in range(20_001 + 10 * i, 20_011 + 10 * i):
            u = [np.sin(k), np.cos(k)]
            rec.write_step(k, t[k - 20_001], u, [0, 0], [0, 0], u, [0, 0], ["displacement"] * 2, u, u, u, u)
        events.clear()
        page._plotted = 0.0  # as if the plots' turn had come
        feed._last_poll = 0.0
        started = time.perf_counter()
        page.update()
        times.append(time.perf_counter() - started)
        sizes.append(patch_bytes(events))
    rec.close()
    assert page.steps.data["step"][-1] == 20_097 and page.last.data["step"][0] == 20_100  # every 8th row
    print(f"20,000 steps recorded: {shown} points shown; per update {np.median(sizes) / 1e3:.1f} kB, "
          f"{np.median(times) * 1e3:.1f} ms on the server")
    assert np.median(sizes) < 5_000 and max(sizes) < 20_000  # a few kB: never the record again


# -- the server: the token, clear errors ------------------------------------------------------------
def start_monitor(run_dir: Path, *args: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([sys.executable, "-m", "hsio.cli", "monitor", str(run_dir), *args], env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if "serving" not in line:
        proc.kill()
        raise AssertionError(f"no monitor: {line}{proc.stderr.read()}")
    return proc, line.rpartition(" at ")[2].strip()


def get(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=20) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()


def test_off_the_loopback_the_page_needs_the_token_printed_at_start_up(tmp_path):
    write_record(tmp_path, 50).close()
    # 127.0.0.2 is on the loopback interface but is not the loopback address the monitor trusts.
    proc, url = start_monitor(tmp_path, "--host", "127.0.0.2", "--port", "0")
    try:
        base, _, token = url.partition("?token=")
        assert len(token) >= 20
        status, text = get(base)
        assert status == 403 and "token" in text
        assert get(base + "?token=wrong")[0] == 403
        status, text = get(url)
        assert status == 200 and "bokeh" in text.lower() and "cdn.bokeh.org" not in text
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_on_the_loopback_the_page_is_served_without_a_token_and_from_local_assets(tmp_path):
    write_record(tmp_path, 50).close()
    proc, url = start_monitor(tmp_path, "--port", "0")
    try:
        assert url.startswith("http://127.0.0.1:") and "token" not in url
        status, text = get(url)
        assert status == 200 and "/static/js/bokeh.min.js" in text
        sources = re.findall(r'<(?:script|link|img)\b[^>]*\b(?:src|href)="([^"]*)"', text)
        assert sources and all(not re.match(r"[a-z]+:|//", src) or src.startswith("http://127.0.0.1:")
                               for src in sources), sources  # every asset from the local server
        assert get(url + "static/js/bokeh.min.js")[0] == 200
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_a_port_in_use_is_a_clear_error(tmp_path):
    write_record(tmp_path, 5).close()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = str(taken.getsockname()[1])
        proc = subprocess.run([sys.executable, "-m", "hsio.cli", "monitor", str(tmp_path), "--port", port], env=ENV,
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2 and f"cannot listen on 127.0.0.1:{port}" in proc.stderr
        assert "Traceback" not in proc.stderr
        cfg = tmp_path / "run.toml"
        cfg.write_text("[record]\nduration_s = 0.5\n[output]\nplots = false\n")
        out = tmp_path / "o"
        proc = subprocess.run([sys.executable, "-m", "hsio.cli", "run", str(cfg), "--out", str(out), "--monitor",
                               "--monitor-port", port], env=ENV, capture_output=True, text=True, timeout=120,
                              stdin=subprocess.DEVNULL)
        assert proc.returncode == 2 and f"cannot listen on 127.0.0.1:{port}" in proc.stderr
        assert "Traceback" not in proc.stderr and not (out / "run.sqlite").exists()  # nothing ran


def test_an_empty_address_is_refused_not_taken_for_every_interface(tmp_path):
    """An empty --host (an unset variable) would bind every interface: refused, exit 2 (a server
    that started instead would outlive the bounded wait: TimeoutExpired)."""
    write_record(tmp_path, 5).close()
    for host in ("", "  "):
        proc = subprocess.run([sys.executable, "-m", "hsio.cli", "monitor", str(tmp_path), "--host", host, "--port", "0"],
                              env=ENV, capture_output=True, text=True, timeout=30)
        assert proc.returncode == 2 and "the address to listen on is empty" in proc.stderr


@pytest.mark.parametrize("args", [["--monitor-port", "9000"], ["--monitor-host", "0.0.0.0"]])
def test_a_monitor_port_or_address_without_monitor_is_refused_before_anything_runs(tmp_path, args):
    """The operator asked for a page: a run without one, silently, would leave them without their Stop."""
    from click.testing import CliRunner

    from hsio.cli import main

    out = tmp_path / "o"
    res = CliRunner().invoke(main, ["run", "--out", str(out), *args])
    assert res.exit_code == 2 and f"{args[0]} set the monitor's page" in res.output and "add --monitor" in res.output
    assert not out.exists()


def test_a_request_without_a_run_to_answer_is_refused_and_logged(tmp_path):
    op = Operator(tmp_path)
    assert op.request("pause").startswith("error: no control socket")
    assert op.request("jump").startswith("error unknown action 'jump'")
    log = (tmp_path / LOG_FILE).read_text().splitlines()
    assert len(log) == 2 and " pause from the monitor page: error" in log[0]
    assert op.status() == ""


def test_monitor_of_a_missing_folder_is_a_clear_error(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "monitor", str(tmp_path / "nope")], env=ENV,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "does not exist" in proc.stderr and "Traceback" not in proc.stderr


def test_monitor_of_a_folder_of_runs_names_the_run_folders_in_it(tmp_path):
    """runs/validation instead of runs/validation/run-0002: watched (a run may start there) but the
    operator is told where the records are, not left before a page that waits for ever."""
    for name in ("run-0001", "run-0002"):
        (tmp_path / name).mkdir()
        write_record(tmp_path / name, 3).close()
    proc = subprocess.Popen([sys.executable, "-m", "hsio.cli", "monitor", str(tmp_path), "--port", "0"], env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    import select

    try:
        ready, _, _ = select.select([proc.stderr], [], [], 30.0)  # bounded: no line, no hang
        line = proc.stderr.readline() if ready else ""
    finally:
        proc.terminate()
        proc.wait(20)
    assert "holds no run.sqlite but run folders with one: run-0001, run-0002" in line, line


def test_monitor_is_listed_by_hsio():
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "--help"], env=ENV, capture_output=True, text=True,
                          timeout=60)
    assert "monitor" in proc.stdout


def test_the_page_of_a_column_on_two_actuators_shows_phases_and_the_rotation_in_rad(tmp_path):
    """A structure through a setup: each channel's command-generator phase (from its element's
    actuators), the rotation DOF in rad and its channel's legends so; no following-error margin of
    the rotation against a threshold in mm."""
    from bokeh.document import Document
    from bokeh.models import Legend

    from hsio import config, runner
    from hsio.monitor import page as page_mod

    library = Path(__file__).resolve().parents[1] / "hsio" / "library"
    cfg = config.from_dict({"structure": {"file": str(library / "column_two_actuators.toml")},
                            "record": {"synthetic_duration_s": 0.3, "pga_g": 0.3}, "test": {"rate": 10.0},
                            "output": {"plots": False}, "safety": {"keys": False}})
    runner.run(cfg, tmp_path / "run")
    feed = RecordFeed(tmp_path / "run")
    page = page_mod.MonitorPage(Document(), feed, Operator(tmp_path / "run"))
    status = page.status.text
    phases = re.search(r"phase (column\.top_x \w+), (column\.top_rot \w+)", status)
    assert phases and "n/a" not in phases.group(0), status
    assert re.search(r"top_rot DC, 0 switches, peak \|u\| 0\.\d{5} rad \(NS 0\.\d{5}\)", status), status
    legends = [item.label.value for doc_root in page.doc.roots for legend in doc_root.select({"type": Legend})
               for item in legend.items]
    assert "top_rot (rad)" in legends and "column.top_rot (rad, kN mm)" in legends, legends
    margins = dict(zip(page.margins.data["label"], page.margins.data["text"]))
    assert margins["column.top_rot following"] == "limit not known"
    assert margins["column.top_x following"] != "limit not known"
    feed.close()


class _RunAnswering:
    """An operator whose run answers ``line`` on its control socket."""

    def __init__(self, line: str):
        self.line, self.answers, self.log = line, True, []

    def status(self) -> str:
        return self.line


@pytest.mark.parametrize("message, shown", [
    ("paused after step 5: the actuators hold (confirmed by read-back)", "the actuators hold (confirmed by read-back)"),
    ("paused after step 5: WARNING: C1 did not confirm the hold (reads back not holding)",
     "WARNING: C1 did not confirm the hold"),
    (None, "the hold's read-back is not in the record yet"),
])
def test_a_paused_run_shows_the_hold_as_read_back_never_assumed(tmp_path, message, shown):
    from bokeh.document import Document

    from hsio.monitor import page as page_mod

    rec = write_record(tmp_path, 5)
    rec.write_event(1.0, 3, "pause", "", "paused after step 3: the actuators hold (confirmed by read-back)")
    if message:
        rec.write_event(2.0, 5, "pause", "", message)
    rec.db.commit()
    page = page_mod.MonitorPage(Document(), RecordFeed(tmp_path), _RunAnswering("ok paused phase HS step 5"))
    state = html.unescape(re.search(r"hsio-state'>([^<]*)<", page.status.text).group(1))
    assert state.startswith("paused (phase HS): ") and shown in state, state
    rec.close()


def test_a_channel_that_read_nan_at_the_newest_step_is_not_said_to_have_no_limit(tmp_path):
    """A displacement sensor that read NaN at the last step: its stroke margin says there is no
    reading, with the least margin of the steps before, not that the limit is not known."""
    from bokeh.document import Document

    from hsio.monitor import page as page_mod

    rec = write_record(tmp_path, 5)
    rec.write_step(6, 0.06, [0, 0], [0, 0], [0, 0], [0, 0], [0, 0], ["displacement"] * 2,
                   [0, 0], [0, 0], [float("nan"), 0], [0, 0])
    rec.close()
    page = page_mod.MonitorPage(Document(), RecordFeed(tmp_path), Operator(tmp_path))
    margins = dict(zip(page.margins.data["label"], page.margins.data["text"]))
    assert margins["C1 stroke"].startswith("no reading at the newest step (least "), margins
    assert margins["C2 stroke"].endswith("%)")


def test_the_events_kept_are_bounded_and_the_runs_state_is_still_told_from_them(tmp_path):
    """Thousands of warnings (a channel at the edge of its warning band) around a pause, a trip
    and a reopening by `hsio resume`: the feed keeps the newest events only, yet the page still
    shows the pause's hold as read back, the trip to acknowledge, and the record as open."""
    from bokeh.document import Document

    from hsio.monitor import feed as feed_mod
    from hsio.monitor import page as page_mod

    rec = write_record(tmp_path, 5)
    rec.write_summary({"steps": 5, "outcome": "stopped"})
    rec.write_event(None, 5, "resume", "", "resumed after step 5 (hsio test)")

    def warnings(n):
        for i in range(n):
            rec.write_event(1.0, 5, "warning", "C1", f"displacement beyond 90 % of the limit ({i})", commit=False)

    warnings(3000)
    rec.write_event(1.0, 5, "pause", "", "paused after step 5: the actuators hold (confirmed by read-back)", commit=False)
    warnings(3000)
    rec.write_event(2.0, 5, "controller_trip", "C1", "C1 tripped: valve", commit=False)
    warnings(3000)
    rec.db.commit()
    feed = RecordFeed(tmp_path)
    page = page_mod.MonitorPage(Document(), feed, _RunAnswering("ok paused phase HS step 5"))
    assert len(feed.events) <= feed_mod.EVENTS_KEPT and len(feed.marks) <= feed_mod.MARKS_KEPT
    assert feed.events[-1]["message"].endswith("(2999)") and not feed.finished
    state = html.unescape(re.search(r"hsio-state'>([^<]*)<", page.status.text).group(1))
    assert "the actuators hold (confirmed by read-back)" in state and "C1 tripped: valve" in state, state
    rec.write_summary({"steps": 5, "outcome": "finished", "resumed_from": 5})
    feed.poll(force=True)
    assert feed.finished
    rec.close()


def test_a_run_over_shows_its_final_hold(tmp_path):
    from bokeh.document import Document

    from hsio.monitor import page as page_mod

    rec = write_record(tmp_path, 5)
    rec.write_summary({"outcome": "stopped by the operator", "stopped": "step 6: stopped by the operator",
                       "final_hold": "the hold of C2 could not be confirmed (no read-back)"})
    operator = _RunAnswering("")
    operator.answers = False
    page = page_mod.MonitorPage(Document(), RecordFeed(tmp_path), operator)
    state = re.search(r"hsio-state'>([^<]*)<", page.status.text).group(1)
    assert "run over (stopped by the operator)" in state and "the hold of C2 could not be confirmed" in state, state
    rec.close()


def test_a_run_started_without_a_control_socket_is_said_so(tmp_path):
    """[safety] control_socket = false: the page says the run cannot hear it, not that it may be dead."""
    from bokeh.document import Document

    from hsio.monitor import page as page_mod

    rec = write_record(tmp_path, 5)
    rec.write_meta({"config": {"structure": {"name": "validation", "file": ""},
                               "safety": {"following_error_mm": 10.0, "following_error_kN": 25.0,
                                          "warning_fraction": 0.9, "control_socket": False}}})
    rec.db.commit()
    operator = _RunAnswering("")
    operator.answers = False
    page = page_mod.MonitorPage(Document(), RecordFeed(tmp_path), operator)
    state = html.unescape(re.search(r"hsio-state'>([^<]*)<", page.status.text).group(1))
    assert "no control socket ([safety] control_socket = false)" in state and "killed" not in state, state
    rec.close()


def test_a_record_without_controller_samples_says_why_it_shows_no_phase(tmp_path):
    from bokeh.document import Document

    from hsio import config, runner
    from hsio.monitor import page as page_mod

    cfg = config.from_dict({"structure": {"name": "validation"}, "record": {"synthetic_duration_s": 0.1},
                            "output": {"plots": False, "samples": False}, "safety": {"keys": False}})
    runner.run(cfg, tmp_path / "run")
    feed = RecordFeed(tmp_path / "run")
    page = page_mod.MonitorPage(Document(), feed, Operator(tmp_path / "run"))
    assert "phase not recorded ([output] samples = false" in page.status.text
    feed.close()


def test_a_run_without_the_ns_table_still_shows_its_progress(tmp_path):
    """[output] ns = false keeps no NS curve, but the test's length is known from the record: the
    page still shows "of N" and the share done (and hence the time to finish)."""
    from bokeh.document import Document

    from hsio import config, runner
    from hsio.monitor import page as page_mod

    for ns in (True, False):
        cfg = config.from_dict({"structure": {"name": "validation"}, "record": {"synthetic_duration_s": 0.1},
                                "output": {"plots": False, "ns": ns}, "safety": {"keys": False}})
        runner.run(cfg, tmp_path / f"run{ns}")
        feed = RecordFeed(tmp_path / f"run{ns}")
        page = page_mod.MonitorPage(Document(), feed, Operator(tmp_path / f"run{ns}"))
        assert feed.n == 10 and feed.total_steps == 10, (ns, feed.n, feed.total_steps)
        assert "</span> of 10 (100.0 %)" in page.status.text, page.status.text
        feed.close()


def force_controlled_record(folder: Path, modes: list[str], error_mm: float, error_kN: float) -> None:
    """C1 (DOF C1) over len(modes) steps of 64 controller samples each, in the mode given per
    step: the force follows a 3 kN sine (kN in FC) or the displacement a 5 mm one, with the end
    of step error ``error_mm`` in DC and ``error_kN`` in FC; the samples track their command
    exactly (a displacement 1/0.6 of the force)."""
    meta = {"structure": "validation", "record": "sine", "dt": 0.01, "test_rate": 2.0,
            "config": {"structure": {"name": "validation", "file": ""},
                       "safety": {"following_error_mm": 10.0, "following_error_kN": 25.0, "warning_fraction": 0.9}},
            "dry_run": {"limits": {"stroke_mm": 254.0, "force_kN": 250.0, "velocity_mm_s": 500.0}}}
    rec = Recorder(folder / "run.sqlite", ["C1"], ["C1"], meta)
    rec.db.execute("PRAGMA synchronous=OFF")
    for k, mode in enumerate(modes, start=1):
        t = (k - 1 + np.arange(64) / 64) * 0.02
        force = 3.0 * np.sin(2 * np.pi * 2.0 * t)
        disp = force / 0.6
        cmd = force if mode == "force" else disp
        samples = np.stack([cmd, disp, force], axis=-1)[:, None, :]
        target = force[-1] + error_kN if mode == "force" else disp[-1] + error_mm
        rec.write_step(k, 0.01 * k, [disp[-1]], [0], [0], [disp[-1]], [force[-1]], [mode], [target], [target],
                       [disp[-1]], [force[-1]], samples)
    rec.close()


def test_the_spectrum_of_a_channel_in_force_control_is_of_its_force_error(tmp_path):
    """In force control the controller's command is a force: its tracking error is against the
    measured force (kN), not the displacement (mm). A force loop that tracks exactly shows no error."""
    from bokeh.document import Document

    from hsio.monitor import page as page_mod

    force_controlled_record(tmp_path, ["force"] * 80, 0.0, 0.0)
    page = page_mod.MonitorPage(Document(), RecordFeed(tmp_path), Operator(tmp_path))
    page._spectrum()
    assert len(page.spectrum.data["f"]) and np.max(page.spectrum.data["a_C1"]) < 1e-6


def test_the_least_following_margin_of_a_mixed_channel_takes_each_step_against_its_own_mode(tmp_path):
    """C1 ran 8 mm behind in DC (20 % of the 10 mm threshold left), then 1 kN behind in FC (96 %
    of 25 kN): the least margin is 20 %, not the DC errors read against the FC threshold."""
    from bokeh.document import Document

    from hsio.monitor import page as page_mod

    force_controlled_record(tmp_path, ["displacement"] * 10 + ["force"] * 10, 8.0, 1.0)
    page = page_mod.MonitorPage(Document(), RecordFeed(tmp_path), Operator(tmp_path))
    margins = dict(zip(page.margins.data["label"], page.margins.data["text"]))
    assert margins["C1 following"] == "96 % (least 20 %)", margins


def test_a_second_pause_at_the_same_step_is_not_shown_with_the_first_pauses_hold(tmp_path):
    """Paused and resumed during the ramp in of the preloads (events at step 0), then paused
    again: until the second pause's read-back is in the record, the page does not show the first's."""
    from bokeh.document import Document

    from hsio.monitor import page as page_mod

    rec = write_record(tmp_path, 0)
    rec.write_event(1.0, 0, "pause", "", "paused after step 0: the actuators hold (confirmed by read-back) "
                                         "(in the ramp in of the static preloads)")
    rec.write_event(2.0, 0, "resume", "", "resumed after 1.0 s of pause (in the ramp in of the static preloads)")
    page = page_mod.MonitorPage(Document(), RecordFeed(tmp_path), _RunAnswering("ok paused phase ramp-in step 0"))
    state = html.unescape(re.search(r"hsio-state'>([^<]*)<", page.status.text).group(1))
    assert "confirmed" not in state and "the hold's read-back is not in the record yet" in state, state
    rec.close()


def test_a_long_record_costs_the_feed_a_bounded_memory(tmp_path):
    """A page opened on a long record (late in a run, or a replay) reads it READ_BATCH steps at a
    time and keeps the last `window` steps whole and every stride-th step of all (at most `cap`
    rows): four times the steps, the same memory. What it keeps is the record's, and the peaks
    and the tracking indicator are of every step."""
    import tracemalloc

    held = {}
    for steps in (2_000, 8_000):
        folder = tmp_path / str(steps)
        folder.mkdir()
        write_record(folder, steps, ns=False).close()
        feed = RecordFeed(folder, window=128, cap=256)
        feed.READ_BATCH = 500
        assert feed._open()  # the record's names and structure, then the steps alone are measured
        tracemalloc.start()
        try:
            before = tracemalloc.get_traced_memory()[0]
            assert feed.poll(force=True) == steps
            held[steps] = tracemalloc.get_traced_memory()[0] - before
        finally:
            tracemalloc.stop()
        bound = len(feed.columns.names) * (2 * 128 + 256 + 128) * 8
        assert feed.columns.nbytes <= bound
        run = Run(folder / "run.sqlite")
        stride = feed.columns.stride
        assert -(-steps // stride) <= 256 < -(-steps // (stride // 2))
        kept = feed.rows(np.arange(0, steps, stride))
        np.testing.assert_array_equal(kept["u_C1"], run.steps["u_C1"][::stride])
        ti = tracking_indicator(run.steps["target_C1"], run.steps["disp_C1"])
        np.testing.assert_allclose(kept["ti_C1"], ti[::stride])
        np.testing.assert_array_equal(feed["u_C2"], run.steps["u_C2"][-len(feed["u_C2"]):])
        assert 128 <= len(feed["u_C2"]) and feed.last("step") == steps
        assert feed.peak["u_C1"] == np.max(np.abs(run.steps["u_C1"]))
        assert feed.peak_error["C1"][0] == np.max(np.abs(run.steps["target_C1"] - run.steps["disp_C1"]))
        with pytest.raises(ValueError, match="neither recent nor on the stride"):
            feed.rows([stride + 1])
        feed.close()
    print(f"the feed holds {held[2_000] / 1e3:.0f} kB after 2,000 steps, {held[8_000] / 1e3:.0f} kB after 8,000")
    assert held[8_000] < 1.1 * held[2_000] + 20_000


@pytest.mark.parametrize("record", ["sine", "modes"])
def test_a_page_over_the_bounded_feed_shows_what_it_shows_over_every_step(tmp_path, record):
    """The same record through a feed that keeps every step and through one that keeps 64 steps
    whole and 200 thinned: the same points in every plot, the same newest step, margins (the
    least so far included), status (switches and peaks of the whole run) and NS curve."""
    from bokeh.document import Document

    from hsio.monitor import page as page_mod

    if record == "sine":
        write_record(tmp_path, 3_000).close()
    else:  # control-mode switches, and the following errors of each mode, all before the window
        modes = (["displacement"] * 30 + ["force"] * 20) * 8 + ["displacement"] * 100
        force_controlled_record(tmp_path, modes, 9.5, 1.0)
    pages = []
    for window, cap in ((10**6, 10**6), (64, 200)):
        page = page_mod.MonitorPage(Document(), RecordFeed(tmp_path, window=window, cap=cap), Operator(tmp_path),
                                    cap=150)
        pages.append(page)
    full, bounded = pages

    def same() -> None:
        assert bounded.feed.columns.stride > 1 and bounded.feed.columns.recent_start > 0
        for source in ("steps", "last", "ns", "margins"):
            a, b = getattr(full, source).data, getattr(bounded, source).data
            assert a.keys() == b.keys()
            for key in a:
                np.testing.assert_array_equal(np.asarray(a[key]), np.asarray(b[key]), err_msg=f"{source} {key}")
        assert len(full.steps.data["t"]) > 50
        # the socket's answer and the rate measured on the wall clock aside
        unasked = [re.sub(r"hsio-state'>[^<]*<|<tr><td><b>(test rate|time to finish)</b>.*?</tr>", "", page.status.text)
                   for page in pages]
        assert unasked[0] == unasked[1]

    same()
    if record == "sine":  # the run goes on: the pages stream the new points (a doubling of the stride between)
        rec = Recorder.append(tmp_path / "run.sqlite")
        for k in range(3_001, 4_001):
            v = [np.sin(0.01 * k), np.cos(0.01 * k)]
            rec.write_step(k, 0.01 * k, v, [0, 0], [0, 0], v, [0, 0], ["displacement"] * 2, v, v, v, v)
            if k % 250 == 0:
                for page in pages:
                    page._plotted = page.feed._last_poll = 0.0
                    page.update()
                same()
        rec.close()
        assert full.steps.data["step"][-1] == 3_999 // full.decimation.stride * full.decimation.stride + 1  # row 0: step 1
    if record == "modes":
        assert "16 switches" in bounded.status.text
        assert "least 5 %" in dict(zip(bounded.margins.data["label"], bounded.margins.data["text"]))["C1 following"]


def test_a_run_that_commits_nothing_for_a_while_has_no_measured_rate_or_time_to_finish(tmp_path):
    """Paused (or held up) for longer than the window: the page shows no measured rate and no
    time to finish, not the rate from before the pause; over the last seconds, steps per second."""
    feed = RecordFeed(tmp_path)
    now = time.monotonic()
    feed.seen_at = [(now - 9.0, 100), (now - 8.0, 110)]  # ten steps a second, then nothing for 8 s
    assert feed.steps_per_second() is None
    feed.seen_at = [(now - 4.0, 100), (now - 2.0, 120)]  # twenty steps in the last 4 s, none in the last 2
    # 20 steps over the 4 s until the call (a loaded machine may take a while to make it), not 10 a
    # second over the 2 s up to the last commit
    assert 20 / 4.5 < feed.steps_per_second() <= 5.0


@pytest.mark.parametrize("token", ["a;b c", "tökén", "x\"y"])
def test_a_token_that_cannot_travel_in_a_url_and_a_cookie_is_refused(tmp_path, token):
    write_record(tmp_path, 5).close()
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "monitor", str(tmp_path), "--host", "127.0.0.2",
                           "--port", "0", "--token", token], env=ENV, capture_output=True, text=True, timeout=20)
    assert proc.returncode == 2 and "may hold only letters, digits" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("host", ["127.0.0.2", "127.0.0.1"])
def test_an_empty_token_is_refused_not_replaced_by_a_random_one(tmp_path, host):
    """An unset variable as the token: the operator would hand out a URL with the token they meant
    and the page would refuse it; refused at once instead (a server that started would outlive the
    bounded wait: TimeoutExpired)."""
    write_record(tmp_path, 5).close()
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "monitor", str(tmp_path), "--host", host,
                           "--port", "0", "--token", ""], env=ENV, capture_output=True, text=True, timeout=20)
    assert proc.returncode == 2 and "the token is empty" in proc.stderr, proc.stderr


def test_the_feed_waits_for_a_regular_file_not_on_a_fifo_for_ever(tmp_path):
    """A FIFO in the place of run.sqlite would block its reader (and the page with it) for ever:
    the feed of a run starting waits for a file (`hsio monitor` refuses the FIFO by name:
    tests/test_record_not_regular.py)."""
    import threading

    os.mkfifo(tmp_path / "run.sqlite")
    feed = RecordFeed(tmp_path)
    polled = threading.Thread(target=feed.poll, kwargs={"force": True}, daemon=True)
    polled.start()
    polled.join(timeout=5)
    assert not polled.is_alive() and not feed.opened


# -- many channels ------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 10, 12, 16, 20, 21, 40])
def test_colours_are_distinct_for_any_number_of_lines(n):
    from hsio.monitor.page import colors

    assert len(colors(n)) == n and len(set(c.lower() for c in colors(n))) == n


def test_many_channels_draw_fewer_points_less_often_with_every_legend_entry(tmp_path):
    """Twelve channels: fewer points per history and fewer redraws than two (each plot holds six
    times the lines); every channel in each plot's legend, in columns below the plot when they
    are more than its corner holds."""
    from bokeh.document import Document
    from bokeh.models import Legend

    from hsio.monitor import page as page_mod

    names = [f"floor_{i:02d}_x" for i in range(1, 13)]
    rec = Recorder(tmp_path / "run.sqlite", names, names, {"structure": "chain", "record": "sine", "dt": 0.01,
                                                           "test_rate": 2.0, "config": {}})
    for k in range(1, 11):
        u = [np.sin(0.1 * k + j) for j in range(12)]
        rec.write_step(k, 0.01 * k, u, u, u, u, u, ["displacement"] * 12, u, u, u, u)
    rec.close()
    doc = Document()
    page = page_mod.MonitorPage(doc, RecordFeed(tmp_path), Operator(tmp_path))
    assert page.built
    assert page.decimation.cap < page_mod.DEFAULT_CAP and page.plot_every_s > page_mod.PLOT_EVERY_S
    legends = [m for m in doc.models if isinstance(m, Legend)]
    assert len(legends) == 7
    for legend in legends:
        assert len(legend.items) == 12
        plot = next(p for p in doc.models if hasattr(p, "below") and legend in p.below)
        assert legend.ncols * -(-12 // legend.ncols) >= 12 and plot.height > page_mod.PLOT["height"]
    (tmp_path / "two").mkdir()
    write_record(tmp_path / "two", 10).close()
    two = page_mod.MonitorPage(Document(), RecordFeed(tmp_path / "two"), Operator(tmp_path / "two"))
    assert two.decimation.cap == page_mod.DEFAULT_CAP and two.plot_every_s == page_mod.PLOT_EVERY_S


def test_a_run_refused_by_its_control_socket_check_leaves_no_page_log(tmp_path, monkeypatch):
    """`hsio run --monitor --out DIR`, DIR holding a file named control.sock that is not a socket:
    the run is refused before its record begins, and the folder is left as it was (no monitor.log
    of a page that watched no run)."""
    from click.testing import CliRunner

    from hsio.cli import main

    monkeypatch.chdir(tmp_path)
    out = tmp_path / "o"
    out.mkdir()
    (out / "control.sock").write_text("")
    (tmp_path / "run.toml").write_text("[record]\nduration_s = 0.1\n[output]\nplots = false\n[safety]\nkeys = false\n")
    got = CliRunner().invoke(main, ["run", "run.toml", "--out", str(out), "--monitor", "--monitor-port", "0"])
    assert got.exit_code == 2, got.output
    assert sorted(p.name for p in out.iterdir()) == ["control.sock"]
    assert "control.sock: a file that is not a control socket" in got.output
    assert "no record was left in it" in got.output


@pytest.mark.parametrize("line, pause, resume", [
    ("ok running phase HS step 5", False, True),
    ("ok pausing phase HS step 5", True, False),  # a resume cancels the pause asked
    ("ok paused phase HS step 5", True, False),
    ("ok stopping phase HS step 5", True, True),
])
def test_the_pause_and_resume_buttons_follow_the_runs_state(tmp_path, line, pause, resume):
    """Pause is offered only to a running run, Resume only to one pausing or paused (disabled)."""
    from bokeh.document import Document

    from hsio.monitor import page as page_mod

    rec = write_record(tmp_path, 5)
    page = page_mod.MonitorPage(Document(), RecordFeed(tmp_path), _RunAnswering(line))
    disabled = {b.name: b.disabled for b in page.buttons}
    assert (disabled["pause_button"], disabled["resume_button"]) == (pause, resume)
    assert disabled["stop_button"] is False
    rec.close()


def test_a_record_of_many_events_is_read_a_batch_at_a_time(tmp_path):
    """A page opened late on a run that wrote 40,000 warnings (a channel chattering at the edge of
    its warning band) holds no more of them while reading than a batch: not every event at once
    as Python rows. It keeps the newest, and the pause before them still tells the run's state."""
    import tracemalloc

    from hsio.monitor import feed as feed_mod

    rec = write_record(tmp_path, 5, ns=False)
    rec.write_event(1.0, 5, "pause", "", "paused after step 5: the actuators hold (confirmed by read-back)", commit=False)
    for i in range(40_000):
        rec.write_event(1.0, 5, "warning", "C1", f"displacement beyond 90 % of the limit, entry number {i:06d}", commit=False)
    rec.db.commit()
    rec.close()
    feed = RecordFeed(tmp_path)
    assert feed._open()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        feed.poll(force=True)
        peak = tracemalloc.get_traced_memory()[1] - before
    finally:
        tracemalloc.stop()
    assert len(feed.events) == feed_mod.EVENTS_KEPT and feed.events[-1]["message"].endswith("039999")
    assert [e["kind"] for e in feed.marks] == ["pause"]
    print(f"first read of 40,000 events: {peak / 1e6:.1f} MB at most")
    assert peak < 4e6
    feed.close()


def test_an_ns_table_without_a_dofs_column_leaves_the_steps_read(tmp_path):
    """An NS prediction the feed cannot use (a column of a DOF missing) is left out of the page,
    not a reason to read no steps at all."""
    import sqlite3

    write_record(tmp_path, 50).close()
    with sqlite3.connect(tmp_path / "run.sqlite") as db:
        db.execute("ALTER TABLE ns RENAME COLUMN u_C1 TO x_C1")
    db.close()
    feed = RecordFeed(tmp_path)
    assert feed.poll(force=True) == 50 and feed.n == 50
    assert not feed.ns and feed.total_steps is None
    feed.close()
