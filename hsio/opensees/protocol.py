"""The wire format of OpenSees' ``genericClient`` element, checked and bounded (docs/opensees.md).

After connecting, the element sends one setup message of 11 little-endian int32:
``sizeCtrl[disp, vel, accel, force, time], sizeDaq[disp, vel, accel, force, time], dataSize``
(a genericClient with n basic DOFs sends ``n, n, n, 0, 1, 0, 0, 0, n, 0, dataSize``). Every later
message, both ways, is exactly ``dataSize`` little-endian float64. From the element, slot 0 holds
an action code and slots 1.. the trial ``d(n), v(n), a(n), t``; replies hold forces ``q(n)`` or an
n x n matrix in column-major order, padded with zeros.

Nothing here trusts the peer: sizes are checked against the element served and capped
(:data:`MAX_DATA_SIZE`), reads are exact and bounded in bytes and time, and a bad message is a
:class:`ProtocolError` naming what is wrong.
"""

from __future__ import annotations

import socket
import struct
import time
from dataclasses import dataclass

import numpy as np

from hsio.errors import HsioError

SETUP_FORMAT = "<11i"
SETUP_BYTES = struct.calcsize(SETUP_FORMAT)  # 44
MAX_DATA_SIZE = 65536  # doubles per message: 512 KiB, far above what any element needs

# Action codes (slot 0 of every message from the element).
SET_TRIAL = 3
COMMIT = 5
GET_DAQ = 6
GET_DISP, GET_VEL, GET_ACCEL, GET_FORCE, GET_TIME = 7, 8, 9, 10, 11
GET_INITIAL_STIFF, GET_TANGENT_STIFF, GET_DAMP, GET_MASS = 12, 13, 14, 15
SHUTDOWN, DIE = 98, 99
ACTION_NAMES = {
    1: "open", 2: "setup", SET_TRIAL: "setTrialResponse", 4: "execute", COMMIT: "commitState",
    GET_DAQ: "getDaqResponse", GET_DISP: "getDisp", GET_VEL: "getVel", GET_ACCEL: "getAccel",
    GET_FORCE: "getForce", GET_TIME: "getTime", GET_INITIAL_STIFF: "getInitialStiff",
    GET_TANGENT_STIFF: "getTangentStiff", GET_DAMP: "getDamp", GET_MASS: "getMass",
    SHUTDOWN: "shutdown", DIE: "DIE",
}
# Actions a genericClient sends and the server answers; the rest are refused.
SERVED = {SET_TRIAL, COMMIT, GET_DISP, GET_FORCE, GET_TIME, GET_INITIAL_STIFF, GET_TANGENT_STIFF, GET_DAMP,
          GET_MASS, DIE}
REPLIES = {GET_DISP, GET_FORCE, GET_TIME, GET_INITIAL_STIFF, GET_TANGENT_STIFF, GET_DAMP, GET_MASS}


class ProtocolError(HsioError):
    """A message from an OpenSees element is malformed, unexpected or too large."""


class PeerClosed(HsioError):
    """The element closed the connection."""


@dataclass(frozen=True)
class Setup:
    """The setup message: signal sizes of the control and DAQ vectors, and the frame size."""

    ctrl: tuple[int, int, int, int, int]  # disp, vel, accel, force, time
    daq: tuple[int, int, int, int, int]
    data_size: int

    @property
    def n(self) -> int:
        """Basic DOFs of the element (the size of its displacement vector)."""
        return self.ctrl[0]

    @classmethod
    def decode(cls, raw: bytes) -> "Setup":
        if len(raw) != SETUP_BYTES:
            raise ProtocolError(f"setup message: {len(raw)} bytes, expected {SETUP_BYTES}")
        v = struct.unpack(SETUP_FORMAT, raw)
        return cls(tuple(v[0:5]), tuple(v[5:10]), v[10])

    def encode(self) -> bytes:
        return struct.pack(SETUP_FORMAT, *self.ctrl, *self.daq, self.data_size)

    def check(self, n_expected: int, where: str, basic=()) -> None:
        """Refuse sizes that do not fit an element of ``n_expected`` basic DOFs (named ``basic``)
        or that are hostile."""
        names = ("disp", "vel", "accel", "force", "time")
        values = [*self.ctrl, *self.daq, self.data_size]
        if any(x < 0 for x in values):
            raise ProtocolError(f"{where}: setup message has a negative size: {values}")
        if self.n != n_expected:
            listed = f": {', '.join(basic)}" if basic else ""
            raise ProtocolError(f"{where}: the element has {self.n} basic DOFs (sizeCtrl disp); the served "
                                f"element has {n_expected}{listed} (the genericClient's -dof list must match)")
        for label, sizes in (("sizeCtrl", self.ctrl), ("sizeDaq", self.daq)):
            for name, size in zip(names[:4], sizes[:4]):
                if size not in (0, n_expected):
                    raise ProtocolError(f"{where}: {label} {name} = {size}, expected 0 or {n_expected}")
            if sizes[4] not in (0, 1):
                raise ProtocolError(f"{where}: {label} time = {sizes[4]}, expected 0 or 1")
        if self.ctrl[3]:
            raise ProtocolError(f"{where}: sizeCtrl force = {self.ctrl[3]}: the element sends trial forces, and this "
                                f"server imposes displacements only (sizeCtrl force must be 0)")
        if self.daq[3] != n_expected:
            raise ProtocolError(f"{where}: sizeDaq force = {self.daq[3]}, expected {n_expected} (the element's forces)")
        need = max(1 + sum(self.ctrl), n_expected * n_expected)
        if not need <= self.data_size <= MAX_DATA_SIZE:
            raise ProtocolError(f"{where}: dataSize = {self.data_size} doubles, expected {need} to {MAX_DATA_SIZE}")


