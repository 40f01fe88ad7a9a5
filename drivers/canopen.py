"""CANopen CiA 402 driver: one servo drive per axis, through canopen's BaseNode402.

``canopen+virtual://CHANNEL/NODE`` (python-can's virtual bus; the emulator must run in the same
process), ``canopen+socketcan://can0/NODE``, or a Lawicel (SLCAN) adapter:
``canopen+slcan:///dev/ttyACM0/NODE`` (a serial device or pseudo-terminal) or
``canopen+slcan://127.0.0.1:PORT/NODE`` (a TCP serial port, pyserial's socket://); axis k is node
NODE + k (docs/canopen.md). The [driver] table (or
the URL's query) sets ``eds`` (the drive's EDS file; default hsio's object dictionary),
``timeout_s``, ``retries``, ``reconnect_delay_s``, ``heartbeat_ms`` and the limits ``stroke_mm``, ``force_kN``,
``velocity_mm_s``; the stroke and force capacity default to the drive's own (0x607D, 0x6072 x
0x6076), never to a guess, and a configured one may be tighter than the drive's, never wider.

Start-up, per node: SDO reads of identity, device type (must be CiA 402), scaling (counts per mm,
rated force), software position limits, max torque and the emulator-only lockstep flag; then,
once the limits and the clock are checked, per node: PDO configuration
read by SDO (``setup_402_state_machine``); heartbeat on; NMT operational; the CiA 402 state
machine walked to OPERATION ENABLED in cyclic synchronous position mode.

Each controller period: RPDO2 (targets) to every node, one SYNC, and the TPDO2 of every node
(actual position and torque, cycle counter) awaited with a timeout. In lockstep the SYNC is
what advances the emulated drive's clock.

A bus that fails (an SLCAN adapter's TCP link closed) is opened again within ``retries`` attempts
(``reconnect_delay_s`` x attempt apart), the drives checked by SDO before the run goes on
(:meth:`CanopenLink.recover`); one that does not come back stops the run (:class:`LinkLostError`).

Errors: SDO aborts, EMCY messages, a silent node (no TPDO, no heartbeat) and a restarted node
(boot-up message) become :class:`~hsio.errors.CommunicationError` or
:class:`~hsio.errors.InterlockError` naming the node, the object and the code. A failure while
opening disables (halt, disable operation) every drive that may have been enabled.

EMCY policy (docs/canopen.md, "EMCY"): an EMCY stops the run, unless it is a warning: its code
is of the temperature class (0x4xxx) or listed in [driver] ``emcy_warnings``, and the drive's
statusword, read by SDO when the EMCY is handled, shows OPERATION ENABLED with no fault. A
warning is printed once per node and code (and counted in :attr:`DriveNode.warnings`); the run
goes on, and the statusword check of every period still stops it if the drive then faults.

Mode confirmation: after a switch of the mode of operation 0x6060 the mode display 0x6061 must
show it (canopen's setter waits ``timeout_s`` for it, then an SDO read decides), and in
OPERATION ENABLED every TPDO1 mode display must be the commanded mode; otherwise the run stops
with an :class:`~hsio.errors.InterlockError` naming the actuator, the requested and the shown mode.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from pathlib import Path
from urllib.parse import urlsplit

import can
import canopen
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from hsio.drivers import canopen_od as cod
from hsio.drivers import common
from hsio.drivers.canopen_sdo import MatchingNode402
from hsio.clock import Clock
from hsio.errors import (CommunicationError, ConfigError, ControllerRestartedError, InterlockError, LimitError,
                         SdoAbortError)
from hsio.interfaces import Actuator, ActuatorChannels, ControlMode, Feedback, Limits

log = logging.getLogger(__name__)
# canopen reports lost SDO responses, client aborts and a stopped receive thread on its own
# logger; the driver retries and names each failure itself (the node, the object, the bus), so
# those reports stay out of a terminal unless logging is configured.
logging.getLogger("canopen").addHandler(logging.NullHandler())

DEFAULT_OPTIONS = {"eds": "", "emcy_warnings": "", "timeout_s": 0.5, "retries": 2, "reconnect_delay_s": 0.1,
                   "heartbeat_ms": 100, "bitrate": 1000000,
                   "stroke_mm": None, "force_kN": None, "velocity_mm_s": 500.0, "counts_per_mm": None,
                   **common.PLAUSIBILITY_DEFAULTS}
MODE_NAMES = {ControlMode.DISPLACEMENT: "CYCLIC SYNCHRONOUS POSITION", ControlMode.FORCE: "CYCLIC SYNCHRONOUS TORQUE"}
MODE_CODES = {ControlMode.DISPLACEMENT: cod.CSP, ControlMode.FORCE: cod.CST}
CODE_MODES = {code: mode for mode, code in MODE_CODES.items()}
WARNING_CLASSES = (0x4000,)  # EMCY code classes (code & 0xF000) that may be warnings: temperature
RULES = {
    **common.COMMON_RULES,
    "heartbeat_ms": common.whole(0, 65535),
    "bitrate": common.Rule(int, 10_000, 1_000_000, False, "a CAN bit rate in 10000..1000000 bit/s"),
    "counts_per_mm": common.Rule(float, 1e-3, 1e9, False, "between 0.001 and 1e9 counts per mm"),
    **common.PLAUSIBILITY_RULES,
}
SCALING_TOLERANCE = 1e-6  # relative: a configured counts_per_mm within 1 ppm of the drive's figure is the same
COUNTS_MAX = 2**31 - 1  # the target and actual positions 0x607A, 0x6064 are int32 counts
PERMILLE_MAX = 32767  # the CiA 402 torque objects are int16, per mille of the rated value 0x6076
BUS_POLL_S = 0.01  # while awaiting the TPDOs, how often a failed bus is looked for


def parse_url(url: str, options: dict | None) -> tuple[str, str, int, dict]:
    parts = common.split_url(url)
    interface = parts.scheme.partition("+")[2]
    if parts.scheme.partition("+")[0] != "canopen" or not interface:
        raise ConfigError(f"{url!r} is not a canopen+INTERFACE://CHANNEL/NODE URL")
    if interface == "slcan":  # a Lawicel adapter: a serial device path, or a TCP serial port (docs/canopen.md)
        if parts.netloc:
            if common.url_port(url, 0) == 0:
                raise ConfigError(f"{url!r}: an SLCAN adapter on TCP needs a port: canopen+slcan://HOST:PORT/NODE")
            channel, node_text = f"socket://{parts.netloc}", parts.path.strip("/") or "1"
        else:
            device, _, node_text = parts.path.rstrip("/").rpartition("/")
            channel = device
            if not device or not node_text:
                raise ConfigError(f"{url!r}: expected canopen+slcan:///dev/ttyXXX/NODE or canopen+slcan://HOST:PORT/NODE")
    else:
        channel = parts.hostname or parts.netloc
        node_text = parts.path.strip("/") or "1"
    if not channel:
        raise ConfigError(f"{url!r}: no channel (expected canopen+{interface}://CHANNEL/NODE)")
    try:
        node_id = int(node_text)
    except ValueError:
        raise ConfigError(f"{url!r}: node id {node_text!r} is not a number") from None
    if not 1 <= node_id <= 127:
        raise ConfigError(f"{url!r}: node id {node_id} is not in 1..127")
    table = common.parse_options(url, options, DEFAULT_OPTIONS, RULES)
    if table["eds"] and not Path(table["eds"]).is_file():
        raise ConfigError(f"[driver] for {url!r}: eds = {table['eds']!r} is not a readable file (the drive's EDS)")
    table["emcy_warnings"] = parse_emcy_codes(url, table["emcy_warnings"])
    return interface, channel, node_id, table


def parse_emcy_codes(url: str, text) -> frozenset[int]:
    """[driver] emcy_warnings: the EMCY codes the lab's drive sends as warnings, a string of codes
    separated by commas or spaces ("0x4310, 0xFF01"); each in 0x0100..0xFFFF."""
    if isinstance(text, frozenset):
        return text
    codes = set()
    for item in str(text).replace(",", " ").split():
        try:
            codes.add(common.emcy_code(item))
        except ValueError as exc:
            raise ConfigError(f"[driver] for {url!r}: emcy_warnings: {exc}; give the codes as a string such as "
                              "\"0x4310, 0xFF01\"") from None
    return frozenset(codes)


def check_options(url: str, options: dict | None = None) -> None:
    """The URL and the [driver] table checked before anything opens (hsio.hardware.check_options)."""
    parse_url(url, options)


def input_files(url: str, options: dict | None = None) -> list[tuple[str, Path]]:
    """The drive's EDS the link reads when it opens (``eds``; none for hsio's own object dictionary)."""
    eds = common.parse_options(url, options, DEFAULT_OPTIONS, RULES)["eds"]
    return [("[driver] eds", Path(eds))] if eds else []


def sdo_error(node_id: int, what: str, exc: Exception) -> CommunicationError:
    if isinstance(exc, SdoAbortedError):
        return SdoAbortError(f"CANopen node {node_id}: SDO {what} aborted with code 0x{exc.code:08X} ({exc})", exc.code)
    if isinstance(exc, can.CanError):
        return bus_error(f"CANopen node {node_id}", f"the SDO {what}", exc)
    return CommunicationError(f"CANopen node {node_id}: SDO {what} failed: {exc}")


class LinkLostError(CommunicationError):
    """The CAN bus failed and did not come back within the reconnection budget ([driver]
    ``retries`` attempts, ``reconnect_delay_s`` x attempt apart): the run stops."""


def bus_error(where: str, what: str, exc: BaseException) -> CommunicationError:
    """The CAN bus itself failed (an adapter unplugged, the TCP link of an SLCAN adapter closed):
    a link fault, named with python-can's reason and the one beneath it."""
    cause = f": {exc.__cause__}" if exc.__cause__ is not None else ""
    return CommunicationError(f"{where}: the CAN bus failed during {what} ({exc}{cause}); the adapter or its "
                              "link is lost")


