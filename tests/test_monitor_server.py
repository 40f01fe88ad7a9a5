"""The monitor's page server as a process and as a door: it ends with the run that started it
(however the run ends), its start-up is bounded, only its own origin with the token opens the
page's websocket; and a record reopened by `hsio resume` is shown as a run in progress."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from hsio.errors import ConfigError, HsioError
from hsio.monitor.feed import RecordFeed
from hsio.monitor.operator import Operator
from hsio.monitor.server import MonitorProcess
from hsio.safety.control import RunControl
from hsio.safety.socket import ControlServer

from test_monitor import ENV, get, start_monitor, write_record

RUN = """[record]
synthetic_duration_s = 60.0
[hardware]
clock = "realtime"
[output]
plots = false
[safety]
keys = false
"""


def alive(pid: int) -> bool:
    """The process exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rpartition(")")[2].split()[0] != "Z"
    except OSError:
        return False


def children(pid: int, marker: str) -> list[int]:
    """The live children of ``pid`` whose command line holds ``marker``."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rpartition(")")[2].split()[1])
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, ValueError, IndexError):
            continue
        if ppid == pid and marker in cmdline and alive(int(entry.name)):
            out.append(int(entry.name))
    return out


def gone_within(pid: int, timeout_s: float) -> bool:
    for _ in range(int(timeout_s / 0.05)):
        if not alive(pid):
            return True
        time.sleep(0.05)
    return not alive(pid)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_page_server_ends_when_its_run_is_killed(tmp_path):
    (tmp_path / "run.toml").write_text(RUN)
    out = tmp_path / "o"
    run = subprocess.Popen([sys.executable, "-m", "hsio.cli", "run", "run.toml", "--out", str(out), "--monitor",
                            "--monitor-port", "0"], cwd=tmp_path, env=ENV, stdin=subprocess.DEVNULL,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    server = []
    try:
        line = run.stderr.readline()
        for _ in range(50):
            if "monitor at" in line or not line:
                break
            line = run.stderr.readline()
        assert "monitor at http://127.0.0.1:" in line, line
        server = children(run.pid, "hsio.monitor")
        assert len(server) == 1
        run.send_signal(signal.SIGKILL)  # no finally, no atexit: the run just vanishes
        run.wait(timeout=10)
        assert gone_within(server[0], 20.0), "the page server outlived its run"
    finally:
        try:
            os.killpg(run.pid, signal.SIGKILL)  # whatever the run had started, if a check failed
        except ProcessLookupError:
            pass
        run.wait(timeout=10)
        run.stderr.close()


def test_the_page_server_ends_when_its_parent_closes_the_pipe(tmp_path):
    """The pipe alone (the mechanism that works on every platform) ends the server."""
    write_record(tmp_path, 10).close()
    page = MonitorProcess(tmp_path, port=0)
    try:
        assert page.url.startswith("http://127.0.0.1:")
        page.proc.stdin.close()  # what the end of the parent does to the pipe
        page.proc.wait(timeout=20)
        assert page.proc.returncode is not None
    finally:
        page.close(grace_s=0)


def test_a_ctrl_c_in_the_grace_time_ends_the_server_and_is_not_an_interruption(tmp_path, monkeypatch):
    """The run has ended when the grace time starts: a Ctrl-C there ends the page server at once
    and does not reach the caller (a finished run keeps its exit status 0)."""
    write_record(tmp_path, 10).close()
    page = MonitorProcess(tmp_path, port=0)

    real_sleep, calls = time.sleep, []

    def interrupted(s):  # Ctrl-C lands in the grace sleep (the first); later waits are real
        calls.append(s)
        if len(calls) == 1:
            raise KeyboardInterrupt
        real_sleep(s)

    monkeypatch.setattr(time, "sleep", interrupted)
    page.close()  # no KeyboardInterrupt escapes
    monkeypatch.undo()
    assert calls[0] == MonitorProcess.GRACE_S and page.proc.returncode is not None


class Stalled(MonitorProcess):
    START_TIMEOUT_S = 1.0
    SCRIPT = "import time; time.sleep(120)"

    def command(self, host, port):
        return [sys.executable, "-c", self.SCRIPT]


class Babbling(Stalled):
    SCRIPT = "import sys, time; print('something else', flush=True); time.sleep(120)"


@pytest.mark.parametrize("kind", [Stalled, Babbling])
def test_a_server_that_never_says_it_is_ready_is_a_clear_error_and_is_ended(tmp_path, kind, monkeypatch):
    started = []
    original = subprocess.Popen

    def popen(*args, **kwargs):
        started.append(original(*args, **kwargs))
        return started[-1]

    monkeypatch.setattr(subprocess, "Popen", popen)
    with pytest.raises(ConfigError, match="the monitor did not start") as caught:
        kind(tmp_path, port=0)
    monkeypatch.undo()
    assert isinstance(caught.value, HsioError)
    assert started and started[0].poll() is not None  # not left running
    if kind is Stalled:
        assert "no answer" in str(caught.value)


# -- the door: origin and token ---------------------------------------------------------------
def handshake(host: str, port: int, path: str, origin: str, cookie: str | None = None) -> str:
    """The status line the server answers to a websocket opening from ``origin``."""
    with socket.create_connection((host, port), timeout=20) as s:
        lines = [f"GET {path} HTTP/1.1", f"Host: {host}:{port}", "Upgrade: websocket", "Connection: Upgrade",
                 "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Version: 13", f"Origin: {origin}"]
        if cookie:
            lines.append(f"Cookie: {cookie}")
        s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        data = b""
        while b"\r\n" not in data:
            chunk = s.recv(4096)
            if not chunk:
                break
            data += chunk
    return data.split(b"\r\n")[0].decode()


def cookie_get(base: str, cookie: str) -> int:
    request = urllib.request.Request(base + "/", headers={"Cookie": cookie})
    try:
        with urllib.request.urlopen(request, timeout=20) as r:
            return r.status
    except urllib.error.HTTPError as exc:
        return exc.code


def test_only_the_monitors_own_origin_with_the_token_opens_the_websocket(tmp_path):
    write_record(tmp_path, 20).close()
    proc, url = start_monitor(tmp_path, "--host", "127.0.0.2", "--port", "0")
    try:
        parts = urllib.parse.urlsplit(url)
        port, token = parts.port, urllib.parse.parse_qs(parts.query)["token"][0]
        own = f"http://127.0.0.2:{port}"
        assert " 101 " in handshake("127.0.0.2", port, f"/ws?token={token}", own)
        # Another page on the same host (another port), another host: refused though they hold the token.
        for foreign in (f"http://127.0.0.2:{port + 1}", "http://evil.example"):
            status = handshake("127.0.0.2", port, f"/ws?token={token}", foreign)
            assert " 403 " in status, (foreign, status)
        # The page: the token in the query or in this port's cookie; none, a wrong one, one that
        # is not ASCII, or another port's cookie: refused, never a server error.
        assert get(url)[0] == 200
        assert cookie_get(own, f"hsio_monitor_token_{port}={token}") == 200
        assert cookie_get(own, f"hsio_monitor_token_{port + 1}={token}") == 403
        for bad in ("", "?token=wrong", "?token=" + urllib.parse.quote("tökén")):
            assert get(f"{own}/{bad}")[0] == 403, bad
    finally:
        proc.terminate()
        proc.wait(timeout=10)


# -- a record reopened by hsio resume ---------------------------------------------------------------
def test_a_resumed_record_is_open_and_stop_stays_available_while_the_run_answers(tmp_path):
    from bokeh.document import Document

    from hsio.monitor.page import MonitorPage

    rec = write_record(tmp_path, 50)
    rec.write_summary({"steps": 50, "outcome": "stopped by the operator", "exit_status": 5})
    feed = RecordFeed(tmp_path)
    feed.poll(force=True)
    assert feed.finished  # a stopped run
    rec.write_event(None, 50, "resume", "", "resumed after step 50 (hsio 0)")  # hsio resume reopens it
    feed.poll(force=True)
    assert not feed.finished
    server = ControlServer(tmp_path, RunControl())
    op = Operator(tmp_path, socket_path=lambda: str(server.path))
    try:
        page = MonitorPage(Document(), feed, op)
        for _ in range(200):  # the status is asked in a worker thread
            page.update()
            if op.answers is not None:
                break
            time.sleep(0.02)
        page._status()
        assert op.answers is True
        buttons = {b.name: b.disabled for b in page.buttons}
        assert buttons["stop_button"] is False and "record is closed" not in page.status.text
        # The resume's own summary closes the record again; with no run answering, all is greyed out.
        rec.write_summary({"steps": 80, "resumed_from": 50, "outcome": "finished", "exit_status": 0})
        feed.poll(force=True)
        assert feed.finished
    finally:
        server.close()
        rec.close()
    op._asked_at = float("-inf")
    for _ in range(200):
        page.update()
        if op.answers is False:
            break
        time.sleep(0.02)
    page._status()
    assert op.answers is False and all(b.disabled for b in page.buttons)
    assert "the record is closed" in page.status.text
    op.close()


# -- a hung run does not hold up the page ---------------------------------------------------------
def test_a_run_that_does_not_answer_never_blocks_the_page_and_stop_stays_available(tmp_path, monkeypatch):
    """The socket is spoken to only from worker threads: with a run that never answers, the
    page's update returns (it would block for as long as the run is hung otherwise), the state
    is unknown, and Stop stays available."""
    import threading

    from bokeh.document import Document

    from hsio.monitor import operator as operator_mod
    from hsio.monitor.page import MonitorPage

    write_record(tmp_path, 30).close()
    (tmp_path / "control.sock").touch()  # a socket is there; the run behind it is hung
    release, callers = threading.Event(), []

    def hung(path, command, timeout_s=2.0):
        callers.append((command, threading.current_thread()))
        release.wait(30)
        raise TimeoutError("timed out")

    monkeypatch.setattr(operator_mod.control_socket, "send", hung)
    op = Operator(tmp_path)
    try:
        page = MonitorPage(Document(), RecordFeed(tmp_path), op)
        page._on_request("value", "", "stop 123")  # the operator presses Stop: returns at once
        for _ in range(200):
            if len(callers) >= 2:
                break
            time.sleep(0.01)
        page.update()
        assert not release.is_set()  # both calls are still waiting for the run ...
        assert {c for c, _ in callers} == {"status", "stop"}
        assert all(t is not threading.main_thread() for _, t in callers)  # ... in worker threads
        assert op.answers is None and "busy, or hung" in page.status.text
        assert {b.name: b.disabled for b in page.buttons} == {"pause_button": True, "resume_button": True,
                                                               "ack_button": True, "stop_button": False}
    finally:
        release.set()
        op.close()
    for _ in range(200):  # the timed-out request is logged
        if op.log:
            break
        time.sleep(0.01)
    assert "stop from the monitor page: error: the run does not answer" in op.log[0]


def _raw(port: int, path: str, host: str, headers: tuple[str, ...] = ()) -> bytes:
    """What the monitor on 127.0.0.1:``port`` sends to a request of ``path`` addressed to
    ``host`` (its Host header), until it closes the connection or says "ACK" (Bokeh's greeting)."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(("\r\n".join([f"GET {path} HTTP/1.1", f"Host: {host}", *headers]) + "\r\n\r\n").encode())
        data, deadline = b"", time.monotonic() + 10
        while b"ACK" not in data and time.monotonic() < deadline:
            chunk = s.recv(4096)
            if not chunk:
                break
            data += chunk
    return data


def test_on_the_loopback_a_request_addressed_to_another_name_is_refused(tmp_path):
    """A site whose name a browser resolves to 127.0.0.1 (DNS rebinding) reaches the loopback
    monitor's port with its own Host and Origin: same origin, as the browser sees it. Neither its
    page nor its websocket is served; the monitor's own names are."""
    from bokeh.util.token import generate_jwt_token, generate_session_id

    write_record(tmp_path, 20).close()
    proc, url = start_monitor(tmp_path, "--port", "0")
    try:
        port = urllib.parse.urlsplit(url).port
        for name in ("127.0.0.1", "localhost", "[::1]"):
            assert _raw(port, "/", f"{name}:{port}", ("Connection: close",)).startswith(b"HTTP/1.1 200 "), name
        assert _raw(port, "/", f"evil.example:{port}", ("Connection: close",)).startswith(b"HTTP/1.1 302 ")
        assert _raw(port, "/denied", f"evil.example:{port}", ("Connection: close",)).startswith(b"HTTP/1.1 403 ")
        for name, served in ((f"127.0.0.1:{port}", True), (f"evil.example:{port}", False)):
            reply = _raw(port, "/ws", name, ("Upgrade: websocket", "Connection: Upgrade", f"Origin: http://{name}",
                                             "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Version: 13",
                                             f"Sec-WebSocket-Protocol: bokeh, {generate_jwt_token(generate_session_id())}"))
            assert (b'"msgtype": "ACK"' in reply) is served, (name, reply[-200:])
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_hsio_run_whose_page_cannot_listen_leaves_no_run_folder(tmp_path, monkeypatch):
    """`hsio run --monitor` on a port in use: exit 2 naming the address, and the numbered folder it
    made for the page is gone (no run began in it; its number stays free)."""
    from click.testing import CliRunner

    from hsio.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "c.toml").write_text("[record]\nsynthetic_duration_s = 0.2\n[output]\nplots = false\n")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        out = CliRunner().invoke(main, ["run", "c.toml", "--monitor", "--monitor-port", str(port)])
    assert out.exit_code == 2 and f"127.0.0.1:{port}" in out.output, out.output
    assert not any((tmp_path / "runs" / "validation").iterdir())


