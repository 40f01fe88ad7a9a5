"""The emulated controller as CiA 402 drives on a CAN bus (canopen LocalNode, python-can).

One node per axis (node ids ``node_id``, ``node_id + 1``, ...), each with the object dictionary
of :mod:`hsio.drivers.canopen_od`:

* the controlword/statusword state machine of CiA 402 (switch on disabled -> ready to switch on
  -> switched on -> operation enabled; quick stop; fault and fault reset). The axis follows the
  targets only in operation enabled with the halt bit clear; otherwise it holds its position
  (a hydraulic actuator holds, it does not coast).
* cyclic synchronous position (mode 8, displacement control) and cyclic synchronous torque
  (mode 10, read as force control);
* RPDOs for the targets, TPDOs for the actual values on every SYNC, SDO for configuration,
  heartbeat (0x1017), EMCY for refused targets, interlocks and the host watchdog.

Lockstep: with ``lockstep=True`` every SYNC advances the controller one period before the TPDOs
are sent (the emulator-only object 0x2100 reads 1). In real time the controller runs its own
loop and a SYNC only samples it.
"""

from __future__ import annotations

import logging
import math
import struct
import threading

import canopen
from canopen.sdo import SdoAbortedError

from hsio.clock import CONTROLLER_RATE_HZ
from hsio.drivers import canopen_od as cod
from hsio.emulators.bank import CommandRefused, ControllerBank
from hsio.errors import ConfigError
from hsio.interfaces import ControlMode

log = logging.getLogger(__name__)

SOD, RTSO, SO, OE, QSA, FAULT = "SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED", \
    "QUICK STOP ACTIVE", "FAULT"
STATUS_BITS = {SOD: 0x0040, RTSO: 0x0021, SO: 0x0023, OE: 0x0027, QSA: 0x0007, FAULT: 0x0008}
WARNING, REMOTE, FOLLOWING, VOLTAGE = 0x0080, 0x0200, 0x1000, 0x0010