class BusWatch(can.Listener):
    """Notes the first error of the bus's receive thread (python-can's Notifier), which would
    otherwise end that thread with a traceback on the terminal; the exchange raises it as a
    :class:`~hsio.errors.CommunicationError`. The Notifier calls ``recv`` again after a handled
    error, so each report waits a little: a dead adapter does not spin a core."""

    RETRY_S = 0.05

    def __init__(self):
        self.error: BaseException | None = None

    def on_message_received(self, msg) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        self.note(exc)
        log.debug("CAN bus receive error: %r", exc)
        time.sleep(self.RETRY_S)

    def note(self, exc: BaseException) -> None:
        """The bus failed (its first error is kept until the link is made again)."""
        if self.error is None:
            self.error = exc

    def stop(self) -> None:
        pass


class DriveNode:
    """One CiA 402 drive (one axis): its BaseNode402, scaling, latest actual values, events."""

    def __init__(self, link: "CanopenLink", node_id: int, od):
        self.link = link
        self.id = node_id
        self.node = MatchingNode402(node_id, od)  # SDO answers taken for the request in flight only
        link.network.add_node(self.node)
        self.node.sdo.RESPONSE_TIMEOUT = link.options["timeout_s"]
        # canopen counts attempts: MAX_RETRIES 1 is one request, and 0 would wait for ever on a silent node
        self.node.sdo.MAX_RETRIES = max(int(link.options["retries"]), 0) + 1
        self.node.TIMEOUT_SWITCH_OP_MODE = link.options["timeout_s"]  # canopen's wait for the mode display
        self.counts_per_mm = float(cod.COUNTS_PER_MM)
        self.rated_N = float(cod.RATED_FORCE_N)
        self.mode = ControlMode.DISPLACEMENT
        self.target_counts = 0
        self.target_torque = 0
        self.halt = False
        self.actual = (0, 0, 0)  # counts, per mille, cycle
        self.expected_cycle: int | None = None  # lockstep: the cycle the awaited TPDO2 carries
        self.stale = 0  # TPDO2 frames of an earlier cycle (a repeated frame), not taken
        self.received = threading.Event()
        # One awaited cycle at a time: the notifier thread's (check the cycle, take, signal) and
        # the exchange's (expect the next cycle, clear) never interleave.
        self.cycle_lock = threading.Lock()
        self.status_received = threading.Event()
        self.emcy: list = []
        self.warnings: dict[int, int] = {}  # EMCY code -> how many were taken as warnings
        self.last_warning: tuple[int, float] | None = None  # the last EMCY taken as a warning: code, when (monotonic)
        self.booted = False
        self.identity: dict = {}
        self.max_torque_permille: int | None = None
        self.limits_counts = (0, 0)
        self.watchdog_s = 0.0  # host watchdog time (0x2103, where the drive has it; 0: off or unknown)
        self.enabling = False  # set once the drive may be enabled: a failure must disable it
        self.operating = False  # taken to OPERATION ENABLED by the driver: it must stay there

    def sdo_read(self, index: int, sub: int = 0, what: str = ""):
        """An SDO upload; an object missing from the local dictionary is read as an unsigned
        integer (so a drive that lacks it answers with its own abort)."""
        def read():
            if index in self.node.object_dictionary:
                obj = self.node.sdo[index]
                return (obj[sub] if sub else obj).raw
            return int.from_bytes(self.node.sdo.upload(index, sub), "little")

        try:
            return self._sdo(f"the SDO read of 0x{index:04X}:{sub} from node {self.id}", read)
        except (SdoAbortedError, SdoCommunicationError, can.CanError) as exc:
            raise sdo_error(self.id, f"read of {what or hex(index)} (0x{index:04X}:{sub})", exc) from None
        except KeyError:
            raise CommunicationError(f"CANopen node {self.id}: object 0x{index:04X}:{sub} is not in its dictionary") from None

    def sdo_write(self, index: int, value, what: str = ""):
        try:
            self._sdo(f"the SDO write of 0x{index:04X} to node {self.id}", lambda: setattr(self.node.sdo[index], "raw", value))
        except (SdoAbortedError, SdoCommunicationError, can.CanError) as exc:
            raise sdo_error(self.id, f"write of {what or hex(index)} (0x{index:04X}) = {value!r}", exc) from None

    def _sdo(self, what: str, transfer):
        """One SDO transfer; a bus that failed before or under it is reconnected (within the
        budget, :meth:`CanopenLink.recover`) and the transfer made once more: a read, and a write
        of an absolute value, may be repeated."""
        self.link.check_bus(what)
        try:
            return transfer()
        except (SdoCommunicationError, can.CanError) as exc:
            if isinstance(exc, can.CanError):
                self.link.bus_watch.note(exc)
            if self.link.bus_watch.error is None or self.link.recovering:
                raise  # no answer on a working bus, or a failure within a reconnection (one failed attempt)
        self.link.check_bus(what)  # the bus failed under the transfer: made again (or LinkLostError)
        return transfer()

    def take_pdos(self) -> None:
        """RPDO2 and TPDO2 as the drive maps them (read from its 0x1601 / 0x1A01 over SDO): the
        targets and actual values are set and read through canopen's PDO maps, by object."""
        self.rpdo2, self.tpdo2 = self.node.rpdo[2], self.node.tpdo[2]
        for name, pdo, needed in (("RPDO2", self.rpdo2, (0x607A, 0x6071)), ("TPDO2", self.tpdo2, (0x6064, 0x6077))):
            mapped = {v.index for v in pdo.map}
            missing = [f"0x{i:04X}" for i in needed if i not in mapped]
            if missing:
                raise CommunicationError(f"CANopen node {self.id}: {name} does not map {', '.join(missing)} "
                                         "(docs/canopen.md)")
        self.cycle_mapped = cod.CYCLE in {v.index for v in self.tpdo2.map}
        if self.link.lockstep and not self.cycle_mapped:
            raise CommunicationError(f"CANopen node {self.id}: TPDO2 does not map the cycle counter 0x{cod.CYCLE:04X}, "
                                     "which a lockstep drive's reply must carry (docs/canopen.md)")
        self.tpdo2.add_callback(self.on_tpdo2)

    def on_tpdo2(self, pdo) -> None:
        """The actual values of one SYNC. In lockstep only the frame of the awaited cycle is an
        answer: a repeated frame of the cycle before (it may arrive after the next SYNC went out)
        is dropped, so it cannot pass for the next cycle's reply."""
        try:
            if len(pdo.data) < self.tpdo2_length:
                raise ValueError(f"{len(pdo.data)} bytes, the mapping has {self.tpdo2_length}")
            actual = (pdo[0x6064].raw, pdo[0x6077].raw, pdo[cod.CYCLE].raw if self.cycle_mapped else 0)
        except Exception as exc:  # a malformed frame is not an answer: the exchange retries
            log.warning("node %d: malformed TPDO2 %r (%s)", self.id, bytes(pdo.data), exc)
            return
        with self.cycle_lock:
            expected = self.expected_cycle
            if expected is not None and self.cycle_mapped and actual[2] != expected:
                self.stale += 1
                log.debug("node %d: TPDO2 of cycle %d while awaiting %d (a repeated frame): dropped",
                          self.id, actual[2], expected)
                return
            self.actual = actual
            self.received.set()

    def await_cycle(self, expected: int | None) -> None:
        """Before a SYNC: the TPDO2 to take is the one of cycle ``expected`` (None: any frame).
        Under the lock of :meth:`on_tpdo2`, so a frame checked against the previous expectation
        cannot signal after this clear."""
        with self.cycle_lock:
            self.expected_cycle = expected
            self.received.clear()

    @property
    def tpdo2_length(self) -> int:
        return sum(v.length for v in self.tpdo2.map) // 8

    def on_emcy(self, error) -> None:
        if error.code:
            self.emcy.append(error)

    def on_bootup(self, can_id, data, timestamp) -> None:
        if data and data[0] == 0:
            self.booted = True

    def check_events(self) -> None:
        if self.booted:
            raise ControllerRestartedError(f"CANopen node {self.id} restarted (boot-up message); its state is lost, the run stops")
        while self.emcy:
            e = self.emcy.pop(0)
            text = cod.EMCY_TEXT.get(e.code, e.get_desc())
            what = f"CANopen node {self.id}: EMCY 0x{e.code:04X} ({text}), error register 0x{e.register:02X}"
            word = self._warning_statusword(e.code)
            if word is None:
                raise (InterlockError if is_drive_fault(e.code) else CommunicationError)(what)
            self.warnings[e.code] = self.warnings.get(e.code, 0) + 1
            self.last_warning = (e.code, time.monotonic())
            if self.warnings[e.code] == 1:
                log.warning("%s: a warning: the drive stays OPERATION ENABLED with no fault (statusword 0x%04X); the run "
                            "goes on (further EMCY 0x%04X from node %d are counted, not printed)",
                            what, word, e.code, self.id)
        word = self.node.tpdo_values.get(0x6041)
        if self.operating and word is not None and word & 0x6F != 0x27:
            emcy = "without an EMCY"
            if self.last_warning is not None:
                code, when = self.last_warning
                emcy += (f" (its last EMCY, 0x{code:04X}, {time.monotonic() - when:.1f} s earlier, was taken as a "
                         "warning while the drive showed itself enabled)")
            raise InterlockError(f"CANopen node {self.id} left OPERATION ENABLED (statusword 0x{word:04X}, "
                                 f"{self.node.state}) {emcy}: it no longer follows its targets")
        shown = self.node.tpdo_values.get(0x6061)
        if self.operating and shown is not None and shown != MODE_CODES[self.mode]:
            raise InterlockError(f"CANopen node {self.id}: mode display 0x6061 shows {mode_name(shown)} while the driver "
                                 f"commands {mode_name(MODE_CODES[self.mode])}: the drive changed its mode of operation "
                                 "on its own; the run stops")

    def _warning_statusword(self, code: int) -> int | None:
        """The statusword that makes an EMCY of ``code`` a warning, or None (the EMCY stops the
        run): its class is a warning class or the lab lists it ([driver] emcy_warnings), and the
        drive is in OPERATION ENABLED with the fault bit clear: asked by SDO at the code's first
        EMCY, read from the cyclic statusword (TPDO) at the next ones of the same code, so that a
        drive repeating a warning costs no SDO round trip in the loop's periods."""
        if code & 0xF000 not in WARNING_CLASSES and code not in self.link.options["emcy_warnings"]:
            return None
        if not self.operating:
            return None
        cyclic = self.node.tpdo_values.get(0x6041)
        if code in self.warnings and cyclic is not None:
            return cyclic if cyclic & 0x6F == 0x27 and not cyclic & 0x08 else None
        try:
            word = int(self.sdo_read(0x6041, what="statusword (after an EMCY)"))
        except CommunicationError:
            return None  # its state unknown: a fault until shown otherwise
        return word if word & 0x6F == 0x27 and not word & 0x08 else None

    def displacement_mm(self) -> float:
        return self.actual[0] / self.counts_per_mm

    def force_kN(self) -> float:
        return self.actual[1] * self.rated_N / 1e6

    def permille(self, kN: float) -> int:
        """A force as the int16 torque objects carry it (per mille of the rated force)."""
        value = int(round(kN * 1e6 / self.rated_N))
        if not -PERMILLE_MAX - 1 <= value <= PERMILLE_MAX:
            raise LimitError(f"CANopen node {self.id}: force {kN:.3f} kN is {value} per mille of the rated force "
                             f"{self.rated_N / 1e3:g} kN (0x6076), beyond the int16 range; not sent")
        return value

    def limits(self, url: str, options: dict):
        """[driver] stroke_mm / force_kN where set, else the drive's own: the software position
        limits 0x607D and the max torque 0x6072 (per mille of the rated torque 0x6076, read as
        newtons). A configured limit wider than the drive's is refused (a tighter one is a
        software limit inside the drive's). Asymmetric position limits give the smaller
        half-range on either side of zero; a force capacity the int16 torque objects cannot
        carry is refused."""
        lo, hi = self.limits_counts
        where = f"{url} node {self.id}"
        stroke, stroke_why = None, " (0x607D software position limits are 0/0: none set)"
        stroke_from = f" (its software position limits 0x607D, {lo / self.counts_per_mm:g}..{hi / self.counts_per_mm:g} mm)"
        if (lo, hi) != (0, 0):
            if not lo < 0 < hi:
                raise ConfigError(f"{where}: software position limits 0x607D {lo}..{hi} counts do not contain zero; "
                                  "hsio's stroke is centred on zero: set the drive's limits around the neutral position")
            stroke = 2.0 * min(-lo, hi) / self.counts_per_mm
            if -lo != hi and options["stroke_mm"] is None:
                log.warning("%s: asymmetric software position limits %.3f..%.3f mm; using +/-%.3f mm", where,
                            lo / self.counts_per_mm, hi / self.counts_per_mm, stroke / 2)
        force = None if self.max_torque_permille is None else self.max_torque_permille * self.rated_N / 1e6
        limits = common.resolve_limits(where, options, stroke, force, stroke_why, " (no max torque 0x6072)",
                                       stroke_from, " (its max torque 0x6072 x rated torque 0x6076)")
        reach = COUNTS_MAX / self.counts_per_mm
        if limits.half_stroke_mm > reach:
            key = "[driver] stroke_mm" if options["stroke_mm"] is not None else "0x607D"
            raise ConfigError(f"{where}: the half stroke {limits.half_stroke_mm:g} mm ({key}) at {self.counts_per_mm:g} "
                              f"counts per mm is beyond what the int32 target position 0x607A carries ({COUNTS_MAX} "
                              f"counts = {reach:.6g} mm); check [driver] counts_per_mm or the drive's position factor")
        top = PERMILLE_MAX * self.rated_N / 1e6
        if limits.force_kN > top:
            key = "[driver] force_kN" if options["force_kN"] is not None else "the max torque 0x6072"
            raise ConfigError(f"{where}: force capacity {limits.force_kN:g} kN ({key}) is beyond what the int16 torque "
                              f"objects carry: {PERMILLE_MAX} per mille of the rated force {self.rated_N / 1e3:g} kN "
                              f"(0x6076) = {top:g} kN; set [driver] force_kN <= {top:g}")
        return limits

    def send_targets(self) -> None:
        """RPDO2 through canopen's PDO map: target position 0x607A, target torque 0x6071."""
        self.rpdo2[0x607A].raw = self.target_counts
        self.rpdo2[0x6071].raw = self.target_torque
        self.link.transmit(f"the RPDO2 to node {self.id}", self.rpdo2.transmit)

    def send_control(self) -> bool:
        """RPDO1 (controlword with or without halt, mode); True when the drive confirmed it
        with a TPDO1 within the timeout."""
        cw = 0x000F | (0x0100 if self.halt else 0)
        self.node.rpdo_pointers[0x6060].raw = MODE_CODES[self.mode]
        self.status_received.clear()
        # RPDO1 (event driven: transmitted at once); an absolute controlword may be sent again
        self.link.transmit(f"the RPDO1 to node {self.id}", lambda: setattr(self.node, "controlword", cw))
        return self.status_received.wait(self.link.options["timeout_s"])


