"""How far a browser tab lags behind its page (docs/monitor.md section 4).

A tab that stops reading its websocket (a stalled or suspended browser, a congested network)
leaves what the page sends it queued: first in the kernel's send buffer of the connection, then
in the server's own write buffer. :func:`backlog_bytes` is the sum of both over the tab's
connections, the bytes sent to the tab and not yet taken by it (as far as this machine knows).
The page sends its plots only while the backlog is under :data:`BACKLOG_BYTES`; past it, it sends
only the notices (a change of the run's state, a new event) and, once the tab reads again, the
latest state of the plots in one update.
"""

from __future__ import annotations

import array

try:
    import fcntl
    import termios
except ImportError:  # not a POSIX system: the server's write buffer alone
    fcntl = termios = None

BACKLOG_BYTES = 256 * 1024


def _connections(doc) -> list:
    """The websocket handlers of the tab that shows ``doc`` (none outside a Bokeh server)."""
    context = getattr(doc, "session_context", None)
    session = getattr(context, "_session", None)
    return [getattr(c, "_socket", None) for c in getattr(session, "_subscribed_connections", ())]


def _queued(handler) -> int:
    """Bytes written to ``handler``'s connection and not yet read by the peer: the server's write
    buffer plus the kernel's send queue (Linux SIOCOUTQ, the same request as TIOCOUTQ)."""
    stream = getattr(getattr(handler, "ws_connection", None), "stream", None)
    if stream is None or stream.closed():
        return 0
    queued = max(0, int(getattr(stream, "_total_write_index", 0)) - int(getattr(stream, "_total_write_done_index", 0)))
    if fcntl is None:
        return queued
    try:
        out = array.array("i", [0])
        fcntl.ioctl(stream.socket.fileno(), termios.TIOCOUTQ, out, True)
        queued += max(0, out[0])
    except (OSError, AttributeError, ValueError):  # no such request here: the server's buffer alone
        pass
    return queued


def backlog_bytes(doc) -> int:
    """The bytes the tab of ``doc`` has been sent and has not read (0 outside a server)."""
    return sum(_queued(h) for h in _connections(doc) if h is not None)
