"""The monitor's web server (docs/monitor.md section 1).

A Bokeh server (Tornado) in its own process: it serves the page of :mod:`hsio.monitor.page` and
BokehJS from the installed bokeh package (``BOKEH_RESOURCES=server``: no CDN, works offline). It
binds 127.0.0.1 unless told otherwise; bound to any other address it requires a token, printed at
start-up, in the page's URL (``?token=...``; a cookie keeps it for the page's connection).

`hsio run --monitor` starts it as a child process (:class:`MonitorProcess`) beside the run: the
run's loop never waits for the page, which reads the record from its own process.
"""

from __future__ import annotations

import hmac
import os
import secrets
import socket
import subprocess
import sys
import time
from pathlib import Path

from hsio.errors import ConfigError

DEFAULT_PORT = 8765
LOOPBACK = ("127.0.0.1", "localhost", "::1")
COOKIE = "hsio_monitor_token"
READY = "hsio monitor: serving"
LOG_FILE = "monitor.log"


def free_port(host: str) -> int:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def needs_token(host: str) -> bool:
    return host not in LOOPBACK


def _token_auth(token: str):
    """A Bokeh auth provider that admits a request carrying ``token`` (query or cookie)."""
    from bokeh.server.auth_provider import AuthProvider
    from tornado.web import RequestHandler
    from tornado.websocket import WebSocketHandler

    def get_user(handler):
        given = handler.get_argument("token", None)
        if given is not None and hmac.compare_digest(given, token):
            if not isinstance(handler, WebSocketHandler):
                handler.set_cookie(COOKIE, token, httponly=True, samesite="Strict")
            return "operator"
        cookie = handler.get_cookie(COOKIE)
        return "operator" if cookie is not None and hmac.compare_digest(cookie, token) else None

    class Denied(RequestHandler):
        def get(self):
            self.set_status(403)
            self.write("This hsio monitor needs the token printed when it started: open its URL with ?token=...\n")

    class TokenAuth(AuthProvider):
        @property
        def get_user(self):
            return get_user

        @property
        def login_url(self):
            return "/denied"

        @property
        def login_handler(self):
            return Denied

    return TokenAuth()


def serve(run_dir: str | Path, host: str = "127.0.0.1", port: int = DEFAULT_PORT, token: str | None = None,
          announce=print, cap: int | None = None, wait_s: float = 60.0) -> None:
    """Serve the monitor of the run in ``run_dir`` until interrupted (SIGINT, SIGTERM).

    The record may not exist yet (a run starting): the page waits for it, up to ``wait_s`` before
    the server gives up announcing."""
    os.environ["BOKEH_RESOURCES"] = "server"  # BokehJS from the installed package, never a CDN
    from bokeh.application import Application
    from bokeh.application.handlers.function import FunctionHandler
    from bokeh.server.server import Server
    from tornado.ioloop import IOLoop

    from hsio.monitor.feed import RecordFeed
    from hsio.monitor.operator import Operator
    from hsio.monitor.page import MonitorPage

    run_dir = Path(run_dir)
    if needs_token(host) and not token:
        token = secrets.token_urlsafe(18)
    feed = RecordFeed(run_dir)
    operator = Operator(run_dir, socket_path=lambda: feed.meta.get("control_socket"))

    def make_page(doc):
        MonitorPage(doc, feed, operator, cap=cap)

    try:
        port = port or free_port(host)
        origins = [f"{h}:{port}" for h in ("127.0.0.1", "localhost")] if not needs_token(host) else ["*"]
        kwargs = {"auth_provider": _token_auth(token)} if needs_token(host) else {}
        server = Server({"/": Application(FunctionHandler(make_page))}, address=host, port=port,
                        allow_websocket_origin=origins, num_procs=1, check_unused_sessions_milliseconds=2000,
                        unused_session_lifetime_milliseconds=5000, **kwargs)
    except OSError as exc:
        raise ConfigError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    server.start()
    shown = f"[{host}]" if ":" in host else host
    url = f"http://{shown}:{server.port}/" + (f"?token={token}" if needs_token(host) else "")
    announce(f"{READY} {run_dir} at {url}")
    try:
        IOLoop.current().start()
    finally:
        feed.close()


class MonitorProcess:
    """The monitor of a run, served by a child process for the run's duration."""

    START_TIMEOUT_S = 30.0
    GRACE_S = 1.5  # after the run: time for the page to show the closed record

    def __init__(self, run_dir: str | Path, host: str = "127.0.0.1", port: int = DEFAULT_PORT):
        self.run_dir = Path(run_dir)
        self.url = ""
        cmd = [sys.executable, "-m", "hsio.monitor", str(self.run_dir), "--host", host, "--port", str(port)]
        env = {**os.environ, "BOKEH_RESOURCES": "server", "PYTHONUNBUFFERED": "1"}
        self.log_path = self.run_dir / LOG_FILE  # the server's own messages
        with open(self.log_path, "a", encoding="utf-8") as log:
            # The run's own session (so its lower priority counts against the run's processes).
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log,
                                         text=True, env=env)
        line = self.proc.stdout.readline()  # the child prints READY once it listens, or exits
        if not line.startswith(READY):
            self.proc.wait(timeout=self.START_TIMEOUT_S)
            self.proc.stdout.close()
            lines = [x for x in (line + self.log_path.read_text(encoding="utf-8")).splitlines() if x.strip()]
            reason = lines[-1].removeprefix("hsio monitor: error: ") if lines else f"exit {self.proc.returncode}"
            raise ConfigError(f"the monitor did not start: {reason}")
        self.url = line.rpartition(" at ")[2].strip()

    def close(self, grace_s: float | None = None) -> None:
        if self.proc.poll() is None:
            time.sleep(self.GRACE_S if grace_s is None else grace_s)
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5.0)
        self.proc.stdout.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
