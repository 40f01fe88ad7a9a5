"""A browser tab that stops reading its websocket: what the monitor queues for it stays bounded,
the run's state still reaches it, the other tabs and the run go on, and when it reads again it
gets the latest plots and is told how many updates it missed. The tabs are raw websocket clients
on the loopback (one never reads); the page's server runs in this process, on its own loop."""

from __future__ import annotations

import asyncio
import base64
import concurrent.futures
import json
import os
import re
import socket
import struct
import threading
import time
import urllib.request

import numpy as np
import pytest

from hsio.monitor import page as page_mod
from hsio.monitor.backlog import BACKLOG_BYTES, backlog_bytes

from test_monitor import write_record

pytestmark = pytest.mark.timeout(60)


class Served:
    """The monitor's server of ``run_dir`` on a loop in its own thread; each page it builds is
    kept in :attr:`pages`."""

    def __init__(self, run_dir, monkeypatch):
        from tornado.ioloop import IOLoop

        from hsio.monitor.server import make_server

        self.pages: list[page_mod.MonitorPage] = []
        pages = self.pages

        class Kept(page_mod.MonitorPage):
            def __init__(self, *args, **kwargs):
                super().__init__(*args, **kwargs)
                pages.append(self)

        monkeypatch.setattr(page_mod, "MonitorPage", Kept)
        started: concurrent.futures.Future = concurrent.futures.Future()

        def run() -> None:
            asyncio.set_event_loop(asyncio.new_event_loop())
            self.loop = IOLoop.current()
            try:
                server, url, close = make_server(run_dir, port=0, io_loop=self.loop)
            except BaseException as exc:
                started.set_exception(exc)
                return
            started.set_result(url)
            self.loop.start()
            server.stop()
            close()

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        self.url = started.result(timeout=30)
        self.port = int(self.url.rstrip("/").rpartition(":")[2])

    def call(self, fn):
        """``fn()`` on the server's loop (where the pages live); its result."""
        done: concurrent.futures.Future = concurrent.futures.Future()

        def run() -> None:
            try:
                done.set_result(fn())
            except BaseException as exc:
                done.set_exception(exc)

        self.loop.add_callback(run)
        return done.result(timeout=10)

    def close(self) -> None:
        self.loop.add_callback(self.loop.stop)
        self.thread.join(timeout=10)


def _frame(text: str) -> bytes:
    """A masked text frame, as a client sends it."""
    data, mask = text.encode(), os.urandom(4)
    n = len(data)
    head = bytes([0x81, 0x80 | n]) if n < 126 else bytes([0x81, 0x80 | 126]) + struct.pack(">H", n)
    return head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data))


def open_tab(port: int, receive_buffer: int | None = None) -> socket.socket:
    """A tab of the page: its session's token from the page, the websocket opened with it, the
    document asked for. ``receive_buffer``: the socket's (a tab that will not read fills it soon)."""
    html = urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=20).read().decode()
    token = re.search(r'"token":\s*"([^"]+)"', html).group(1)
    s = socket.socket()
    if receive_buffer:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
    s.settimeout(20)
    s.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall((f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
               f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nOrigin: http://127.0.0.1:{port}\r\n"
               f"Sec-WebSocket-Protocol: bokeh, {token}\r\n\r\n").encode())
    got = b""
    while b'"ACK"' not in got:  # the server's first message: then it takes requests
        chunk = s.recv(65536)
        assert chunk and len(got) < 1_000_000, got[:200]
        got += chunk
    assert got.startswith(b"HTTP/1.1 101"), got[:200]
    for part in (json.dumps({"msgid": "1", "msgtype": "PULL-DOC-REQ"}), "{}", "{}"):
        s.sendall(_frame(part))
    return s


