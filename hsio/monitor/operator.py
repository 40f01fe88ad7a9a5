"""The operator's pause, resume and stop from the page, through the run's control socket
(:mod:`hsio.safety.socket`, docs/safety.md section 4): the same requests as the terminal keys and
`hsio` scripts, obeyed by the run between two steps. Each request is written, with its UTC time
and the run's reply, to ``operator.log`` in the run folder; the run itself records the pause,
resume and stop it made (with lab time and step) in the events of run.sqlite.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from hsio.safety import socket as control_socket

ACTIONS = ("pause", "resume", "stop")
LOG_FILE = "operator.log"


class Operator:
    """Sends the page's requests to the run in ``run_dir``."""

    STATUS_EVERY_S = 0.5

    def __init__(self, run_dir: str | Path, socket_path=None):
        self.run_dir = Path(run_dir)
        self.socket_path = socket_path  # a callable giving the path (the record names it) or None
        self.log: list[str] = []
        self._lock = threading.Lock()
        self._status = ("", 0.0)

    def path(self) -> Path:
        named = self.socket_path() if self.socket_path is not None else None
        return Path(named) if named else self.run_dir / "control.sock"

    def status(self) -> str:
        """The run's status line (``ok running phase HS step 12``), or '' if nobody answers;
        asked at most every STATUS_EVERY_S."""
        line, when = self._status
        if time.monotonic() - when < self.STATUS_EVERY_S:
            return line
        try:
            line = control_socket.send(self.path(), "status", timeout_s=0.5) if self.path().exists() else ""
        except OSError:
            line = ""
        self._status = (line, time.monotonic())
        return line

    def request(self, action: str, who: str = "the monitor page") -> str:
        """Send ``action`` (pause, resume, stop) to the run; the reply, also logged."""
        if action not in ACTIONS:
            reply = f"error unknown action {action!r}; known: {', '.join(ACTIONS)}"
        else:
            path = self.path()
            try:
                reply = control_socket.send(path, action) if path.exists() else \
                    "error: no control socket: the run is over or was started without one"
            except OSError as exc:
                reply = f"error: the run does not answer on {path}: {exc}"
        stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        line = f"{stamp} {action} from {who}: {reply}"
        with self._lock:
            self.log.append(line)
            try:
                with open(self.run_dir / LOG_FILE, "a", encoding="utf-8") as f:
                    f.write(line + "\n")
            except OSError:
                pass
        self._status = ("", 0.0)
        return reply
