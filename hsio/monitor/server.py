"""The monitor's web server (docs/monitor.md section 1).

A Bokeh server (Tornado) in its own process: it serves the page of :mod:`hsio.monitor.page` and
BokehJS from the installed bokeh package (``BOKEH_RESOURCES=server``: no CDN, works offline). It
binds 127.0.0.1 unless told otherwise; bound to any other address it requires a token, printed at
start-up, in the page's URL (``?token=...``; a cookie keeps it for the page's connection).

`hsio run --monitor` starts it as a child process (:class:`MonitorProcess`) beside the run: the
run's loop never waits for the page, which reads the record from its own process. The child ends
with its parent, however the parent ends (even killed): it watches its stdin, a pipe from the
parent, and stops when the pipe reaches its end (and on Linux asks the kernel for SIGTERM when
the parent dies).
"""

from __future__ import annotations

import hmac
import html
import os
import queue
import re
import secrets
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from hsio.errors import ConfigError

DEFAULT_PORT = 8765
LOOPBACK = ("127.0.0.1", "localhost", "::1")
COOKIE = "hsio_monitor_token_{port}"  # one per port: cookies are shared by all ports of a host
READY = "hsio monitor: serving"
LOG_FILE = "monitor.log"


def free_port(host: str) -> int:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def needs_token(host: str) -> bool:
    return host not in LOOPBACK


def same_token(given: str | None, token: str) -> bool:
    """``given`` is ``token`` (compared in constant time, as bytes: any text compares)."""
    if given is None:
        return False
    return hmac.compare_digest(given.encode("utf-8", "surrogateescape"), token.encode("utf-8"))


def allowed_origins(host: str, port: int) -> list[str]:
    """The origins (``host:port`` as a browser sends it) whose pages may open the page's
    websocket: the monitor's own address and port only. Bound to every address (0.0.0.0), or to
    an IPv6 one (which Bokeh's patterns cannot spell), any name of this machine but this port only."""
    if not needs_token(host):
        return [f"{h}:{port}" for h in ("127.0.0.1", "localhost")]
    if host in ("0.0.0.0", "") or ":" in host:
        return [f"*:{port}"]
    return [f"{host}:{port}"]


def loopback_hosts(port: int) -> set[str]:
    """The ``Host`` headers a browser sends to a monitor on the loopback (``host:port``; the bare
    name on port 80)."""
    names = ("127.0.0.1", "localhost", "[::1]")
    return {f"{h}:{port}" for h in names} | (set(names) if port == 80 else set())


def _token_auth(token: str | None, port: int, hosts: set[str] | None = None):
    """A Bokeh auth provider that admits a request carrying ``token`` (query or cookie), or with
    no token any request, and only one addressed to one of ``hosts`` (None: any). On the loopback
    (no token) the host is what keeps out another site's page that a browser reaches at the
    monitor's port through a name of its own resolved to 127.0.0.1 (DNS rebinding): that page is
    of its own origin, so its websocket would pass the origin check."""
    from bokeh.server.auth_provider import AuthProvider
    from tornado.web import RequestHandler
    from tornado.websocket import WebSocketHandler

    cookie = COOKIE.format(port=port)

    def get_user(handler):
        if hosts is not None and handler.request.host.lower() not in hosts:
            return None
        if token is None:
            return "operator"
        if same_token(handler.get_argument("token", None), token):
            if not isinstance(handler, WebSocketHandler):
                handler.set_cookie(cookie, token, httponly=True, samesite="Strict")
            return "operator"
        return "operator" if same_token(handler.get_cookie(cookie), token) else None

    class Denied(RequestHandler):
        def get(self):
            self.set_status(403)
            if hosts is not None and self.request.host.lower() not in hosts:
                self.write(f"This hsio monitor answers only at its own address (http://127.0.0.1:{port}/), "
                           f"not at {html.escape(self.request.host)}\n")
            else:
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
          announce=print, cap: int | None = None) -> None:
    """Serve the monitor of the run in ``run_dir`` until interrupted (SIGINT, SIGTERM).

    The record may not exist yet (a run starting): the page says so and waits for it."""
    from tornado.ioloop import IOLoop

    server, url, close = make_server(run_dir, host, port, token, cap)
    announce(f"{READY} {run_dir} at {url}")
    try:
        IOLoop.current().start()
    finally:
        close()


