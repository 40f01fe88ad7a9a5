"""CANopen CiA 402 driver: one servo drive per axis, through canopen's BaseNode402.

``canopen+virtual://CHANNEL/NODE`` (python-can's virtual bus; the emulator must run in the same
process) or ``canopen+socketcan://can0/NODE``; axis k is node NODE + k. The [driver] table (or
the URL's query) sets ``eds`` (the drive's EDS file; default hsio's object dictionary),
``timeout_s``, ``retries``, ``heartbeat_ms`` and the limits ``stroke_mm``, ``force_kN``,
``velocity_mm_s``.

Start-up, per node: SDO reads of identity, device type (must be CiA 402), scaling (counts per mm,
rated force), software position limits and the emulator-only lockstep flag; PDO configuration
read by SDO (``setup_402_state_machine``); heartbeat on; NMT operational; the CiA 402 state
machine walked to OPERATION ENABLED in cyclic synchronous position mode.

Each controller period: RPDO2 (targets) to every node, one SYNC, and the TPDO2 of every node
(actual position and torque, cycle counter) awaited with a timeout. In lockstep the SYNC is
what advances the emulated drive's clock.

Errors: SDO aborts, EMCY messages, a silent node (no TPDO, no heartbeat) and a restarted node
(boot-up message) become :class:`~hsio.errors.CommunicationError` or
:class:`~hsio.errors.InterlockError` naming the node, the object and the code.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from urllib.parse import parse_qsl, urlsplit

import canopen
from canopen.profiles.p402 import BaseNode402
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from drivers import canopen_od as cod
from hsio.clock import Clock
from hsio.errors import CommunicationError, ConfigError, InterlockError
from hsio.interfaces import Actuator, Channel, ControlMode, DAQ, Feedback, Limits

log = logging.getLogger(__name__)

DEFAULT_OPTIONS = {"eds": "", "timeout_s": 0.5, "retries": 2, "heartbeat_ms": 100, "bitrate": 1000000,
                   "stroke_mm": None, "force_kN": None, "velocity_mm_s": 500.0}
MODE_NAMES = {ControlMode.DISPLACEMENT: "CYCLIC SYNCHRONOUS POSITION", ControlMode.FORCE: "CYCLIC SYNCHRONOUS TORQUE"}
MODE_CODES = {ControlMode.DISPLACEMENT: cod.CSP, ControlMode.FORCE: cod.CST}


def parse_url(url: str, options: dict | None) -> tuple[str, str, int, dict]:
    parts = urlsplit(url)
    interface = parts.scheme.partition("+")[2]
    if parts.scheme.partition("+")[0] != "canopen" or not interface:
        raise ConfigError(f"{url!r} is not a canopen+INTERFACE://CHANNEL/NODE URL")
    channel = parts.hostname or parts.netloc
    if not channel:
        raise ConfigError(f"{url!r}: no channel (expected canopen+{interface}://CHANNEL/NODE)")
    node_text = parts.path.strip("/") or "1"
    try:
        node_id = int(node_text)
    except ValueError:
        raise ConfigError(f"{url!r}: node id {node_text!r} is not a number") from None
    if not 1 <= node_id <= 127:
        raise ConfigError(f"{url!r}: node id {node_id} is not in 1..127")
    table = dict(DEFAULT_OPTIONS)
    given = {**(options or {}), **dict(parse_qsl(parts.query))}
    for key, value in given.items():
        if key not in DEFAULT_OPTIONS:
            raise ConfigError(f"[driver] for {url!r}: unknown key {key!r}; known: {', '.join(DEFAULT_OPTIONS)}")
        if key == "eds":
            table[key] = str(value)
            continue
        try:
            table[key] = None if value is None else (int(value) if key in ("retries", "heartbeat_ms", "bitrate") else float(value))
        except (TypeError, ValueError):
            raise ConfigError(f"[driver] for {url!r}: {key} must be a number, got {value!r}") from None
    if not table["timeout_s"] > 0:
        raise ConfigError(f"[driver] for {url!r}: timeout_s must be positive")
    return interface, channel, node_id, table


def sdo_error(node_id: int, what: str, exc: Exception) -> CommunicationError:
    if isinstance(exc, SdoAbortedError):
        return CommunicationError(f"CANopen node {node_id}: SDO {what} aborted with code 0x{exc.code:08X} ({exc})")
    return CommunicationError(f"CANopen node {node_id}: SDO {what} failed: {exc}")


class DriveNode:
    """One CiA 402 drive (one axis): its BaseNode402, scaling, latest actual values, events."""

    def __init__(self, link: "CanopenLink", node_id: int, od):
        self.link = link
        self.id = node_id
        self.node = BaseNode402(node_id, od)
        link.network.add_node(self.node)
        self.node.sdo.RESPONSE_TIMEOUT = link.options["timeout_s"]
        self.node.sdo.MAX_RETRIES = max(int(link.options["retries"]), 0)
        self.counts_per_mm = float(cod.COUNTS_PER_MM)
        self.rated_N = float(cod.RATED_FORCE_N)
        self.mode = ControlMode.DISPLACEMENT
        self.target_counts = 0
        self.target_torque = 0
        self.halt = False
        self.actual = (0, 0, 0)  # counts, per mille, cycle
        self.received = threading.Event()
        self.status_received = threading.Event()
        self.emcy: list = []
        self.booted = False
        self.identity: dict = {}

    def sdo_read(self, index: int, sub: int = 0, what: str = ""):
        """An SDO upload; an object missing from the local dictionary is read as an unsigned
        integer (so a drive that lacks it answers with its own abort)."""
        try:
            if index in self.node.object_dictionary:
                obj = self.node.sdo[index]
                return (obj[sub] if sub else obj).raw
            return int.from_bytes(self.node.sdo.upload(index, sub), "little")
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise sdo_error(self.id, f"read of {what or hex(index)} (0x{index:04X}:{sub})", exc) from None
        except KeyError:
            raise CommunicationError(f"CANopen node {self.id}: object 0x{index:04X}:{sub} is not in its dictionary") from None

    def sdo_write(self, index: int, value, what: str = ""):
        try:
            self.node.sdo[index].raw = value
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise sdo_error(self.id, f"write of {what or hex(index)} (0x{index:04X}) = {value!r}", exc) from None

    def on_tpdo2(self, can_id, data, timestamp) -> None:
        try:
            self.actual = struct.unpack_from("<ihH", data)
        except struct.error:
            log.warning("node %d: malformed TPDO2 %r", self.id, bytes(data))
            return
        self.received.set()

    def on_emcy(self, error) -> None:
        if error.code:
            self.emcy.append(error)

    def on_bootup(self, can_id, data, timestamp) -> None:
        if data and data[0] == 0:
            self.booted = True

    def check_events(self) -> None:
        if self.booted:
            raise CommunicationError(f"CANopen node {self.id} restarted (boot-up message); its state is lost, the run stops")
        if self.emcy:
            e = self.emcy.pop(0)
            text = cod.EMCY_TEXT.get(e.code, e.get_desc())
            error = InterlockError if e.code in (0x7320, 0x2310, 0x8130, 0x8612) else CommunicationError
            raise error(f"CANopen node {self.id}: EMCY 0x{e.code:04X} ({text}), error register 0x{e.register:02X}")

    def displacement_mm(self) -> float:
        return self.actual[0] / self.counts_per_mm

    def force_kN(self) -> float:
        return self.actual[1] * self.rated_N / 1e6

    def send_targets(self) -> None:
        self.link.network.send_message(0x300 + self.id, struct.pack("<ih", self.target_counts, self.target_torque))

    def send_control(self) -> bool:
        """RPDO1 (controlword with or without halt, mode); True when the drive confirmed it
        with a TPDO1 within the timeout."""
        cw = 0x000F | (0x0100 if self.halt else 0)
        self.node.rpdo_pointers[0x6060].raw = MODE_CODES[self.mode]
        self.status_received.clear()
        self.node.controlword = cw  # RPDO1 (event driven: transmitted at once)
        return self.status_received.wait(self.link.options["timeout_s"])


class CanopenLink:
    """The drives of one controller on one CAN network; the cyclic SYNC exchange."""

    def __init__(self, url: str, n_axes: int, options: dict | None = None):
        self.url = url
        self.interface, self.channel, self.node_id, self.options = parse_url(url, options)
        self.n = n_axes
        self.network = canopen.Network()
        self.lockstep = False
        self.ticks = 0
        self.drives: list[DriveNode] = []
        self.fresh = [False] * n_axes
        self.submitted: set[int] = set()
        self.requests = 0
        self.actuators: list = []

    def open(self, enable: bool = True) -> None:
        kwargs = {"interface": self.interface, "channel": self.channel}
        if self.interface not in ("virtual",):
            kwargs["bitrate"] = self.options["bitrate"]
        try:
            self.network.connect(**kwargs)
        except Exception as exc:
            raise CommunicationError(f"{self.url}: cannot open the CAN bus: {exc}") from None
        eds = self.options["eds"]
        for k in range(self.n):
            node_id = self.node_id + k
            od = eds or cod.object_dictionary(node_id)
            drive = DriveNode(self, node_id, od)
            self.drives.append(drive)
            self.network.subscribe(0x700 + node_id, drive.on_bootup)
            drive.node.emcy.add_callback(drive.on_emcy)
        for drive in self.drives:
            self._start_drive(drive, enable)

    def _start_drive(self, d: DriveNode, enable: bool) -> None:
        device_type = d.sdo_read(0x1000, what="device type")
        if device_type & 0xFFFF != 402:
            raise CommunicationError(f"CANopen node {d.id}: device type 0x{device_type:08X} is not a CiA 402 drive")
        d.identity = {"vendor_id": d.sdo_read(0x1018, 1, "vendor id"), "product_code": d.sdo_read(0x1018, 2, "product code"),
                      "revision": d.sdo_read(0x1018, 3, "revision"), "serial": d.sdo_read(0x1018, 4, "serial number")}
        try:
            d.counts_per_mm = float(d.sdo_read(cod.COUNTS, what="counts per mm"))
        except CommunicationError:
            pass  # a lab drive: the default scaling holds unless [driver] says otherwise
        d.rated_N = float(d.sdo_read(0x6076, what="rated torque (read as rated force, N)"))
        d.limits_counts = (d.sdo_read(0x607D, 1, "min position limit"), d.sdo_read(0x607D, 2, "max position limit"))
        try:
            flag = d.sdo_read(cod.LOCKSTEP_FLAG, what="lockstep flag")
        except CommunicationError as exc:
            if "aborted" not in str(exc):
                raise
            flag = 0
        self.lockstep = bool(flag)
        if self.lockstep:
            self.ticks = d.sdo_read(cod.CLOCK, what="clock")
        if not enable:
            return
        if self.options["heartbeat_ms"]:
            d.sdo_write(0x1017, int(self.options["heartbeat_ms"]), "producer heartbeat time")
        d.node.nmt.state = "PRE-OPERATIONAL"
        try:
            d.node.setup_402_state_machine(read_pdos=True)
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise sdo_error(d.id, "read of the PDO configuration", exc) from None
        self.network.subscribe(0x280 + d.id, d.on_tpdo2)
        d.node.tpdo[1].add_callback(lambda _map, d=d: d.status_received.set())
        d.node.tpdo_values[0x6041] = d.sdo_read(0x6041, what="statusword")
        d.node.tpdo_values[0x6061] = d.sdo_read(0x6061, what="modes of operation display")
        d.node.nmt.state = "OPERATIONAL"
        d.node.rpdo_pointers[0x6060].raw = cod.CSP
        if d.node.state == "FAULT":
            d.node.reset_from_fault()
        # Start from where the axis stands.
        d.target_counts = d.sdo_read(0x6064, what="position actual value")
        d.target_torque = d.sdo_read(0x6077, what="torque actual value")
        d.send_targets()
        try:
            d.node.state = "OPERATION ENABLED"
        except RuntimeError as exc:
            raise CommunicationError(f"CANopen node {d.id}: could not reach OPERATION ENABLED ({exc}); "
                                     f"state {d.node.state}, statusword 0x{d.node.statusword:04X}") from None
        mode = d.sdo_read(0x6061, what="modes of operation display")
        if mode != cod.CSP:
            raise CommunicationError(f"CANopen node {d.id}: mode {mode} after asking for cyclic synchronous position (8)")
        d.check_events()

    # -- cyclic exchange -----------------------------------------------------------------------
    def submit(self, axis: int) -> None:
        self.submitted.add(axis)
        if not self.lockstep and len(self.submitted) == self.n:
            self.exchange()

    def advance(self, ticks: int) -> None:
        for _ in range(int(ticks)):
            self.exchange()

    def exchange(self) -> None:
        """Targets to every drive, one SYNC, and every drive's TPDO2 back (with retries)."""
        self.submitted.clear()
        expected = (self.ticks + 1) & 0xFFFF
        timeout = self.options["timeout_s"]
        for attempt in range(int(self.options["retries"]) + 1):
            if attempt and self.lockstep:
                try:  # did the last SYNC arrive? then only its TPDO was lost
                    clock = self.drives[0].sdo_read(cod.CLOCK, what="clock")
                    if clock == self.ticks + 1:
                        for d in self.drives:
                            d.actual = (d.sdo_read(0x6064), d.sdo_read(0x6077), clock & 0xFFFF)
                        break
                except CommunicationError:
                    continue
            for d in self.drives:
                d.received.clear()
                d.check_events()
                d.send_targets()
            self.network.sync.transmit()
            self.requests += 1
            deadline = time.monotonic() + timeout
            if all(d.received.wait(max(deadline - time.monotonic(), 0.0)) for d in self.drives):
                break
        else:
            silent = [d.id for d in self.drives if not d.received.is_set()]
            beat = ", ".join(f"node {d.id}: last heartbeat {self._heartbeat_age(d)}" for d in self.drives if d.id in silent)
            raise CommunicationError(f"{self.url}: no TPDO from node(s) {silent} within {timeout:g} s after "
                                     f"{int(self.options['retries']) + 1} SYNC(s) ({beat})")
        if self.lockstep:
            self.ticks += 1
            for d in self.drives:
                if d.actual[2] != expected:
                    raise CommunicationError(f"CANopen node {d.id}: cycle {d.actual[2]}, expected {expected} (lockstep lost)")
        for d in self.drives:
            d.check_events()
        self.fresh = [True] * self.n

    def _heartbeat_age(self, d: DriveNode) -> str:
        ts = getattr(d.node.nmt, "timestamp", None)
        return "never" if not ts else f"{time.time() - ts:.2f} s ago"

    def close(self) -> None:
        try:
            self.network.disconnect()
        except Exception:
            pass


