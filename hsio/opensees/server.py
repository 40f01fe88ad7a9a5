"""The TCP side: one listening port per served element, one client per element at a time.

A genericClient says nothing about which element it is, so each served element listens on its
own port (``--port`` for the first, the next ports for the others; port 0: any free port, each
printed). A connection must send a valid setup message within the timeout; a second client for
an element already served is refused (logged, then closed). Each connection runs in its own
thread with a socket timeout: an element silent for ``timeout_s`` is dropped, its silence counted
only while the actuators are not executing a motion (for any element: the elements of one model
wait for each other, :meth:`hsio.opensees.lab.Lab.silent_since`). Whatever a client
sends, the server answers it, refuses it, or times out; the actuators hold and the session's
record is closed when the last element leaves (docs/opensees.md).

A session that stops on a fault (a trial beyond the stroke, an interlock, a controller lost, a
non-finite trial, a silent element of the same model) detaches all its elements at once, and
their connections stay open as *stopped* ones (:class:`hsio.opensees.element.StoppedElement`):
every request is answered with NaN and nothing reaches the actuators again, until DIE, a closed
connection or ``timeout_s`` of silence. OpenSees' genericClient does not notice a closed
connection (it reads the closed socket for ever); NaN answers make its analysis end by itself.
"""

from __future__ import annotations

import socket
import threading

from hsio.errors import HsioError, RecordError
from hsio.opensees import protocol as p
from hsio.opensees.element import ElementHandler, SessionEnded, StoppedElement
from hsio.opensees.lab import Lab, SessionBusy

SETUP_TIMEOUT_S = 10.0  # for the setup message (the element sends it right after connecting)
MAX_PENDING = 8  # connections waiting for their setup message, at most
ACCEPT_POLL_S = 0.2
CLAIM_WAIT_S = 0.5  # a second client for a busy element waits this long, then is refused