# -- a controller trip during a pause ------------------------------------------------------------
def test_a_trip_during_the_pause_is_shown_and_acknowledged_from_the_page(tmp_path):
    """A controller that tripped while the run was paused: the page says so, Acknowledge is the
    button that lets the resume go on (the run refuses a resume before it), and once the record
    holds the acknowledgement the button is greyed out again."""
    from bokeh.document import Document

    from hsio.monitor.page import MonitorPage
    from hsio.safety import control as control_mod

    rec = write_record(tmp_path, 30)
    control = RunControl()
    control.state, control._pause_wanted = control_mod.PAUSED, True
    control._unacknowledged.append("C1: interlock latched")
    rec.write_event(None, 30, "controller_trip", "C1", "C1: interlock latched")
    server = ControlServer(tmp_path, control)
    op = Operator(tmp_path, socket_path=lambda: str(server.path))

    def settle(page):
        op._asked_at = float("-inf")
        for _ in range(200):
            page.update()
            if op.answers is not None and not (op._asking and not op._asking.done()):
                break
            time.sleep(0.02)
        page.feed.poll(force=True)
        page._status()
        return {b.name: b.disabled for b in page.buttons}

    try:
        page = MonitorPage(Document(), RecordFeed(tmp_path), op)
        buttons = settle(page)
        assert buttons["ack_button"] is False and buttons["resume_button"] is False
        assert "a controller tripped during the pause (C1: interlock latched)" in page.status.text
        assert op.request("resume").startswith("error: not resumed")
        assert op.request("ack") == "ok acknowledged"
        rec.write_event(None, 30, "acknowledge", "", "controller trip acknowledged by socket: C1: interlock latched")
        buttons = settle(page)
        assert buttons["ack_button"] is True and "tripped during the pause" not in page.status.text
        assert op.request("resume").startswith("ok")
    finally:
        server.close()
        rec.close()
        op.close()