class DriveAxis:
    """The CiA 402 side of one axis: state machine, mode, targets, PDO codec."""

    def __init__(self, emulator: "CanopenEmulator", axis: int, node: canopen.LocalNode):
        self.emu = emulator
        self.bank = emulator.bank
        self.axis = axis
        self.node = node
        self.state = SOD
        self.controlword = 0
        self.mode = cod.CSP
        self.target_counts = 0
        self.target_torque = 0
        self.rx_count = 0
        self.warning = False
        self.fault_code = 0
        self.rated_N = float(emulator.rated_force_N)
        cfg = self.bank.controllers[axis].config
        if emulator.position_limits_mm is None:  # the controller's stroke, centred on zero
            lo, hi = -0.5 * cfg.stroke_mm, 0.5 * cfg.stroke_mm
        else:
            lo, hi = emulator.position_limits_mm
        node.data_store.setdefault(0x607D, {})[1] = struct.pack("<i", int(lo * cod.COUNTS_PER_MM))
        node.data_store[0x607D][2] = struct.pack("<i", int(hi * cod.COUNTS_PER_MM))
        node.data_store.setdefault(0x6076, {})[0] = struct.pack("<I", int(self.rated_N))
        # The force capacity as max torque, per mille of the rated force (u16).
        node.data_store.setdefault(0x6072, {})[0] = struct.pack("<H", min(0xFFFF, int(cfg.force_limit_kN * 1e6 / self.rated_N)))
        node.add_read_callback(self.on_read)
        node.add_write_callback(self.on_write)

    # -- scaling -----------------------------------------------------------------------------------
    @staticmethod
    def to_counts(mm: float) -> int:
        return int(round(mm * cod.COUNTS_PER_MM))

    def to_permille(self, kN: float) -> int:
        if not math.isfinite(kN):
            return -32768  # a NaN reading: the int16 "no value"
        return max(-32768, min(32767, int(round(kN * 1e6 / self.rated_N))))

    # -- SDO ---------------------------------------------------------------------------------------
    def on_read(self, index, subindex, od):
        if index == 0x6041:
            return self.statusword()
        if index == 0x6061:
            return self.mode
        if index == 0x6060:
            return self.mode
        if index == 0x6064:
            return self.to_counts(self.bank.displacement(self.axis))
        if index == 0x6077:
            return self.to_permille(self.bank.force(self.axis))
        if index == 0x607A:
            return self.target_counts
        if index == 0x6071:
            return self.target_torque
        if index == cod.LOCKSTEP_FLAG:
            return 1 if self.bank.lockstep else 0
        if index == cod.CLOCK:
            return self.bank.ticks & 0xFFFFFFFF
        if index == cod.CYCLE:
            return self.bank.ticks & 0xFFFF
        if index == cod.WATCHDOG_MS:
            return int(round(self.bank.watchdog_s * 1000))
        return None

    def on_write(self, index, subindex, od, data):
        value = od.decode_raw(data)
        with self.bank.lock:
            if index == 0x6040:
                self.on_controlword(value)
            elif index == 0x6060:
                self.set_mode(value, from_sdo=True)
            elif index == 0x607A:
                self.target_counts = value
                self.apply_targets(from_sdo=True)
            elif index == 0x6071:
                self.target_torque = value
                self.apply_targets(from_sdo=True)
            elif index == cod.CLOCK:
                try:
                    self.bank.advance_to(value)
                except CommandRefused:
                    raise SdoAbortedError(0x08000022) from None  # not in the present device state
            elif index == cod.WATCHDOG_MS:
                self.bank.watchdog_s = value / 1000.0

    # -- state machine -----------------------------------------------------------------------------
    def statusword(self) -> int:
        word = STATUS_BITS[self.state] | REMOTE
        if self.state in (RTSO, SO, OE):
            word |= VOLTAGE
        if self.warning:
            word |= WARNING
        if self.state == OE and not self.controlword & 0x0100 and not self.bank.axes[self.axis].watchdog_expired:
            word |= FOLLOWING
        return word

    def on_controlword(self, cw: int) -> None:
        previous, self.controlword = self.controlword, cw
        state = self.state
        if state == FAULT:
            if cw & 0x80 and not previous & 0x80:  # fault reset, rising edge
                c = self.bank.controllers[self.axis]
                c.clear_trip()
                self.bank.axes[self.axis].watchdog_expired = False
                self.fault_code = 0
                self.warning = False
                self.node.emcy.reset()
                self.state = SOD
        elif not cw & 0x02:  # disable voltage
            self.state = SOD
        elif cw & 0x06 == 0x02:  # quick stop
            self.state = QSA if state == OE else SOD
        elif cw & 0x0F == 0x06:  # shutdown
            if state in (SOD, SO, OE):
                self.state = RTSO
        elif cw & 0x0F == 0x07:  # switch on / disable operation
            if state in (RTSO, OE):
                self.state = SO
        elif cw & 0x0F == 0x0F:  # enable operation
            if state in (SO, QSA):
                self.state = OE
            elif state == RTSO:
                self.state = OE  # transitions 3 + 4 at once, as many drives allow
        self.apply_targets()

    def set_mode(self, mode: int, from_sdo: bool = False) -> None:
        if mode not in (cod.CSP, cod.CST):
            if from_sdo:
                raise SdoAbortedError(0x06090030)
            self.node.emcy.send(0x6320, 0x01, struct.pack("<b", mode) + b"\0" * 4)
            return
        if self.axis in self.emu.ignore_mode or self.bank.ignores_mode(self.axis):
            mode = self.mode  # a drive that ignores the switch (a fault for tests); 0x6061 says so
        if mode != self.mode:
            self.mode = mode
            c = self.bank.controllers[self.axis]
            # Bumpless: the targets start at the present measurement.
            self.target_counts = self.to_counts(c.measured_displacement)
            self.target_torque = self.to_permille(c.measured_force)
        self.apply_targets()

    def warn(self, code: int, register: int = 0x01) -> None:
        """A warning EMCY (e.g. 0x4210, temperature): the warning bit 7 of the statusword set,
        the drive stays in its state and goes on following its targets."""
        with self.bank.lock:
            self.warning = True
        self.node.emcy.send(code, register, b"\0" * 5)
        self.send_tpdo1()

    def following(self) -> bool:
        return self.state == OE and not self.controlword & 0x0100

    def apply_targets(self, from_sdo: bool = False) -> None:
        """Pass the targets to the controller (or hold when not following)."""
        self.rx_count += 1
        if self.state == FAULT:
            return
        mode = ControlMode.FORCE if self.mode == cod.CST else ControlMode.DISPLACEMENT
        value = self.target_counts / cod.COUNTS_PER_MM if mode is ControlMode.DISPLACEMENT \
            else self.target_torque * self.rated_N / 1e6
        if self.following():
            try:
                self.bank.check_command(self.axis, mode, value)
            except CommandRefused as exc:
                self.bank.refuse(self.axis)
                self.warning = True
                self.node.emcy.send(0x8612, 0x01, b"\0" * 5)
                log.info("refused: %s", exc)
                if from_sdo:
                    raise SdoAbortedError(0x06090030) from None
                return
        self.bank.apply(self.axis, mode, value, self.following(), float(self.rx_count % (1 << 24)))

    def check_faults(self) -> None:
        """Interlock trips and watchdog expiry become FAULT with an EMCY (once each)."""
        c = self.bank.controllers[self.axis]
        code = 0
        if c.tripped:
            code = 0x7320 if "displacement" in c.tripped else 0x5000 if "valve" in c.tripped else 0x2310
        elif self.bank.axes[self.axis].watchdog_expired:
            code = 0x8130
        if code and self.state != FAULT:
            self.state = FAULT
            self.fault_code = code
            self.node.emcy.send(code, 0x01, b"\0" * 5)
            self.send_tpdo1()

    # -- PDOs --------------------------------------------------------------------------------------
    def on_rpdo1(self, data: bytes) -> None:
        cw, mode = struct.unpack_from("<Hb", data)
        with self.bank.lock:
            if mode != self.mode:
                self.set_mode(mode)
            self.on_controlword(cw)
        self.send_tpdo1()

    def on_rpdo2(self, data: bytes) -> None:
        pos, torque = struct.unpack_from("<ih", data)
        with self.bank.lock:
            self.target_counts, self.target_torque = pos, torque
            self.apply_targets()

    def send_tpdo1(self) -> None:
        self.emu.network.send_message(0x180 + self.node.id, struct.pack("<Hb", self.statusword(), self.mode))

    def tpdo2(self) -> bytes:
        d, f = self.bank.measured(self.axis)
        counts = self.to_counts(d) if math.isfinite(d) else -(1 << 31)  # a NaN reading: the int32 "no value"
        counts = max(-(1 << 31), min((1 << 31) - 1, counts))
        return struct.pack("<ihH", counts, self.to_permille(f), self.bank.ticks & 0xFFFF)

    def send_tpdo2(self, data: bytes | None = None) -> None:
        self.emu.network.send_message(0x280 + self.node.id, data if data is not None else self.tpdo2())


