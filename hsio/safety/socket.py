"""The local control socket of a run (docs/safety.md section 4).

A UNIX stream socket in the run folder (``control.sock``; if that path is too long for a UNIX
socket, in a short temporary folder, and the run's meta ``control_socket`` names it). One
request per connection, one line of text each way:

    pause      -> ok pausing | ok paused | error ...
    resume     -> ok running | ok resuming | error ...
    stop       -> ok stopping
    status     -> ok <running|pausing|paused|stopping> phase <phase> step <n>

Anything else gets ``error unknown command ...``. Only local processes of the same user can
reach it (file permissions 0600).
"""

from __future__ import annotations

import contextlib
import os
import socket
import stat
import tempfile
import threading
import time
from pathlib import Path

from hsio.errors import ConfigError
from hsio.safety.control import RunControl

MAX_PATH = 100  # sun_path holds 108 bytes on Linux


def socket_path(run_dir: str | Path) -> Path:
    path = Path(run_dir).resolve() / "control.sock"
    if len(os.fsencode(str(path))) <= MAX_PATH:
        return path
    return Path(tempfile.mkdtemp(prefix="hsio-")) / "control.sock"


class ControlServer:
    """Serves :class:`RunControl` requests on a UNIX socket in a daemon thread, each connection
    answered in a thread of its own (at most MAX_CLIENTS at once)."""

    ACCEPT_SLICE_S = 0.2
    READ_TIMEOUT_S = 2.0  # for the whole request line, however it trickles in
    MAX_LINE = 256
    MAX_CLIENTS = 8  # connections answered at once, each in a thread of its own

    def __init__(self, run_dir: str | Path, control: RunControl):
        self.control = control
        self.path = socket_path(run_dir)
        # a run folder whose path is too long for a socket: a temporary folder of its own, removed at close
        self._own_folder = self.path.parent != Path(run_dir).resolve()
        self._stop = threading.Event()
        self._clients = threading.BoundedSemaphore(self.MAX_CLIENTS)
        if os.path.lexists(self.path):  # left by a run that was killed: nobody answers on it
            if not stat.S_ISSOCK(os.lstat(self.path).st_mode):  # not ours to remove
                raise ConfigError(f"{self.path}: a file that is not a control socket is in the way of the run's "
                                  f"control socket; move it aside")
            try:
                send(self.path, "status", timeout_s=0.5)
                raise ConfigError(f"{self.path}: another run is using this control socket")
            except (ConnectionRefusedError, FileNotFoundError, socket.timeout, TimeoutError):
                try:
                    self.path.unlink(missing_ok=True)
                except OSError as exc:
                    raise ConfigError(f"{self.path}: a control socket left by an earlier run cannot be removed "
                                      f"({exc.strerror or exc}); move it aside") from None
            except OSError as exc:  # e.g. another user's socket: whether a run answers on it cannot be told
                raise ConfigError(f"{self.path}: a control socket is there that cannot be asked whether a run "
                                  f"uses it ({exc.strerror or exc}); move it aside if no run does") from None
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)
        try:
            self.sock.bind(str(self.path))
        except OSError as exc:
            self.sock.close()
            if self._own_folder:
                with contextlib.suppress(OSError):
                    self.path.parent.rmdir()
            raise ConfigError(f"{self.path}: cannot open the run's control socket ({exc.strerror or exc})") from None
        finally:
            os.umask(old)
        self.sock.listen(4)
        self.sock.settimeout(self.ACCEPT_SLICE_S)
        self._thread = threading.Thread(target=self._serve, name="hsio-control-socket", daemon=True)
        self._thread.start()

    def handle(self, line: str) -> str:
        word = line.strip().lower()
        if word == "pause":
            return self.control.request_pause("socket")
        if word == "resume":
            return self.control.request_resume("socket")
        if word == "ack":
            return self.control.request_ack("socket")
        if word == "stop":
            return self.control.request_stop("stopped by the operator (control socket)")
        if word == "status":
            return self.control.status()
        return f"error unknown command {line.strip()[:40]!r}; known: pause, resume, ack, stop, status"

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                break
            # Each connection is answered on its own (a client that connects and says nothing
            # waits out its READ_TIMEOUT_S without holding up the others, a stop among them).
            if self._clients.acquire(blocking=False):
                threading.Thread(target=self._answer, args=(conn,), name="hsio-control-client", daemon=True).start()
            else:
                with conn:
                    try:
                        conn.sendall(f"error busy: {self.MAX_CLIENTS} connections are open\n".encode())
                    except OSError:
                        pass

    def _answer(self, conn: socket.socket) -> None:
        try:
            with conn:
                line = _read_line(conn, time.monotonic() + self.READ_TIMEOUT_S)
                reply = self.handle(line.decode("utf-8", "replace").partition("\n")[0])
                conn.sendall((reply + "\n").encode())
        except OSError:
            pass
        finally:
            self._clients.release()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        try:
            self.sock.close()
        finally:
            try:
                self.path.unlink()
                if self._own_folder:
                    self.path.parent.rmdir()
            except OSError:
                pass


def send(path: str | Path, command: str, timeout_s: float = 2.0) -> str:
    """Send one command to a run's control socket; returns the reply line."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(timeout_s)
        s.connect(str(path))
        s.sendall((command.strip() + "\n").encode())
        data = _read_line(s, time.monotonic() + timeout_s)
    return data.decode("utf-8", "replace").strip()


def _read_line(conn: socket.socket, deadline: float) -> bytes:
    """What ``conn`` sends up to its first newline, its end, or MAX_LINE bytes, by ``deadline``
    (time.monotonic()): a peer that sends a byte now and then cannot hold the connection longer."""
    data = b""
    while b"\n" not in data and len(data) < ControlServer.MAX_LINE:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError("the line did not come in time")
        conn.settimeout(left)
        chunk = conn.recv(ControlServer.MAX_LINE)
        if not chunk:
            break
        data += chunk
    return data