class OpenSeesServer:
    """Serves ``lab``'s elements on ``host``; ``ports[j]`` for element j (0: any free port)."""

    def __init__(self, lab: Lab, host: str = "127.0.0.1", ports=None, log=print):
        self.lab = lab
        self.host = host
        self.log = log
        ports = list(ports) if ports is not None else [0] * lab.n
        if len(ports) != lab.n:
            raise HsioError(f"{lab.n} elements served, {len(ports)} ports given")
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._freed = threading.Condition(self._lock)  # notified when an element's client leaves
        self._busy: dict[int, socket.socket] = {}
        self._open: set[socket.socket] = set()  # every accepted connection not yet closed
        self._ended: dict[socket.socket, str] = {}  # connections detached because another element stopped the session
        self._detached: set[socket.socket] = set()  # connections whose element's detach is queued
        self._session_of: dict[socket.socket, int] = {}  # the session each attached connection joined
        self._pending = 0
        self._threads: list[threading.Thread] = []
        self.refused = 0
        self.listeners: list[socket.socket] = []
        try:
            for port in ports:
                s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.bind((host, port))
                s.listen(4)
                s.settimeout(ACCEPT_POLL_S)
                self.listeners.append(s)
        except OSError as exc:
            for s in self.listeners:
                s.close()
            raise HsioError(f"cannot listen on {host} port {port}: {exc.strerror or exc}") from None
        self.ports = [s.getsockname()[1] for s in self.listeners]

    def start(self) -> "OpenSeesServer":
        for j, listener in enumerate(self.listeners):
            t = threading.Thread(target=self._accept, args=(j, listener), name=f"hsio-opensees-{j}", daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def _accept(self, j: int, listener: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                conn, peer = listener.accept()
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            with self._lock:
                full = self._pending >= MAX_PENDING or self._stop.is_set()
                if not full:
                    self._pending += 1
                    self._open.add(conn)
            if full:
                self._refuse(conn, f"element {self.lab.names[j]}: connection from {peer[0]}:{peer[1]} refused: "
                                   f"{MAX_PENDING} connections already wait for their setup message")
                continue
            t = threading.Thread(target=self._connection, args=(j, conn, peer), daemon=True,
                                 name=f"hsio-opensees-{j}-{peer[0]}:{peer[1]}")
            t.start()
            with self._lock:
                self._threads = [x for x in self._threads if x.is_alive()] + [t]

    def _refuse(self, conn: socket.socket, message: str) -> None:
        self.refused += 1
        self.log(message)
        try:
            conn.close()
        except OSError:
            pass

    def _connection(self, j: int, conn: socket.socket, peer) -> None:
        name = self.lab.names[j]
        who = f"element {name} ({peer[0]}:{peer[1]})"
        claimed = False
        try:
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            limit = min(SETUP_TIMEOUT_S, self.lab.settings.timeout_s)
            conn.settimeout(limit)
            try:
                setup = p.Setup.decode(bytes(p.recv_exact(conn, p.SETUP_BYTES)))
                setup.check(self.lab.n_basic[j], "setup message", self.lab.channels[self.lab.blocks[j]])
            except (TimeoutError, socket.timeout) as exc:
                key = " ([opensees] timeout_s)" if limit < SETUP_TIMEOUT_S else ""
                self._refuse(conn, f"{who}: refused: no setup message within {limit:g} s{key}: {exc}")
                return
            except (p.ProtocolError, p.PeerClosed, OSError) as exc:
                self._refuse(conn, f"{who}: refused: {_describe(exc)}")
                return
            finally:
                with self._lock:
                    self._pending -= 1
            with self._freed:
                # A client that reconnects at once may find the previous one still closing its session.
                self._freed.wait_for(lambda: j not in self._busy or self._stop.is_set(), CLAIM_WAIT_S)
                busy = j in self._busy or self._stop.is_set()
                if not busy:
                    self._busy[j] = conn
            if busy:
                self._refuse(conn, f"{who}: refused: element {name} already has a client (one client per element)")
                return
            claimed = True
            conn.settimeout(self.lab.settings.timeout_s)
            try:
                self.lab.attach(j, self.lab.settings.timeout_s, log=lambda line: self.log(f"{who}: {line}"))
            except SessionBusy as exc:
                self._refuse(conn, f"{who}: refused: {exc}")
                return
            except RecordError as exc:  # the actuators were opened, held and released again
                self.log(f"{who}: no session: {exc}")
                self._serve_stopped(j, conn, setup, None, who)
                return
            except Exception as exc:
                self.log(f"{who}: cannot open the actuators: {_describe(exc)}")
                self._serve_stopped(j, conn, setup, None, who)
                return
            try:  # the session it joined (only a detach of j ends it for j)
                session = self.lab._call(lambda: self.lab.sessions)
            except HsioError:  # the server is closing: its connections are shut down
                session = 0
            with self._lock:
                self._session_of[conn] = session
            self.log(f"{who}: connected (dataSize {setup.data_size})")
            handler = ElementHandler(self.lab, j, p.Framer(conn, setup.data_size, self.lab.silent_since),
                                     ctrl=setup.ctrl, ended=lambda: self._ended.get(conn, ""))
            reason = "left"
            hold = False  # the actuators are told to hold (when this element is still in the session)
            failed = False  # this element stopped the session: the actuators hold
            stopped = False  # the session stopped on a fault: the client is answered NaN until it leaves
            try:
                reason = handler.serve()
            except SessionEnded as exc:  # another element stopped the session and detached this one
                reason = str(exc)
                stopped = True
            except p.PeerClosed as exc:
                reason = str(exc)
                if self._stop.is_set():  # the server shut the connection down: it stopped the session
                    reason = "stopped: the server is stopping"
                    hold = True
            except (TimeoutError, socket.timeout):
                reason = f"silent for {self.lab.settings.timeout_s:g} s: disconnected"
                hold = failed = True
            except p.ProtocolError as exc:
                reason = f"refused: {exc}"
                hold = failed = True
                stopped = handler.action is not None  # a known action: its reply (if any) is known
            except HsioError as exc:
                reason = f"stopped: {exc}"
                hold = failed = stopped = True
            except OSError as exc:
                reason = ("stopped: the server is stopping" if self._stop.is_set()
                          else f"connection lost: {exc.strerror or exc}")
                hold = True
                failed = not self._stop.is_set()
            except Exception as exc:  # a fault of the server itself: hold, report, keep serving
                reason = f"unexpected error: {exc!r}"
                hold = failed = stopped = True
            with self._lock:  # another element that stopped the session may have detached this one already
                mine = conn not in self._detached
                self._detached.add(conn)
            leaving = None
            if mine:
                if hold:
                    self.lab.hold(reason, j)
                try:
                    leaving = self.lab.begin_detach(j, f"{reason}; {handler.messages} messages", clean=handler.died)
                except Exception as exc:  # the server is closing: the lab closes the session itself
                    self.log(f"{who}: {reason}; {exc}")
            elif not stopped:
                self.log(f"{who}: {reason} (detached earlier: {self._ended.get(conn, 'the session stopped')})")
            stopped = stopped and not self._stop.is_set()
            if stopped:  # the others are detached first: no request of theirs moves anything after this fault
                if failed and mine:
                    self._end_session_of_others(name, reason, session)
                handler.died = self._serve_stopped(j, conn, setup, handler.action, who)
            # The element is free once its detach is queued (and its stopped client has gone): a client
            # that reconnects now attaches after it, in the next session (after the preloads ramped off).
            with self._freed:
                self._busy.pop(j, None)
                claimed = False
                if handler.died:
                    self._open.discard(conn)
                self._freed.notify_all()
            if handler.died:  # the client is done with it; the session's end (a ramp off) may take a while
                try:
                    conn.close()
                except OSError:
                    pass
            if failed and mine and not stopped and not self._stop.is_set():
                self._end_session_of_others(name, reason, session)
            if leaving is not None:
                try:
                    leaving.result()
                except Exception as exc:
                    self.log(f"{who}: {reason}; closing the session: {_describe(exc)}")
        finally:
            with self._freed:
                self._open.discard(conn)
                self._ended.pop(conn, None)
                self._detached.discard(conn)
                self._session_of.pop(conn, None)
                if claimed:
                    self._busy.pop(j, None)
                    self._freed.notify_all()
            try:
                conn.close()
            except OSError:
                pass

    def _serve_stopped(self, j: int, conn: socket.socket, setup: p.Setup, pending: int | None, who: str) -> bool:
        """The session of element ``j``'s client stopped on a fault (or never opened): its
        connection stays open and every request is answered with NaN (:class:`StoppedElement`),
        first ``pending``, the request the fault interrupted, so that the model ends by itself,
        until DIE (returns True), a closed connection, ``timeout_s`` of silence or the server's
        stop. Nothing reaches the lab: the actuators do not move for this client again."""
        if self._stop.is_set():  # the server is closing: its connections are shut down
            return False
        timeout = self.lab.settings.timeout_s
        stopped = StoppedElement(p.Framer(conn, setup.data_size), self.lab.n_basic[j], self.lab.names[j])
        self.log(f"{who}: the session stopped: nothing this client sends moves the actuators again; every request "
                 f"is answered with NaN until DIE, a closed connection or {timeout:g} s of silence")
        try:
            end = stopped.serve(pending)
        except p.PeerClosed:  # the client closed it, or the server shut it down as it stops
            end = "the server is stopping" if self._stop.is_set() else "the element closed the connection"
        except (TimeoutError, socket.timeout):
            end = f"silent for {timeout:g} s: disconnected"
        except p.ProtocolError as exc:
            end = f"refused: {exc}"
        except OSError as exc:
            end = "the server is stopping" if self._stop.is_set() else f"connection lost: {exc.strerror or exc}"
        self.log(f"{who}: stopped session: {end}; {stopped.answered} request(s) answered with NaN")
        return stopped.died

    def _end_session_of_others(self, name: str, reason: str, session: int) -> None:
        """Element ``name`` stopped its session (number ``session``; ``reason``; the actuators hold):
        the session's other elements are detached from it now, each on its client's behalf, so that the session
        and its record close at once (their model, waiting on the element that failed, may send
        them nothing for a while). Their clients stay connected: each one's next message finds its
        session stopped (:class:`SessionEnded`) and is answered as a stopped session's. A later
        session (opened by a client that waited for this one to end) is none of theirs."""
        try:  # queued after the failed element's detach: the elements still in the session
            others = self.lab._call(lambda: sorted(self.lab.active) if self.lab.sessions == session else [])
        except HsioError:
            return
        why = f"stopped: element {name} stopped the session ({reason})"
        ended = []
        with self._lock:
            for k in others:
                conn = self._busy.get(k)
                if conn is not None and conn not in self._detached and self._session_of.get(conn) == session:
                    self._detached.add(conn)
                    self._ended[conn] = why
                    ended.append(k)
        for k in ended:
            try:
                self.lab.begin_detach(k, why)
            except HsioError:  # the server is closing: the lab closes the session itself
                return

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop listening, drop every client, end the session (actuators hold, record closed).
        Every connection's thread is woken (its socket shut down, its wait for a step or for its
        element released) and given ``timeout_s`` to end; one still running then is logged."""
        if self._stop.is_set():  # closed already
            return
        self._stop.set()
        with self._freed:  # a client waiting to claim its element is refused at once
            self._freed.notify_all()
        for s in self.listeners:
            try:
                s.close()
            except OSError:
                pass
        with self._lock:
            conns = list(self._open)
            threads = list(self._threads)
        for c in conns:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self.lab.release()  # an element waiting for the others to commit a step
        for t in threads:
            t.join(timeout_s)
            if t.is_alive():
                self.log(f"{t.name}: still running {timeout_s:g} s after the server was asked to close")
        self.lab.close()

    def __enter__(self) -> "OpenSeesServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


def _describe(exc: BaseException) -> str:
    if isinstance(exc, (TimeoutError, socket.timeout)):
        return f"timed out ({exc})" if str(exc) else "timed out"
    if isinstance(exc, OSError):
        return exc.strerror or str(exc)
    return str(exc)