class CanopenActuator(Actuator, DAQ):
    """One axis: a CiA 402 drive on a :class:`CanopenLink`."""

    def __init__(self, name: str, link: CanopenLink, axis: int, limits: Limits):
        self.name = name
        self.link = link
        self.axis = axis
        self.drive = link.drives[axis]
        self.limits = limits
        self._closed = False

    @property
    def mode(self) -> ControlMode:
        return self.drive.mode

    def set_mode(self, mode: ControlMode) -> None:
        d = self.drive
        if mode is d.mode:
            return
        fb = self.feedback()
        d.target_counts = int(round(fb.displacement_mm * d.counts_per_mm))
        d.target_torque = int(round(fb.force_kN * 1e6 / d.rated_N))
        d.send_targets()
        d.mode = mode
        d.node.op_mode = MODE_NAMES[mode]  # logs rather than raises on failure: check 0x6061
        shown = d.sdo_read(0x6061, what="modes of operation display")
        if shown != MODE_CODES[mode]:
            raise CommunicationError(f"CANopen node {d.id}: mode display {shown} after asking for {MODE_CODES[mode]}")

    def _send(self, value: float) -> None:
        d = self.drive
        d.check_events()
        if d.halt:
            d.halt = False
            d.send_control()
        if d.mode is ControlMode.DISPLACEMENT:
            d.target_counts = int(round(value * d.counts_per_mm))
        else:
            d.target_torque = int(round(value * 1e6 / d.rated_N))
        self.link.submit(self.axis)

    def feedback(self) -> Feedback:
        link = self.link
        if not link.fresh[self.axis] and not link.lockstep:
            self.drive.received.clear()
            link.exchange()
        link.fresh[self.axis] = False
        t = link.ticks / 1024.0 if link.lockstep else time.monotonic()
        return Feedback(self.drive.displacement_mm(), self.drive.force_kN(), t)

    def hold(self) -> None:
        """Halt (controlword bit 8): the drive holds its position in position control."""
        d = self.drive
        d.halt = True
        d.mode = ControlMode.DISPLACEMENT
        if not d.send_control():
            raise CommunicationError(f"CANopen node {d.id}: no confirmation of the halt within {self.link.options['timeout_s']:g} s")

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self.hold()
        finally:
            if all(a._closed for a in self.link.actuators):
                self.link.close()

    @property
    def channels(self) -> tuple[Channel, ...]:
        return (Channel(f"{self.name}.displacement", "mm"), Channel(f"{self.name}.force", "kN"))

    def read(self) -> dict[str, float]:
        fb = self.feedback()
        return {f"{self.name}.displacement": fb.displacement_mm, f"{self.name}.force": fb.force_kN}