def make_server(run_dir: str | Path, host: str = "127.0.0.1", port: int = DEFAULT_PORT, token: str | None = None,
                cap: int | None = None, io_loop=None):
    """The monitor's server of ``run_dir``, started on ``io_loop`` (None: the current one):
    (the Bokeh server, the page's URL, a function that releases the record and the socket)."""
    os.environ["BOKEH_RESOURCES"] = "server"  # BokehJS from the installed package, never a CDN
    from bokeh.application import Application
    from bokeh.application.handlers.function import FunctionHandler
    from bokeh.server.server import Server

    from hsio.monitor.feed import RecordFeed
    from hsio.monitor.history import CAP as HISTORY_CAP
    from hsio.monitor.operator import Operator
    from hsio.monitor.page import MonitorPage

    run_dir = Path(run_dir)
    if not host.strip():  # an empty address would bind every interface (an unset variable, a typing error)
        raise ConfigError("the address to listen on is empty: give one (127.0.0.1, this machine; 0.0.0.0, every "
                          "interface, with a token)")
    if token is not None and not token.strip():  # an unset variable: not a token, nor a cue for a random one
        raise ConfigError("the token is empty: give one, or leave --token out for a random one printed at start-up")
    if token and not re.fullmatch(r"[A-Za-z0-9._~-]+", token):  # it travels in the URL and a cookie as it is
        raise ConfigError(f"the token {token[:40]!r} may hold only letters, digits and - _ . ~ (it is sent in the "
                          f"page's URL and kept in a cookie)")
    if needs_token(host) and not token:
        token = secrets.token_urlsafe(18)
    feed = RecordFeed(run_dir, cap=max(HISTORY_CAP, cap or 0))  # keeps every row a page of `cap` points shows
    operator = Operator(run_dir, socket_path=lambda: feed.meta.get("control_socket"))

    def make_page(doc):
        MonitorPage(doc, feed, operator, cap=cap)

    try:
        port = port or free_port(host)
        origins = allowed_origins(host, port)
        auth = _token_auth(token, port) if needs_token(host) else _token_auth(None, port, loopback_hosts(port))
        server = Server({"/": Application(FunctionHandler(make_page))}, address=host, port=port,
                        allow_websocket_origin=origins, num_procs=1, check_unused_sessions_milliseconds=2000,
                        unused_session_lifetime_milliseconds=5000, auth_provider=auth,
                        **({"io_loop": io_loop} if io_loop is not None else {}))
    except OSError as exc:
        operator.close()
        feed.close()
        raise ConfigError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    # The record as it stands is read before the URL is given: a long one (a replay, a run followed
    # late) takes seconds, which the first tab would otherwise wait with the page server unable to
    # answer any other (the reading runs on its event loop).
    feed.poll(force=True)
    server.start()
    shown = f"[{host}]" if ":" in host else host
    url = f"http://{shown}:{server.port}/" + (f"?token={token}" if needs_token(host) else "")

    def close() -> None:
        operator.close()
        feed.close()

    return server, url, close


def end_with_parent() -> None:
    """In the page server started by :class:`MonitorProcess`: end (SIGTERM to itself) when the
    parent goes, however it goes. Its stdin is a pipe whose only writer is the parent, so it
    reaches its end when the parent exits or is killed; on Linux the kernel also sends SIGTERM
    when the parent dies (PR_SET_PDEATHSIG)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            PR_SET_PDEATHSIG = 1
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        except (OSError, AttributeError):
            pass

    def watch() -> None:
        try:
            while os.read(0, 4096):  # the raw descriptor: no buffer lock held at the interpreter's exit
                pass
        except OSError:
            pass
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


class MonitorProcess:
    """The monitor of a run, served by a child process for the run's duration."""

    START_TIMEOUT_S = 30.0
    GRACE_S = 1.5  # after the run: time for the page to show the closed record

    def __init__(self, run_dir: str | Path, host: str = "127.0.0.1", port: int = DEFAULT_PORT):
        self.run_dir = Path(run_dir)
        self.url = ""
        env = {**os.environ, "BOKEH_RESOURCES": "server", "PYTHONUNBUFFERED": "1"}
        self.log_path = self.run_dir / LOG_FILE  # the server's own messages
        with open(self.log_path, "a", encoding="utf-8") as log:
            # stdin: a pipe the child watches; its end tells the child that the run is gone.
            self.proc = subprocess.Popen(self.command(host, port), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=log, text=True, env=env)
        try:
            line = self._first_line()
        except BaseException:
            self._end(kill=True)
            raise
        if line is None or not line.startswith(READY):
            self._end(kill=line is None)
            if line is None:
                raise ConfigError(f"the monitor did not start: no answer from its server within {self.START_TIMEOUT_S:g} s "
                                  f"(its messages: {self.log_path})")
            lines = [x for x in (line + self.log_path.read_text(encoding="utf-8")).splitlines() if x.strip()]
            reason = lines[-1].removeprefix("hsio monitor: error: ") if lines else f"exit {self.proc.returncode}"
            raise ConfigError(f"the monitor did not start: {reason}")
        self.url = line.rpartition(" at ")[2].strip()

    def command(self, host: str, port: int) -> list[str]:
        return [sys.executable, "-m", "hsio.monitor", str(self.run_dir), "--host", host, "--port", str(port)]

    def _first_line(self) -> str | None:
        """The child's first line (READY once it listens, else why it failed: it exits); None if
        it says nothing for START_TIMEOUT_S."""
        lines: queue.Queue = queue.Queue()
        threading.Thread(target=lambda: lines.put(self.proc.stdout.readline()), daemon=True).start()
        try:
            return lines.get(timeout=self.START_TIMEOUT_S)
        except queue.Empty:
            return None

    def _end(self, kill: bool = False) -> None:
        """End the child (SIGTERM, then SIGKILL if it lingers) and close its pipes."""
        try:
            if self.proc.poll() is None:
                if kill:
                    self.proc.kill()
                else:
                    self.proc.terminate()
                try:
                    self.proc.wait(timeout=5.0)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(timeout=5.0)
        finally:
            for pipe in (self.proc.stdin, self.proc.stdout):
                try:
                    pipe.close()
                except OSError:
                    pass

    def close(self, grace_s: float | None = None) -> None:
        """After the grace time (the page shows the closed record), end the server. A Ctrl-C in the
        grace time only cuts it short: the run has ended by then, and its exit status is the run's
        (a finished run stays 0, not "interrupted")."""
        try:
            if self.proc.poll() is None:
                time.sleep(self.GRACE_S if grace_s is None else grace_s)
        except KeyboardInterrupt:
            pass
        finally:
            self._end()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
