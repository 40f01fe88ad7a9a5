"""The operator's pause, resume, acknowledgement of a controller trip and stop from the page, through the run's control socket
(:mod:`hsio.safety.socket`, docs/safety.md section 4): the same requests as the terminal keys and
`hsio` scripts, obeyed by the run between two steps. Each request is written, with its UTC time
and the run's reply, to ``operator.log`` in the run folder; the run itself records the pause,
resume and stop it made (with lab time and step) in the events of run.sqlite.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

from hsio.safety import socket as control_socket

ACTIONS = ("pause", "resume", "ack", "stop")
LOG_FILE = "operator.log"


class Operator:
    """Sends the page's requests to the run in ``run_dir``.

    The socket is only ever spoken to from worker threads (:meth:`status` and :meth:`submit`
    return at once): a run that is slow to answer, or hung, never holds up the page's server."""

    STATUS_EVERY_S = 0.5
    STATUS_TIMEOUT_S = 0.5

    def __init__(self, run_dir: str | Path, socket_path=None):
        self.run_dir = Path(run_dir)
        self.socket_path = socket_path  # a callable giving the path (the record names it) or None
        self.log: list[str] = []
        self._lock = threading.Lock()
        self._workers = ThreadPoolExecutor(max_workers=2, thread_name_prefix="hsio-operator")
        self._line = ""
        #: True: the run answered the last status request; False: no run to answer (no socket, or
        #: refused); None: not known (not asked yet, or no answer in time: a busy or hung run).
        self.answers: bool | None = None
        self._asked_at = float("-inf")
        self._asking: Future | None = None

    def path(self) -> Path:
        named = self.socket_path() if self.socket_path is not None else None
        return Path(named) if named else self.run_dir / "control.sock"

    def status(self) -> str:
        """The run's last status line (``ok running phase HS step 12``), or '' if it did not
        answer; asked again in a worker thread at most every STATUS_EVERY_S (see :attr:`answers`)."""
        if (self._asking is None or self._asking.done()) and time.monotonic() - self._asked_at >= self.STATUS_EVERY_S:
            self._asked_at = time.monotonic()
            self._asking = self._workers.submit(self._ask_status)
        return self._line

    def _ask_status(self) -> None:
        path = self.path()
        if not path.exists():
            line, answers = "", False
        else:
            try:
                line = control_socket.send(path, "status", timeout_s=self.STATUS_TIMEOUT_S)
                answers = bool(line)
            except TimeoutError:
                line, answers = "", None
            except (OSError, ValueError):  # refused (a socket left by a killed run), or garbled
                line, answers = "", False
        self._line, self.answers = line, answers

    def submit(self, action: str, who: str = "the monitor page") -> Future:
        """:meth:`request` in a worker thread; the future gives the reply."""
        return self._workers.submit(self.request, action, who)

    def request(self, action: str, who: str = "the monitor page") -> str:
        """Send ``action`` (pause, resume, ack, stop) to the run; the reply, also logged. Blocks until
        the run answers (or the socket's timeout): call it from :meth:`submit`."""
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
        self._asked_at = float("-inf")  # the state changes: ask again at the next look
        return reply

    def close(self) -> None:
        self._workers.shutdown(wait=False, cancel_futures=True)