class CanopenLink(common.AxisLink):
    """The drives of one controller on one CAN network; the cyclic SYNC exchange."""

    def __init__(self, url: str, n_axes: int, options: dict | None = None):
        self.url = url
        self.interface, self.channel, self.node_id, self.options = parse_url(url, options)
        if self.node_id + n_axes - 1 > 127:
            raise ConfigError(f"{url!r}: {n_axes} axes are nodes {self.node_id}..{self.node_id + n_axes - 1}, beyond "
                              "the CANopen node ids 1..127 (axis k is node NODE + k); start at node "
                              f"{128 - n_axes} or lower")
        self.n = n_axes
        self.network = canopen.Network()
        self.lockstep = False
        self.ticks = 0
        self.drives: list[DriveNode] = []
        self.fresh = [False] * n_axes
        self.submitted: set[int] = set()
        self.requests = 0
        self.reconnects = 0  # links made again after the bus failed
        self.recovering = False  # within recover(): a failure there is one failed attempt, not a new recovery
        self.actuators: list = []
        self.bus_watch = BusWatch()
        self.network.listeners.append(self.bus_watch)

    @contextlib.contextmanager
    def bus(self, what: str):
        """Around a transmission: a bus that failed (now, or in the receive thread before) is a
        :class:`~hsio.errors.CommunicationError` naming it."""
        self.check_bus(what)
        try:
            yield
        except can.CanError as exc:
            raise bus_error(self.url, what, exc) from None

    def check_bus(self, what: str) -> None:
        """Before a transmission or an SDO transfer: a bus that failed is reconnected within the
        budget (:meth:`recover`), or the run stops with :class:`LinkLostError`."""
        if self.bus_watch.error is not None:
            if self.recovering:
                raise bus_error(self.url, what, self.bus_watch.error)
            self.recover(what, self.bus_watch.error)

    def transmit(self, what: str, send) -> None:
        """A frame that may be sent again (absolute targets, a controlword): after a bus failure
        the link is made again (:meth:`check_bus`) and the frame sent once more."""
        for attempt in range(2):
            self.check_bus(what)
            try:
                send()
                return
            except can.CanError as exc:
                self.bus_watch.note(exc)
                if attempt or self.recovering:
                    raise bus_error(self.url, what, exc) from None

    def recover(self, what: str, error: BaseException) -> None:
        """The bus failed during ``what``: close it and open it again, up to ``retries`` times,
        ``reconnect_delay_s`` x attempt apart (as the Modbus driver reconnects), then check that
        every drive is as it was left: the lockstep clock not gone back (a restart, whose boot-up
        went with the link) and, for a drive taken to OPERATION ENABLED, its statusword still
        there with the commanded mode (an EMCY sent while the link was down is lost with it; a
        trip shows as FAULT). A drive that is not stops the run; a link that does not come back
        raises :class:`LinkLostError` naming the first failure and the last attempt's. The step in
        flight is settled by the exchange (:meth:`exchange`: the drive's clock tells whether its
        SYNC arrived)."""
        lost = bus_error(self.url, what, error)
        retries, delay = int(self.options["retries"]), self.options["reconnect_delay_s"]
        if retries == 0:
            raise LinkLostError(f"{lost} (no reconnection: [driver] retries = 0)")
        started, last = time.monotonic(), ""
        self.recovering = True
        try:
            for attempt in range(1, retries + 1):
                self.reconnects += 1
                self._disconnect()
                time.sleep(delay * attempt)
                try:
                    self._connect()
                    self._check_drives_after_reconnect()
                except (ControllerRestartedError, InterlockError):
                    raise
                except CommunicationError as exc:
                    last = f"attempt {attempt}: {exc}"
                    continue
                log.warning("%s; reconnected (attempt %d of %d, %.2f s)", lost, attempt, retries,
                            time.monotonic() - started)
                return
        finally:
            self.recovering = False
        raise LinkLostError(f"{lost}; not reconnected after {retries} attempt(s) in {time.monotonic() - started:.2f} s "
                            f"(last: {last})")

    def _check_drives_after_reconnect(self) -> None:
        if self.lockstep and self.drives:
            clock = self.drives[0].sdo_read(cod.CLOCK, what="clock (after the link was made again)")
            if clock < self.ticks:
                raise ControllerRestartedError(
                    f"{self.url}: after the link was lost, the drive's clock reads {clock}, behind the {self.ticks} "
                    "periods already run: it restarted (its boot-up message went with the link); its state is lost, "
                    "the run stops")
        for d in self.drives:
            if not d.operating:
                continue
            word = int(d.sdo_read(0x6041, what="statusword (after the link was made again)"))
            d.node.tpdo_values[0x6041] = word
            if word & 0x6F != 0x27:
                raise InterlockError(
                    f"CANopen node {d.id} is no longer OPERATION ENABLED after the link was lost (statusword "
                    f"0x{word:04X}): it tripped or restarted while the link was down (an EMCY or boot-up message "
                    "sent then went with the link); it no longer follows its targets, the run stops")
            shown = int(d.sdo_read(0x6061, what="modes of operation display (after the link was made again)"))
            d.node.tpdo_values[0x6061] = shown
            if shown != MODE_CODES[d.mode]:
                raise InterlockError(
                    f"CANopen node {d.id}: after the link was lost, the mode display 0x6061 shows {mode_name(shown)} "
                    f"while the driver commands {mode_name(MODE_CODES[d.mode])}; the run stops")

    def _connect(self) -> None:
        try:
            self.network.connect(**self._bus_options)
        except Exception as exc:
            self.network.bus = None
            raise CommunicationError(f"{self.url}: cannot open the CAN bus: {exc}") from None

    def _disconnect(self) -> None:
        """Close the bus; one whose link is gone may fail its own shutdown (an adapter's close
        command cannot be written), so its port is closed here, and the bus's error forgotten."""
        network = self.network
        bus = network.bus
        try:
            network.disconnect()
        except Exception:
            port = getattr(bus, "serialPortOrig", None)
            if port is not None:
                with contextlib.suppress(Exception):
                    port.close()
        network.bus = None
        network.notifier = None
        self.bus_watch.error = None

    def open(self, enable: bool = True) -> None:
        """Connect and identify every drive (nothing enabled); then (``enable``) enable them."""
        kwargs = {"interface": self.interface, "channel": self.channel}
        if self.interface not in ("virtual",):
            kwargs["bitrate"] = self.options["bitrate"]
        if self.interface == "slcan" and (self.channel.startswith("socket://") or self.channel.startswith("/dev/pts/")):
            kwargs["sleep_after_open"] = 0.0  # no adapter to reset behind a TCP port or a pseudo-terminal
        self._bus_options = kwargs
        self._connect()
        eds = self.options["eds"]
        for k in range(self.n):
            node_id = self.node_id + k
            od = eds or cod.object_dictionary(node_id)
            try:
                drive = DriveNode(self, node_id, od)
            except (OSError, ValueError, KeyError) as exc:  # an EDS that cannot be read or parsed
                raise ConfigError(f"[driver] eds = {eds!r}: cannot load the object dictionary: {exc}") from None
            self.drives.append(drive)
            self.network.subscribe(0x700 + node_id, drive.on_bootup)
            drive.node.emcy.add_callback(drive.on_emcy)
        with self.bus("the start-up"):
            for drive in self.drives:
                self._identify(drive)
                drive.booted = False  # a boot-up before this point is the drive's start, not a restart
            if enable:
                self.enable()

    def _read_optional(self, d: DriveNode, index: int, sub: int, what: str):
        """An object a drive may lack: None when it answers "does not exist" (an SDO abort)."""
        try:
            return d.sdo_read(index, sub, what)
        except SdoAbortError:
            return None

    def _identify(self, d: DriveNode) -> None:
        """SDO reads only: device type, identity, scaling, limits, clock."""
        try:
            device_type = d.sdo_read(0x1000, what="device type")
        except SdoAbortError:
            raise
        except CommunicationError as exc:
            if self.interface != "virtual":
                raise
            raise CommunicationError(
                f"{exc} (canopen+virtual:// is python-can's bus inside one process: nothing answers unless the "
                "drive's emulator runs in this same process, as in hsio's tests; from the command line run "
                "`hsio emulate canopen --slcan tcp` and use the canopen+slcan://127.0.0.1:PORT/NODE it prints)") from None
        if device_type & 0xFFFF != 402:
            raise CommunicationError(f"CANopen node {d.id}: device type 0x{device_type:08X} is not a CiA 402 drive")
        d.identity = {"vendor_id": d.sdo_read(0x1018, 1, "vendor id"), "product_code": d.sdo_read(0x1018, 2, "product code"),
                      "revision": d.sdo_read(0x1018, 3, "revision"), "serial": d.sdo_read(0x1018, 4, "serial number")}
        d.counts_per_mm = self._scaling(d)
        d.rated_N = float(d.sdo_read(0x6076, what="rated torque (read as rated force, N)"))
        if not d.rated_N > 0:
            raise CommunicationError(f"CANopen node {d.id}: rated torque 0x6076 is {d.rated_N:g}; the force scaling "
                                     "needs a positive rated force (N)")
        d.max_torque_permille = self._read_optional(d, 0x6072, 0, "max torque")
        lo = self._read_optional(d, 0x607D, 1, "min position limit")
        hi = self._read_optional(d, 0x607D, 2, "max position limit")
        d.limits_counts = (lo or 0, hi or 0) if lo is not None and hi is not None else (0, 0)
        watchdog_ms = self._read_optional(d, cod.WATCHDOG_MS, 0, "host watchdog time")
        d.watchdog_s = watchdog_ms / 1000.0 if watchdog_ms else 0.0
        flag = self._read_optional(d, cod.LOCKSTEP_FLAG, 0, "lockstep flag")
        self.lockstep = bool(flag)
        if self.lockstep:
            self.ticks = d.sdo_read(cod.CLOCK, what="clock")

    def _scaling(self, d: DriveNode) -> float:
        """Position counts per mm (the units of 0x607A, 0x6064 and 0x607D per mm): [driver]
        counts_per_mm where set, else the drive's own (:meth:`_reported_scaling`); never guessed
        (docs/canopen.md). The drive's objects give counts per mm only where its position unit is
        the one hsio reads them in; a drive left at the position factor 1/1, its positions in
        encoder increments, is stated by counts_per_mm. A configured value that differs from the
        drive's figure (by more than :data:`SCALING_TOLERANCE`) is taken, and the difference
        logged, both figures named."""
        given = self.options["counts_per_mm"]
        if given is None:
            reported = self._reported_scaling(d)
            if reported is None:
                raise ConfigError(f"{self.url} node {d.id}: the drive reports no position scaling (neither the position "
                                  "factor 0x6093 nor the feed constant 0x6092 with 0x608F); set [driver] counts_per_mm")
            return reported[0]
        try:
            reported = self._reported_scaling(d)
        except ConfigError:  # a figure of the drive's that cannot be counts per mm: the configured one states it
            reported = None
        if reported is not None and not math.isclose(given, reported[0], rel_tol=SCALING_TOLERANCE):
            log.warning("%s node %d: [driver] counts_per_mm = %g is taken; the drive's %s would give %g counts per mm",
                        self.url, d.id, given, reported[1], reported[0])
        return float(given)

    def _reported_scaling(self, d: DriveNode) -> tuple[float, str] | None:
        """The drive's counts per mm and the objects it comes from, or None: its position factor
        0x6093 (numerator / divisor: counts per mm, the drive's user unit being the mm), else its
        feed constant 0x6092 (feed in mm per driving-shaft revolution) with the encoder
        resolution 0x608F (increments per motor revolution) and the gear ratio 0x6091 (motor
        revolutions per shaft revolution, 1:1 where the drive has none)."""
        num = self._read_optional(d, 0x6093, 1, "position factor numerator")
        div = self._read_optional(d, 0x6093, 2, "position factor divisor")
        if num and div:
            what = f"position factor 0x6093 ({num}/{div})"
            return self._checked_scale(d, num / div, what), what
        feed = self._read_optional(d, 0x6092, 1, "feed constant")
        revs = self._read_optional(d, 0x6092, 2, "feed constant shaft revolutions")
        incs = self._read_optional(d, 0x608F, 1, "position encoder increments")
        turns = self._read_optional(d, 0x608F, 2, "position encoder motor revolutions")
        if feed and revs and incs and turns:
            # A gearbox turns the motor (where the encoder sits) gear_motor times per gear_shaft
            # turns of the driving shaft (0x6091; a drive without one is 1:1, the standard's default).
            gear_motor = self._read_optional(d, 0x6091, 1, "gear ratio motor revolutions")
            gear_shaft = self._read_optional(d, 0x6091, 2, "gear ratio shaft revolutions")
            gear = gear_motor / gear_shaft if gear_motor and gear_shaft else 1.0
            what = (f"feed constant 0x6092 ({feed}/{revs}), encoder resolution 0x608F ({incs}/{turns}) and gear ratio "
                    f"0x6091 ({gear:g})")
            return self._checked_scale(d, (incs / turns) * gear * revs / feed, what), what
        return None

    @staticmethod
    def _checked_scale(d: DriveNode, value: float, what: str) -> float:
        if not (math.isfinite(value) and 1e-3 <= value <= 1e9):
            raise CommunicationError(f"CANopen node {d.id}: {what} gives {value!r} counts per mm, not a usable scaling")
        return float(value)

    def axis_limits(self) -> list[Limits]:
        return [d.limits(self.url, self.options) for d in self.drives]

    def enable(self) -> None:
        with self.bus("the enabling of the drives"):
            for drive in self.drives:
                self._enable_drive(drive)

    def _enable_drive(self, d: DriveNode) -> None:
        """Heartbeat, PDOs, NMT operational, CiA 402 to OPERATION ENABLED in cyclic synchronous
        position mode, starting from where the axis stands."""
        if self.options["heartbeat_ms"]:
            d.sdo_write(0x1017, int(self.options["heartbeat_ms"]), "producer heartbeat time")
        d.node.nmt.state = "PRE-OPERATIONAL"
        try:
            d.node.setup_402_state_machine(read_pdos=True)
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise sdo_error(d.id, "read of the PDO configuration", exc) from None
        d.take_pdos()
        d.node.tpdo[1].add_callback(lambda _map, d=d: d.status_received.set())
        d.node.tpdo_values[0x6041] = d.sdo_read(0x6041, what="statusword")
        d.node.tpdo_values[0x6061] = d.sdo_read(0x6061, what="modes of operation display")
        d.enabling = True
        d.node.nmt.state = "OPERATIONAL"
        d.node.rpdo_pointers[0x6060].raw = cod.CSP
        if d.node.state == "FAULT":
            d.node.reset_from_fault()
        # Start from where the axis stands: the targets, and the actual values that the first
        # feedback reads before any SYNC (in lockstep no exchange precedes it).
        d.target_counts = d.sdo_read(0x6064, what="position actual value")
        d.target_torque = d.sdo_read(0x6077, what="torque actual value")
        d.actual = (d.target_counts, d.target_torque, d.actual[2])
        d.send_targets()
        try:
            d.node.state = "OPERATION ENABLED"
        except RuntimeError as exc:
            raise CommunicationError(f"CANopen node {d.id}: could not reach OPERATION ENABLED ({exc}); "
                                     f"state {d.node.state}, statusword 0x{d.node.statusword:04X}") from None
        mode = d.sdo_read(0x6061, what="modes of operation display")
        if mode != cod.CSP:
            raise CommunicationError(f"CANopen node {d.id}: mode {mode} after asking for cyclic synchronous position (8)")
        d.operating = True
        d.check_events()

    def disable(self) -> None:
        """Every drive that may have been enabled: halt and disable operation (controlword
        0x0107 by SDO, confirmed), so it holds in SWITCHED ON."""
        errors = []
        for d in self.drives:
            if not d.enabling:
                continue
            d.halt = True
            d.mode = ControlMode.DISPLACEMENT
            d.operating = False
            try:
                d.sdo_write(0x6040, 0x0107, "controlword (halt, disable operation)")
            except CommunicationError as exc:
                errors.append(str(exc))
        if errors:
            raise CommunicationError("; ".join(errors))

    # -- cyclic exchange -----------------------------------------------------------------------
    def cycle(self) -> None:
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
                except LinkLostError:
                    raise
                except CommunicationError:
                    continue
            for d in self.drives:
                d.await_cycle(expected if self.lockstep else None)
                d.check_events()
                d.send_targets()
            self.check_bus("the SYNC")
            try:
                self.network.sync.transmit()
            except can.CanError as exc:
                # Whether it left cannot be told: the next attempt, on a link made again, asks
                # the drive's clock (lockstep) before it sends another.
                self.bus_watch.note(exc)
                continue
            self.requests += 1
            if self._await_tpdos(time.monotonic() + timeout):
                break
            self.check_bus("the wait for the TPDOs")
        else:
            if self.bus_watch.error is not None:  # the last attempt's SYNC could not be sent
                raise LinkLostError(f"{bus_error(self.url, 'the SYNC', self.bus_watch.error)} (at the last of "
                                    f"{int(self.options['retries']) + 1} attempt(s))")
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

    def _await_tpdos(self, deadline: float) -> bool:
        """Every drive's TPDO2 by ``deadline``; False then, or as soon as the bus fails (its
        reconnection starts at once, not a whole timeout later: the drives' host watchdog runs)."""
        for d in self.drives:
            while not d.received.wait(min(BUS_POLL_S, max(deadline - time.monotonic(), 0.0))):
                if self.bus_watch.error is not None or time.monotonic() >= deadline:
                    return False
        return True

    def _heartbeat_age(self, d: DriveNode) -> str:
        ts = getattr(d.node.nmt, "timestamp", None)
        return "never" if not ts else f"{time.time() - ts:.2f} s ago"

    def close(self) -> None:
        try:
            self.network.disconnect()
        except Exception:
            pass


