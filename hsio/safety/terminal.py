"""Operator keys on the terminal: p pause, r resume, s stop (docs/safety.md section 4).

Read in a daemon thread, only when stdin is a terminal; the terminal is put in cbreak mode (one
key at a time, no echo) and restored on close.
"""

from __future__ import annotations

import os
import select
import sys
import threading

from hsio.safety.control import RunControl

KEYS = "p pause, r resume, a acknowledge a controller trip, s stop"


class KeyReader:
    """Turns key presses into :class:`RunControl` requests."""

    POLL_S = 0.2

    def __init__(self, control: RunControl, notify=None):
        self.control = control
        self.notify = notify or (lambda line: None)
        self._stop = threading.Event()
        self._saved = None
        self._thread = None
        try:
            fd = sys.stdin.fileno()
            tty = os.isatty(fd)
        except (OSError, ValueError, AttributeError):
            tty = False
        if not tty:
            return
        import termios
        import tty as tty_mod

        self._fd = fd
        self._saved = termios.tcgetattr(fd)
        tty_mod.setcbreak(fd)
        self.notify(f"keys: {KEYS}")
        self._thread = threading.Thread(target=self._read, name="hsio-keys", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._fd], [], [], self.POLL_S)
            if not ready:
                continue
            key = os.read(self._fd, 1).decode(errors="replace").lower()
            if key == "p":
                self.notify(f"pause requested: {self.control.request_pause('keys')}")
            elif key == "r":
                self.notify(f"resume requested: {self.control.request_resume('keys')}")
            elif key == "a":
                self.notify(f"acknowledge requested: {self.control.request_ack('keys')}")
            elif key == "s":
                self.notify(f"stop requested: {self.control.request_stop('stopped by the operator (key s)')}")

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._saved is not None:
            import termios

            termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)
            self._saved = None
