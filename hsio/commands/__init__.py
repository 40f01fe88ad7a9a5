"""The `hsio` subcommands, each in its own module (imported only when it runs)."""

from __future__ import annotations

import signal
import threading


def wait_for_stop(poll_s: float = 0.5) -> None:
    """Block until SIGTERM or SIGINT (Ctrl-C): how a serving command (an emulator, a site
    server) waits for its operator."""
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    try:
        while not done.wait(poll_s):
            pass
    except KeyboardInterrupt:
        pass