class CanopenActuator(Actuator, ActuatorChannels):
    """One axis: a CiA 402 drive on a :class:`CanopenLink`."""

    def __init__(self, name: str, link: CanopenLink, axis: int, limits: Limits):
        self.name = name
        self.link = link
        self.axis = axis
        self.drive = link.drives[axis]
        self.limits = limits
        self._closed = False
        self.plausibility = common.Plausibility(f"actuator {name!r} at {link.url} node {self.drive.id}", limits,
                                                1.0 / 1024.0, link.options)

    @property
    def mode(self) -> ControlMode:
        return self.drive.mode

    @property
    def watchdog_s(self) -> float:
        """The drive's host watchdog time (0x2103; 0: off or not in its dictionary)."""
        return self.drive.watchdog_s

    def set_mode(self, mode: ControlMode) -> None:
        d = self.drive
        if mode is d.mode:
            return
        fb = self.feedback()
        d.target_counts = int(round(fb.displacement_mm * d.counts_per_mm))
        d.target_torque = d.permille(fb.force_kN)
        d.send_targets()
        d.mode = mode
        with self.link.bus(f"the mode change of node {d.id}"):
            # canopen's setter waits up to timeout_s for the mode display and logs rather than
            # raises on failure: the SDO read of 0x6061 decides.
            d.node.op_mode = MODE_NAMES[mode]
        shown = d.sdo_read(0x6061, what="modes of operation display")
        if shown == MODE_CODES[mode]:  # the TPDO's copy may still be the old mode: the drive's answer is newer
            d.node.tpdo_values[0x6061] = shown
        if shown != MODE_CODES[mode]:
            raise InterlockError(f"actuator {self.name!r} at {self.link.url} node {d.id}: {mode.value} control "
                                 f"({mode_name(MODE_CODES[mode])}) asked for, but the mode display 0x6061 shows "
                                 f"{mode_name(shown)} after {self.link.options['timeout_s']:g} s: the drive did not take "
                                 "the mode switch; the run stops")

    def _send(self, value: float) -> None:
        d = self.drive
        d.check_events()
        if d.halt:
            d.halt = False
            if not d.send_control():  # unconfirmed, the drive may still be halted: no command into the void
                d.halt = True
                raise CommunicationError(f"CANopen node {d.id}: no confirmation of the release of the halt within "
                                         f"{self.link.options['timeout_s']:g} s; the drive may still hold")
        if d.mode is ControlMode.DISPLACEMENT:
            d.target_counts = int(round(value * d.counts_per_mm))
        else:
            d.target_torque = d.permille(value)
        self.link.submit(self.axis)

    def feedback(self) -> Feedback:
        link = self.link
        if not link.fresh[self.axis] and not link.lockstep:
            self.drive.received.clear()
            link.exchange()
        link.fresh[self.axis] = False
        t = link.ticks / 1024.0 if link.lockstep else time.monotonic()
        d, f = self.drive.displacement_mm(), self.drive.force_kN()
        command = self.drive.target_counts / self.drive.counts_per_mm \
            if self.drive.mode is ControlMode.DISPLACEMENT and not self.drive.halt else None
        self.plausibility.check(d, f, t, command)
        return Feedback(d, f, t)

    def hold(self) -> None:
        """Halt (controlword bit 8): the drive holds its position in position control."""
        d = self.drive
        d.halt = True
        d.mode = ControlMode.DISPLACEMENT
        if not d.send_control():
            raise CommunicationError(f"CANopen node {d.id}: no confirmation of the halt within {self.link.options['timeout_s']:g} s")

    def keep_alive(self) -> None:
        """While the drive is halted (a pause): send the same targets again (RPDO2), so a drive
        that watches its RPDOs does not time out; a halted drive does not follow them."""
        if self.drive.halt:
            self.drive.send_targets()

    def holding(self) -> bool | None:
        """Read back the statusword 0x6041 by SDO (and, in OPERATION ENABLED, the mode of
        operation display 0x6061): see :func:`statusword_holds`. docs/safety.md section 3."""
        d = self.drive
        word = int(d.sdo_read(0x6041, what="statusword"))
        mode = int(d.sdo_read(0x6061, what="modes of operation display")) if word & 0x6F == 0x27 else None
        return statusword_holds(word, mode)

    def tripped(self) -> str | None:
        """Read the statusword 0x6041 by SDO: a drive in FAULT (an EMCY it sent is named), else None."""
        d = self.drive
        word = int(d.sdo_read(0x6041, what="statusword"))
        if word & 0x4F != 0x08:
            return None
        emcy = f", EMCY 0x{d.emcy[-1].code:04X}" if d.emcy else ""
        return f"CANopen node {d.id} in FAULT (statusword 0x{word:04X}{emcy})"

    def close(self) -> None:
        common.close_axis(self)