class CanopenEmulator:
    """The bank's axes as CiA 402 nodes on a CAN channel (python-can's virtual bus by default)."""

    def __init__(self, bank: ControllerBank, channel: str = "hsio", node_id: int = 1,
                 interface: str = "virtual", heartbeat_ms: int = 100, rated_force_N: float = cod.RATED_FORCE_N,
                 position_limits_mm: tuple[float, float] | None = None, faults=None, bus_options: dict | None = None):
        """``rated_force_N`` is the drive's rated torque 0x6076 (read as newtons);
        ``position_limits_mm`` its software position limits 0x607D (default: the controller's
        stroke, centred on zero; (0, 0): none)."""
        if bank.lockstep and abs(bank.rate_hz - CONTROLLER_RATE_HZ) > 1e-9 * CONTROLLER_RATE_HZ:
            # Each SYNC is one period of the drive and of the experiment (1024 Hz), and no
            # object tells the driver the drive's rate.
            raise ConfigError(f"emulated CANopen drive: rate_hz = {bank.rate_hz:g} in lockstep, where each SYNC is "
                              f"one period of the experiment's {CONTROLLER_RATE_HZ:g} Hz clock; leave rate_hz at "
                              f"{CONTROLLER_RATE_HZ:g} or run in real time")
        last = node_id + len(bank.controllers) - 1
        if not 1 <= node_id <= last <= 127:
            raise ConfigError(f"emulated CANopen drive: {len(bank.controllers)} axes from node {node_id} are nodes "
                              f"{node_id}..{last}, outside the CANopen node ids 1..127")
        self.bank = bank
        if faults is not None:
            bank.faults = faults
        self.bus_options = dict(bus_options or {})
        self.rated_force_N = rated_force_N
        self.position_limits_mm = position_limits_mm
        self.channel, self.interface = channel, interface
        self.node_id = node_id
        self.heartbeat_ms = heartbeat_ms
        self.network: canopen.Network | None = None
        self.axes: list[DriveAxis] = []
        # Axes whose drive ignores the host's switch of the mode of operation 0x6060 (a fault for
        # tests, docs/canopen.md "Mode confirmation"): the mode display 0x6061 keeps its mode.
        self.ignore_mode: set[int] = set()
        self._fault_thread: threading.Thread | None = None
        self._stop = threading.Event()

    slcan = None  # a SlcanPort when served over SLCAN

    @property
    def url(self) -> str:
        if self.slcan is not None:
            return self.slcan.url(self.node_id)
        return f"canopen+{self.interface}://{self.channel}/{self.node_id}"

    def start(self) -> "CanopenEmulator":
        self.network = canopen.Network()
        if self.interface == "slcan":  # the adapter's end of a serial line anyone may write to
            self.network.bus = tolerant_slcan_bus(self.channel, **self.bus_options)
        self.network.connect(interface=self.interface, channel=self.channel, **self.bus_options)
        for k in range(len(self.bank.controllers)):
            node = canopen.LocalNode(self.node_id + k, cod.object_dictionary(self.node_id + k))
            self.network.add_node(node)
            axis = DriveAxis(self, k, node)
            self.axes.append(axis)
            self.network.subscribe(0x200 + node.id, lambda cid, data, ts, a=axis: self._guard(a, a.on_rpdo1, data))
            self.network.subscribe(0x300 + node.id, lambda cid, data, ts, a=axis: self._guard(a, a.on_rpdo2, data))
        self.network.subscribe(0x80, self.on_sync)
        for axis in self.axes:
            axis.node.nmt.state = "PRE-OPERATIONAL"
            self.network.send_message(0x700 + axis.node.id, b"\x00")  # boot-up
            if self.heartbeat_ms:
                axis.node.set_data(0x1017, 0, struct.pack("<H", self.heartbeat_ms))
        self.bank.start()
        self._stop.clear()
        self._fault_thread = threading.Thread(target=self._watch_faults, name="canopen-faults", daemon=True)
        self._fault_thread.start()
        return self

    def _guard(self, axis, handler, data) -> None:
        if axis.node.nmt.state != "OPERATIONAL":
            return  # PDOs count only in OPERATIONAL
        try:
            handler(data)
        except struct.error:  # a PDO of the wrong length: CiA 301's length error, the drive goes on
            axis.node.emcy.send(0x8210, 0x11, bytes([len(data)]) + b"\0" * 4)
        except Exception:  # nothing on the bus may stop the drive
            log.exception("bad PDO %r", bytes(data))

    def on_sync(self, can_id, data, timestamp) -> None:
        try:
            fault = self.bank.fault_due()
            if fault is not None and fault.kind == "drop":
                return  # the SYNC is lost: nothing advances, nothing answers
            if fault is not None and fault.kind == "restart":
                self.restart()
                return
            if self.bank.lockstep:
                with self.bank.lock:
                    self.bank.advance_to(self.bank.ticks + 1)
            if fault is not None and fault.kind == "delay":
                threading.Timer(fault.arg, self._send_tpdos).start()
                return
            self._send_tpdos(fault)
        except Exception:
            log.exception("SYNC handling failed")

    def _send_tpdos(self, fault=None) -> None:
        code = self.bank.faults.take_warn() if self.bank.faults else None
        if code is not None and self.axes and self.axes[0].node.nmt.state == "OPERATIONAL":
            self.axes[0].warn(code)  # the warn fault (docs/faults.md): axis 0 stays operation enabled
        for axis in self.axes:
            if axis.node.nmt.state == "OPERATIONAL":
                axis.check_faults()
                data = axis.tpdo2()
                if fault is not None and fault.kind == "corrupt":
                    data = data[:-3]  # a frame cut short
                axis.send_tpdo2(data)
                if fault is not None and fault.kind == "duplicate":
                    axis.send_tpdo2(data)

    def restart(self) -> None:
        """The controller restarts (docs/faults.md): state lost, every node boots up again."""
        self.bank.restart()
        for axis in self.axes:
            axis.state, axis.controlword, axis.mode = SOD, 0, cod.CSP
            axis.node.nmt.state = "PRE-OPERATIONAL"
            self.network.send_message(0x700 + axis.node.id, b"\x00")

    def _watch_faults(self) -> None:
        while not self._stop.wait(0.01):
            with self.bank.lock:
                for axis in self.axes:
                    axis.check_faults()

    def stop(self) -> None:
        self._stop.set()
        if self._fault_thread is not None:
            self._fault_thread.join(timeout=1.0)
        self.bank.stop()
        for k in range(len(self.bank.controllers)):
            self.bank.hold(k)
        if self.network is not None:
            for axis in self.axes:
                axis.node.nmt.stop_heartbeat()
            self.network.disconnect()
            self.network = None
        self.axes = []
        if self.slcan is not None:
            self.slcan.close()
            self.slcan = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