def element_setup(n: int, data_size: int = 256) -> Setup:
    """The setup message a genericClient with ``n`` basic DOFs sends (for tests and tools)."""
    return Setup((n, n, n, 0, 1), (0, 0, 0, n, 0), max(data_size, 1 + 3 * n + 1, n * n))


@dataclass(frozen=True)
class Trial:
    """Slots 1.. of a setTrialResponse: displacement, velocity, acceleration (model units), time."""

    d: np.ndarray
    v: np.ndarray  # empty when the element sends no velocity (sizeCtrl vel = 0)
    a: np.ndarray  # empty when it sends no acceleration
    t: float

    @classmethod
    def from_frame(cls, frame: np.ndarray, n: int, where: str, has_time: bool = True, has_vel: bool = True,
                   has_accel: bool = True) -> "Trial":
        """The signals follow one another from slot 1, each present only when its size in the setup's
        sizeCtrl is not 0: ``d`` (n), then ``v`` (n), ``a`` (n) and ``t`` (1). ``has_time`` False: no
        time is read, t is nan; ``has_vel``/``has_accel`` False: v/a are empty."""
        sizes = (n, n * has_vel, n * has_accel, int(has_time))
        body = frame[1: 1 + sum(sizes)]
        if not np.all(np.isfinite(body)):
            raise ProtocolError(f"{where}: setTrialResponse carries a value that is not finite: "
                                f"{np.round(body, 6).tolist()}")
        ends = np.cumsum(sizes)
        d, v, a = (body[end - size: end].copy() for end, size in zip(ends[:3], sizes[:3]))
        t = float(body[ends[3] - 1]) if has_time else float("nan")
        return cls(d, v, a, t)


def action_of(frame: np.ndarray, where: str) -> int:
    """The action code in slot 0, refused unless it is a whole number the server answers."""
    code = float(frame[0])
    if not np.isfinite(code) or code != int(code) or int(code) not in ACTION_NAMES:
        raise ProtocolError(f"{where}: unknown action code {code!r}")
    code = int(code)
    if code not in SERVED:
        raise ProtocolError(f"{where}: action {code} ({ACTION_NAMES[code]}) is not served by a genericClient "
                            f"server")
    return code


def recv_exact(sock: socket.socket, n_bytes: int, buffer: bytearray | None = None,
               silent_since=None) -> bytes | bytearray:
    """Exactly ``n_bytes`` from ``sock``, all of them within the socket's timeout (a peer that
    trickles a message byte by byte does not stretch it: :class:`TimeoutError` once it is spent);
    :class:`PeerClosed` if the peer closes first, at most ``n_bytes`` ever buffered.

    ``silent_since``, when given, maps the time the read began (``time.monotonic()``) to the time
    from which the peer's silence counts: silence that work in progress explains is not counted
    (:meth:`hsio.opensees.lab.Lab.silent_since`), so the timeout restarts while it lasts."""
    out = buffer if buffer is not None and len(buffer) == n_bytes else bytearray(n_bytes)
    view = memoryview(out)
    timeout = sock.gettimeout()
    start = time.monotonic()
    got = 0
    try:
        while got < n_bytes:  # each pass reads at least one byte, waits out a deadline or ends
            if timeout is not None:
                since = start if silent_since is None else max(start, silent_since(start))
                left = since + timeout - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"{got} of {n_bytes} bytes within {timeout:g} s")
                sock.settimeout(left)
            try:
                k = sock.recv_into(view[got:], n_bytes - got)
            except (TimeoutError, socket.timeout):
                if silent_since is None:
                    raise TimeoutError(f"{got} of {n_bytes} bytes within {timeout:g} s") from None
                continue  # the deadline may have moved with work in progress: checked above
            if k == 0:
                raise PeerClosed("the element closed the connection" + (f" after {got} of {n_bytes} bytes" if got else ""))
            got += k
    finally:
        if timeout is not None:
            sock.settimeout(timeout)
    return out


class Framer:
    """Fixed-size frames of ``data_size`` float64 over one connection."""

    def __init__(self, sock: socket.socket, data_size: int, silent_since=None):
        self.sock = sock
        self.data_size = data_size
        self.silent_since = silent_since  # see recv_exact
        self._buffer = bytearray(8 * data_size)

    def receive(self) -> np.ndarray:
        quick_ack(self.sock)
        raw = recv_exact(self.sock, 8 * self.data_size, self._buffer, self.silent_since)
        quick_ack(self.sock)
        return np.frombuffer(raw, dtype="<f8").astype(float)

    def send(self, values) -> None:
        values = np.asarray(values, dtype=float).ravel()
        frame = np.zeros(self.data_size, dtype="<f8")
        frame[: values.size] = values
        self.sock.sendall(frame.tobytes())


def quick_ack(sock: socket.socket) -> None:
    """Acknowledge at once (Linux): the element sends messages that get no reply (setTrialResponse,
    commitState) followed by one that does, and with Nagle's algorithm on its side the second
    waits for the first's acknowledgement, which a delayed ACK holds back for tens of ms."""
    option = getattr(socket, "TCP_QUICKACK", None)
    if option is not None:
        try:
            sock.setsockopt(socket.IPPROTO_TCP, option, 1)
        except OSError:
            pass


def matrix_payload(K: np.ndarray) -> np.ndarray:
    """An n x n matrix as the element reads it: column-major."""
    return np.asarray(K, dtype=float).ravel(order="F")
