"""The `hsio` subcommands, each in its own module (imported only when it runs)."""

from __future__ import annotations

import signal
import threading


def stop_requested() -> threading.Event:
    """An event set by SIGTERM or SIGINT (Ctrl-C). A serving command installs it before it says it
    is ready, so that a signal sent as soon as the banner appears stops it cleanly."""
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    return done


def wait_for_stop(done: threading.Event, poll_s: float = 0.5) -> None:
    """Block until ``done`` (from :func:`stop_requested`) is set: how a serving command (an
    emulator, a site server) waits for its operator."""
    try:
        while not done.wait(poll_s):
            pass
    except KeyboardInterrupt:
        pass