# The longest line of the Lawicel protocol (an extended CAN FD frame with 64 data bytes and a
# timestamp) is under 150 characters: a longer run of bytes without a line end is not SLCAN.
SLCAN_LINE_MAX = 256


def tolerant_slcan_bus(channel: str, **options):
    """python-can's SLCAN bus for the emulated adapter, which a line that is not SLCAN (bytes that
    are not ASCII, a frame whose id or length is not hexadecimal: a Modbus RTU client on the wrong
    port, noise) does not stop: the line is dropped, as an adapter answers such a line with an
    error and goes on, and the bus goes on receiving the frames that follow."""
    from can.exceptions import CanOperationError
    from can.interfaces.slcan import slcanBus

    class TolerantSlcanBus(slcanBus):
        def _recv_internal(self, timeout):
            try:
                received = super()._recv_internal(timeout)
            except CanOperationError as exc:
                if not isinstance(exc.__cause__, UnicodeDecodeError):
                    raise  # the serial line itself failed
                received = self._dropped("not ASCII")
            except (ValueError, IndexError):
                received = self._dropped("not a frame")
            if len(self._buffer) > SLCAN_LINE_MAX:
                self._dropped(f"over {SLCAN_LINE_MAX} bytes without a line end")
            return received

        def _dropped(self, why: str):
            log.warning("SLCAN: a line dropped (%s): %r", why, bytes(self._buffer[:40]))
            self._buffer.clear()
            return None, False

    return TolerantSlcanBus(channel=channel, **options)