class Reader(threading.Thread):
    """Reads a tab's socket until it closes; the bytes read, and the text seen so far."""

    def __init__(self, s: socket.socket):
        super().__init__(daemon=True)
        self.s, self.read, self.text = s, 0, bytearray()
        self.start()

    def run(self) -> None:
        try:
            while chunk := self.s.recv(1 << 20):
                self.read += len(chunk)
                self.text += chunk
                del self.text[:-4_000_000]
        except OSError:
            pass

    def wait_for(self, pattern: bytes, timeout_s: float, group: bytes | None = None) -> re.Match:
        """The last match of ``pattern`` read, once there is one (whose first group is ``group``)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            hit = None
            for hit in re.finditer(pattern, bytes(self.text)):
                pass
            if hit and (group is None or hit.group(1) == group):
                return hit
            time.sleep(0.05)
        raise AssertionError(f"never read {pattern!r} ({group!r}; {self.read} bytes read)")


def grow(rec, first: int, count: int) -> None:
    """Commit steps ``first`` .. ``first + count - 1`` of a two-channel record at once."""
    rows = []
    for k in range(first, first + count):
        u = [10 * np.sin(0.01 * k), 8 * np.cos(0.01 * k)]
        row = [k, 0.01 * k]
        for j in range(2):
            row += [u[j], 0.0, 0.0, u[j], 0.5 * u[j]]
        row += ["displacement", "displacement"]
        for j in range(2):
            row += [u[j], u[j], 0.99 * u[j], 0.5 * u[j]]
        row += [0, ""]
        rows.append(row)
    rec.db.executemany(rec._insert_step, rows)
    rec.db.commit()


def test_a_tab_that_stops_reading_is_sent_a_bounded_backlog_and_the_runs_state(tmp_path, monkeypatch):
    rec = write_record(tmp_path, 100)
    served = Served(tmp_path, monkeypatch)
    stalled = reading = None
    try:
        stalled = open_tab(served.port, receive_buffer=4096)  # then never read, until the end
        reading = open_tab(served.port)
        other = Reader(reading)
        for _ in range(200):
            if len(served.pages) == 2 and all(p.built for p in served.pages):
                break
            time.sleep(0.05)
        assert len(served.pages) == 2
        tabs = served.call(lambda: [(p, len(p.doc.session_context._session._subscribed_connections))
                                    for p in served.pages])
        assert all(n == 1 for _, n in tabs)

        def backlogs():
            return [backlog_bytes(p.doc) for p in served.pages]

        # The run commits 1,500 steps per batch; each update of the plots carries hundreds of kB.
        step, most = 101, [0, 0]
        for _ in range(8):  # bounded: 8 batches, a few seconds
            grow(rec, step, 1500)
            step += 1500
            time.sleep(0.25)  # the test's writer never waits on the page: each batch commits at once
            now = served.call(backlogs)
            most = [max(a, b) for a, b in zip(most, now)]
        n_steps = step - 1
        # the largest update a tab can be sent: a history of ``cap`` points, every column
        largest_update = 8 * served.pages[0].decimation.cap * len(served.pages[0].steps.data) + 64_000
        stalled_page, reading_page = served.pages  # built as each tab's page was asked for
        print(f"most queued: {most} bytes; updates held back from the stalled tab: {stalled_page.held_back}")
        assert max(most) <= BACKLOG_BYTES + largest_update  # never the run's whole history
        assert stalled_page.held_back > 0
        # The tab that reads kept up: it has the newest step, and missed nothing.
        for _ in range(100):
            if served.call(lambda: reading_page.last.data["step"][0]) == n_steps:
                break
            time.sleep(0.05)
        assert reading_page.held_back == 0 and reading_page.last.data["step"][0] == n_steps
        other.wait_for(rb"hsio-step'>(\d+)", 10, str(n_steps).encode())

        # The run ends: the stalled tab is sent the notice though it still reads nothing.
        rec.write_summary({"steps": n_steps, "outcome": "finished"})
        rec.close()
        for _ in range(100):
            if "the record is closed" in served.call(lambda: stalled_page.status.text):
                break
            time.sleep(0.05)
        assert "the record is closed" in stalled_page.status.text

        # It reads again: the notice, then the latest plots, and how many updates it missed.
        late = Reader(stalled)
        late.wait_for(rb"the record is closed", 20)
        hit = late.wait_for(rb"hsio-held'>(\d+)<", 20)
        assert int(hit.group(1)) >= 1
        for _ in range(100):
            if served.call(lambda: stalled_page.last.data["step"][0]) == n_steps and not backlog_bytes(stalled_page.doc):
                break
            time.sleep(0.05)
        assert stalled_page.last.data["step"][0] == n_steps
        np.testing.assert_array_equal(stalled_page.steps.data["step"], reading_page.steps.data["step"])
    finally:
        for s in (stalled, reading):
            if s is not None:
                s.close()
        served.close()