def is_drive_fault(code: int) -> bool:
    """An EMCY code that tells of the drive itself (an interlock, a fault, a safety event): hsio's
    drive's limit, valve, watchdog and refusal codes, and the CiA 301 classes current (0x2xxx),
    voltage (0x3xxx), temperature (0x4xxx), device hardware (0x5xxx), additional modules (0x7xxx)
    and external error (0x9xxx). Others (generic, software, monitoring and communication, device
    specific) stop the run as a link or protocol fault."""
    return code in (0x7320, 0x2310, 0x5000, 0x8130, 0x8612) or code >> 12 in (2, 3, 4, 5, 7, 9)


def mode_name(code: int) -> str:
    """A mode of operation code as 'N (NAME)'."""
    return f"{code} ({MODE_NAMES[CODE_MODES[code]] if code in CODE_MODES else 'not a mode hsio commands'})"


def statusword_holds(word: int, mode: int | None = None) -> bool | None:
    """Whether a CiA 402 statusword shows a drive holding its position: True, False (it follows
    its targets) or None (it cannot tell).

    SWITCHED ON, QUICK STOP ACTIVE and FAULT hold. In OPERATION ENABLED bit 12 means "drive
    follows the target" only in the cyclic synchronous modes (``mode`` 8 position, 10 torque, as
    the mode of operation display 0x6061 shows): clear, the drive is halted and holds; set, it
    follows its targets. In any other mode bit 12 means something else (set-point acknowledge in
    profile position), so it cannot tell; nor with the power stage off (SWITCH ON DISABLED, NOT
    READY, READY TO SWITCH ON)."""
    if word & 0x4F == 0x08:  # FAULT
        return True
    state = word & 0x6F
    if state == 0x27:  # OPERATION ENABLED: holding only while not following its targets
        if mode not in (cod.CSP, cod.CST):
            return None
        return not word & 0x1000
    if state in (0x23, 0x07):  # SWITCHED ON, QUICK STOP ACTIVE
        return True
    return None



def open_link(url: str, names: list[str], clock: Clock | None, options: dict | None = None,
              enable: bool = True) -> list[CanopenActuator]:
    """Open the drives and return one actuator per axis; the clock is checked before any drive
    is enabled, and a failure while opening leaves every drive disabled and holding.
    ``clock=None`` skips the clock check."""
    link = CanopenLink(url, len(names), options)
    return common.open_axes(link, names, clock, CanopenActuator, enable)


def open_url(url: str, elements, clock: Clock, options: dict | None = None) -> list[Actuator]:
    """``canopen+virtual://CHANNEL/NODE``: one CiA 402 drive per experimental element."""
    return open_link(url, [n for e in elements for n in getattr(e, "actuator_names", (e.name,))], clock, options)