class SlcanPort:
    """The emulated drives' CAN bus reachable from another process the way a USB-CAN adapter is:
    the Lawicel (SLCAN) serial protocol, spoken by python-can's ``slcan`` interface at both ends.

    ``kind="pty"``: two pseudo-terminals back to back (:class:`hsio.emulators.modbus.PtyBridge`);
    the emulator's bus opens one, a client opens :attr:`path`. ``kind="tcp"``: a TCP port on
    127.0.0.1 (a client opens ``socket://127.0.0.1:PORT`` through pyserial); one client at a
    time, its bytes forwarded to and from a pseudo-terminal the emulator's bus opens.
    """

    def __init__(self, kind: str = "pty", host: str = "127.0.0.1", port: int = 0):
        import os
        import socket
        import tty

        from hsio.emulators.modbus import PtyBridge

        if kind not in ("pty", "tcp"):
            raise ValueError(f"SLCAN port kind must be 'pty' or 'tcp', got {kind!r}")
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise ValueError(f"SLCAN over TCP listens on the loopback address only, not {host!r}")
        self.kind = kind
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        if kind == "pty":
            self.bridge = PtyBridge()
            self.server_path, self.path = self.bridge.server_path, self.bridge.path
            return
        self.bridge = None
        self._master, slave = os.openpty()
        tty.setraw(slave)
        self._slave = slave
        self.server_path = os.ttyname(slave)
        self.listener = socket.socket()
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind((host, port))
        self.listener.listen(1)
        self.listener.settimeout(0.1)
        self.host, self.port = host, self.listener.getsockname()[1]
        self.path = f"socket://{host}:{self.port}"
        t = threading.Thread(target=self._serve, name="slcan-tcp", daemon=True)
        t.start()
        self._threads.append(t)

    def _serve(self) -> None:
        import os
        import select
        import socket

        while not self._stop.is_set():
            try:
                conn, _ = self.listener.accept()
            except OSError:
                self._discard()  # nobody listens: what the drives send is gone, as on a cable
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._conn = conn
            self._discard()  # frames sent before anyone listened are gone
            with conn:
                while not self._stop.is_set():
                    ready, _, _ = select.select([conn, self._master], [], [], 0.1)
                    try:
                        if conn in ready:
                            data = conn.recv(4096)
                            if not data:
                                break
                            if hasattr(socket, "TCP_QUICKACK"):  # ack at once: the client's Nagle then sends its next frame
                                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_QUICKACK, 1)
                            os.write(self._master, data)
                        if self._master in ready:
                            conn.sendall(os.read(self._master, 4096))
                    except OSError:
                        break
            self._conn = None

    def _discard(self) -> None:
        """Read and drop what the emulated drives sent with no client connected, so that their
        writes never block on a full pseudo-terminal (a stop would then hang)."""
        import os
        import select

        try:
            while select.select([self._master], [], [], 0)[0]:
                if not os.read(self._master, 4096):
                    return
        except OSError:
            return

    def drop(self) -> None:
        """Close the present client's connection, as when an adapter is unplugged: the client
        sees its link fail; the port goes on listening for the next one (TCP only)."""
        import socket

        conn = getattr(self, "_conn", None)
        if conn is not None:
            try:
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def url(self, node_id: int) -> str:
        if self.kind == "tcp":
            return f"canopen+slcan://{self.host}:{self.port}/{node_id}"
        return f"canopen+slcan://{self.path}/{node_id}"

    def close(self) -> None:
        import os

        self._stop.set()
        for t in self._threads:
            t.join(timeout=1.0)
        if self.bridge is not None:
            self.bridge.close()
            return
        self.listener.close()
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass


def slcan_emulator(bank: ControllerBank, kind: str = "pty", node_id: int = 1, port: int = 0, **kwargs) -> "CanopenEmulator":
    """A :class:`CanopenEmulator` on an SLCAN port (started); ``emulator.url`` is the driver's URL."""
    slcan = SlcanPort(kind, port=port)
    try:
        emulator = CanopenEmulator(bank, slcan.server_path, node_id, "slcan",
                                   bus_options={"sleep_after_open": 0.0, "bitrate": 1000000}, **kwargs)
        emulator.slcan = slcan
        return emulator.start()
    except BaseException:
        slcan.close()
        raise