def open_link(url: str, names: list[str], clock: Clock | None, options: dict | None = None,
              enable: bool = True) -> list[CanopenActuator]:
    """Open the drives and return one actuator per axis; ``clock=None`` skips the clock check."""
    link = CanopenLink(url, len(names), options)
    try:
        link.open(enable)
    except BaseException:
        link.close()
        raise
    opts = link.options
    d0 = link.drives[0]
    stroke = opts["stroke_mm"] if opts["stroke_mm"] is not None else (d0.limits_counts[1] - d0.limits_counts[0]) / d0.counts_per_mm
    force = opts["force_kN"] if opts["force_kN"] is not None else 250.0
    limits = Limits(stroke or 254.0, force, opts["velocity_mm_s"])
    actuators = [CanopenActuator(name, link, k, limits) for k, name in enumerate(names)]
    link.actuators = actuators
    if clock is None:
        return actuators
    lockstep_clock = clock is not None and getattr(clock, "lockstep", False)
    if link.lockstep != lockstep_clock:
        link.close()
        want = "lockstep" if link.lockstep else "realtime"
        raise ConfigError(f"{url}: the drive's clock is {'lockstep' if link.lockstep else 'real time'} but the experiment's "
                          f"is not; set [hardware] clock = \"{want}\"")
    if link.lockstep:
        clock.attach(link)
    return actuators


def open_url(url: str, elements, clock: Clock, options: dict | None = None) -> list[Actuator]:
    """``canopen+virtual://CHANNEL/NODE``: one CiA 402 drive per experimental element."""
    return open_link(url, [e.name for e in elements], clock, options)
