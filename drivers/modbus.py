"""Modbus TCP and RTU driver: any servo controller described by a register map.

``modbus+tcp://HOST:PORT`` or ``modbus+rtu:///dev/ttyUSB0?baudrate=115200``; the [driver] table
of the configuration (or the URL's query) sets ``map`` (a TOML register map, default hsio's),
``baudrate``, ``parity`` (N, E, O) and ``stopbits`` (RTU), ``timeout_s``, ``retries``, ``reconnect_delay_s``, ``device_id`` and the limits ``stroke_mm``,
``force_kN``, ``velocity_mm_s``. The stroke and force capacity default to the controller's own
(its info registers); one it does not report must be set, never guessed, and a configured one may be
tighter than the controller's, never wider (:mod:`hsio.drivers.common`).

One :class:`ModbusLink` per controller carries the cyclic exchange of all its axes: one write of
every axis' command block and one read of every status block, in a single request (function
23) where the map allows. Each axis is a :class:`ModbusActuator`.

Lockstep: if the controller answers the map's lockstep flag with 1 (hsio's emulator does; a real
controller has no such register), the link attaches itself to a lockstep clock and each tick
writes the commands together with the clock target, so one request steps the controller.
Otherwise the controller runs on its own clock and the link writes and reads once per period.

Robustness: every request has a timeout; a failed request is retried (bounded) after closing
and reopening the link; a changed boot id (the controller restarted) or a latched watchdog or
interlock stops the run with a clear error; Modbus exception responses are named.

Mode confirmation: while an axis is enabled, its status must show the control mode the host
commands (the map's force_mode bit); a mode switch the controller has not taken within
:data:`MODE_READS` status reads (and, in real time, ``timeout_s``) stops the run with an
:class:`~hsio.errors.InterlockError`. A map without a force_mode bit cannot be checked: the link
says so once, when it is made (docs/modbus.md, "Mode confirmation").
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from urllib.parse import urlsplit

import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException
from pymodbus.pdu import ExceptionResponse

from hsio.drivers import common, modbus_map
from hsio.clock import Clock
from hsio.errors import (CommunicationError, ConfigError, ControllerRestartedError, InterlockError, LimitError,
                         ModbusExceptionError)
from hsio.interfaces import Actuator, ActuatorChannels, ControlMode, Feedback, Limits

log = logging.getLogger(__name__)
# pymodbus reports a missed reply on its own logger (with a hex dump); the driver retries and
# names the failure itself, so those reports stay out of a terminal unless logging is configured.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

EXCEPTION_NAMES = {
    1: "illegal function", 2: "illegal data address", 3: "illegal data value", 4: "device failure",
    5: "acknowledge", 6: "device busy", 8: "memory parity error", 10: "gateway path unavailable",
    11: "gateway target failed to respond",
}
ILLEGAL_ADDRESS = 2  # the answer of a controller that lacks an optional register
SEQ_MOD = 1 << 24
FROZEN_S = 1.0  # real time: a sequence register unchanged this long means the controller's loop stopped
MODE_READS = 8  # status reads a mode switch may take to show in the status word (lockstep: controller periods)
PARITIES = ("N", "E", "O")  # Modbus RTU: 8 data bits, parity none, even (the standard's default) or odd

DEFAULT_OPTIONS = {
    "map": "", "timeout_s": 0.5, "retries": 2, "reconnect_delay_s": 0.1, "device_id": None,
    "baudrate": 115200, "parity": "N", "stopbits": 1, "stroke_mm": None, "force_kN": None, "velocity_mm_s": 500.0, "lockstep": "auto",
    **common.PLAUSIBILITY_DEFAULTS,
}


RULES = {
    **common.COMMON_RULES,
    "device_id": common.whole(1, 247),  # 0 is the broadcast address: no device answers it
    "baudrate": common.Rule(int, 1, 10_000_000, False, "a whole number of bit/s, 1..10000000"),
    "stopbits": common.whole(1, 2),
    **common.PLAUSIBILITY_RULES,
}


def parse_options(url: str, options: dict | None) -> dict:
    """The [driver] table and the URL's query, checked (the query wins)."""
    table = common.parse_options(url, options, DEFAULT_OPTIONS, RULES)
    if table["parity"] not in PARITIES:
        raise ConfigError(f"[driver] for {url!r}: parity must be one of {', '.join(PARITIES)} (none, even, odd), "
                          f"got {table['parity']!r}")
    if table["lockstep"] not in ("auto", "on", "off"):
        raise ConfigError(f"[driver] for {url!r}: lockstep must be 'auto', 'on' or 'off', got {table['lockstep']!r}")
    return table


def check_options(url: str, options: dict | None = None) -> None:
    """Before anything opens or is created: the [driver] table, the URL's host (TCP), and the
    register map named by ``map`` (it must load)."""
    table = parse_options(url, options)
    parts = common.split_url(url)
    if parts.scheme == "modbus+tcp" and not parts.hostname:
        raise ConfigError(f"{url!r}: expected modbus+tcp://HOST:PORT")
    if parts.scheme == "modbus+rtu" and not (parts.netloc + parts.path):
        raise ConfigError(f"{url!r}: expected modbus+rtu:///dev/ttyXXX")
    if table["map"]:
        modbus_map.load(table["map"])


def input_files(url: str, options: dict | None = None) -> list[tuple[str, Path]]:
    """The register map the link reads when it opens: ``map``, else hsio's default."""
    return [("[driver] map", Path(parse_options(url, options)["map"] or modbus_map.DEFAULT_MAP))]


def _wrong_count(rr, expected: int) -> str:
    """"" when a read's reply carries the ``expected`` number of registers, else what it carries."""
    got = getattr(rr, "registers", None)
    if isinstance(got, list) and len(got) == expected:
        return ""
    return f"reply with {len(got) if isinstance(got, list) else 'no'} registers, expected {expected}"


class ModbusLink(common.AxisLink):
    """One controller over Modbus: connection, retries, and the cyclic exchange of all axes."""

    def __init__(self, url: str, n_axes: int, options: dict | None = None, regmap=None):
        self.url = url
        self.options = parse_options(url, options)
        self.map = regmap or modbus_map.load(self.options["map"] or None)
        if n_axes > self.map.max_axes:
            raise ConfigError(f"{url}: {n_axes} axes, but register map {self.map.name!r} has room for {self.map.max_axes}")
        self.map.check_spans(n_axes)
        self.n = n_axes
        self.device_id = self.options["device_id"] if self.options["device_id"] is not None else self.map.device_id
        self.client = self._make_client(url)
        self.timeout_s = self.options["timeout_s"]
        self.retries = int(self.options["retries"])
        self.lockstep = False
        self.ticks = 0
        self.boot_id: float | None = None
        self.info: dict[str, float] = {}
        self.commands = [{"displacement": 0.0, "force": 0.0, "mode": float(self.map.modes["displacement"]),
                          "enable": 0.0, "watchdog": 0.0} for _ in range(n_axes)]
        self.status: list[dict] = [{} for _ in range(n_axes)]
        self.fresh = [False] * n_axes
        self.submitted: set[int] = set()
        self.last_sequence: float | None = None
        self._sequence_seen: float | None = None  # wall-clock time the sequence last changed (real time)
        self._last_read: float | None = None  # wall-clock time of the last status read (real time)
        self.requests = 0
        self.reconnects = 0
        self.status_reads = 0  # status blocks taken (the cyclic exchange's and read_status')
        self.actuators: list = []
        self.confirms_mode = "force_mode" in self.map.bits
        if not self.confirms_mode:
            log.warning("%s: register map %r has no force_mode status bit: the control mode the controller runs in "
                        "is not confirmed after a mode switch (docs/modbus.md, \"Mode confirmation\")",
                        url, self.map.name)
        self.enabling = False
        self._status_span = self.map.status_span(n_axes)
        # The host watchdog counter and the controller's sequence wrap where their registers do.
        self.watchdog_mod = self.map.command.registers["watchdog"].counter_modulus()
        self.sequence_mod = self.map.status.registers["sequence"].counter_modulus()

    @property
    def rate_hz(self) -> float:
        """The controller's loop rate (its info register; 1024 Hz when it reports none or nonsense)."""
        rate = self.info.get("rate_hz", 1024.0)
        return rate if math.isfinite(rate) and 1.0 <= rate <= 1e6 else 1024.0

    @property
    def reported_rate_hz(self) -> float | None:
        """The loop rate the controller reports (its rate_hz info register), or None."""
        return common.reported(self.info.get("rate_hz"))

    # -- connection ------------------------------------------------------------------------------
    def _make_client(self, url: str):
        parts = common.split_url(url)
        timeout = self.options["timeout_s"]
        if parts.scheme == "modbus+tcp":
            if not parts.hostname:
                raise ConfigError(f"{url!r}: expected modbus+tcp://HOST:PORT")
            return ModbusTcpClient(parts.hostname, port=common.url_port(url, 502), timeout=timeout, retries=0,
                                   reconnect_delay=0, reconnect_delay_max=0)
        if parts.scheme == "modbus+rtu":
            path = (parts.netloc + parts.path) if parts.netloc else parts.path
            if not path:
                raise ConfigError(f"{url!r}: expected modbus+rtu:///dev/ttyXXX")
            return ModbusSerialClient(path, baudrate=int(self.options["baudrate"]), parity=self.options["parity"],
                                      stopbits=int(self.options["stopbits"]), bytesize=8, timeout=timeout, retries=0,
                                      reconnect_delay=0, reconnect_delay_max=0)
        raise ConfigError(f"{url!r} is not a modbus+tcp:// or modbus+rtu:// URL")

    def open(self, enable: bool = True) -> None:
        """Connect, read the identity and decide lockstep or real time; then (``enable``) take
        every axis into command at the position where it stands."""
        self._connect()
        self._read_info()
        served = self.info.get("axes")
        if served is not None and math.isfinite(served) and 1 <= served < self.n:
            raise ConfigError(f"{self.url}: {self.n} axes asked for, but the controller serves {served:g} (its axes "
                              "register); one axis per experimental element (and static preload)")
        flag = None
        if self.map.lockstep and self.options["lockstep"] != "off":
            reg = self.map.lockstep["flag"]
            try:
                flag = self.map.decode(reg, self.request("read_holding_registers", reg.address, count=reg.words,
                                                         what="read of the lockstep flag").registers)
            except ModbusExceptionError as exc:
                if exc.code != ILLEGAL_ADDRESS:
                    raise
                # a real controller has no lockstep register
        self.lockstep = flag == 1.0
        if self.options["lockstep"] == "on" and not self.lockstep:
            raise CommunicationError(f"{self.url}: lockstep requested but the controller runs on its own clock")
        if self.lockstep:
            adv = self.map.lockstep["advance"]
            self.ticks = int(self.map.decode(adv, self.request("read_holding_registers", adv.address, count=adv.words,
                                                               what="read of the clock").registers))
        self.read_status()
        if enable:
            self.enable()

    def enable(self) -> None:
        """Take every axis into command at the position where it stands (this re-arms a
        watchdog that expired before)."""
        for k, st in enumerate(self.status):  # start from where each axis stands, holding
            self.commands[k]["displacement"] = st["displacement"]
            self.commands[k]["force"] = st["force"]
            self.commands[k]["enable"] = 0.0
        self.exchange(advance=False)
        self.enabling = True  # from here on, a failure must disable the axes again
        for k in range(self.n):
            self.commands[k]["enable"] = 1.0
        self.exchange(advance=False)

    def disable(self) -> None:
        """Every axis holds (enable off, displacement control), one write per axis."""
        if not self.enabling:
            return
        errors = []
        for k in range(self.n):
            self.commands[k]["enable"] = 0.0
            self.commands[k]["mode"] = float(self.map.modes["displacement"])
            try:
                self.write_axis(k, ("mode", "enable", "watchdog"), what=f"hold of axis {k}")
            except CommunicationError as exc:
                errors.append(str(exc))
        if errors:
            raise CommunicationError("; ".join(errors))

    def reset_interlock(self) -> None:
        """The interlock reset of docs/modbus.md: every axis holds (enable 0), then 1 goes to the
        map's [reset] interlock register, then the status must show no latched interlock or
        watchdog. A refusal (the cause persists) is :class:`ModbusExceptionError` code 4."""
        reg = self.map.reset.get("interlock")
        if reg is None:
            raise ConfigError(f"{self.url}: register map {self.map.name!r} has no [reset] interlock register; "
                              "reset the interlock at the controller")
        self.read_status()
        for k in range(self.n):
            self.commands[k]["enable"] = 0.0
            self.commands[k]["mode"] = float(self.map.modes["displacement"])
            self.write_axis(k, ("mode", "enable", "watchdog"), what=f"hold of axis {k} before the reset")
        self.request("write_registers", reg.address, self.map.encode(reg, 1.0), what="interlock reset")
        self.read_status()
        for k, st in enumerate(self.status):
            for bit in ("interlock", "watchdog"):
                if self.map.bit(st["status_word"], bit):
                    raise InterlockError(f"{self.url}: axis {k}: the {bit} bit is still set after the reset")

    def axis_limits(self) -> list[Limits]:
        """One controller, one set of limits: [driver] where set (tighter than the controller's
        info registers stroke_mm, force_limit_kN, where it has them), else those registers;
        neither guessed."""
        why = f" (register map {self.map.name!r} has no such info register or it reads 0)"
        limits = common.resolve_limits(self.url, self.options, self.info.get("stroke_mm"),
                                       self.info.get("force_limit_kN"), why, why, " (its stroke_mm info register)",
                                       " (its force_limit_kN info register)")
        self._check_full_scale(limits)
        return [limits] * self.n

    def _check_full_scale(self, limits: Limits) -> None:
        """Every command the limits allow, and every measurement inside them, must fit its
        integer register: a register too narrow for the stroke or the capacity is refused when
        the link opens, before anything is enabled, never found mid-run."""
        ranges = {"displacement": (0.5 * limits.stroke_mm, "mm", "stroke_mm", "half stroke"),
                  "force": (limits.force_kN, "kN", "force_kN", "force capacity")}
        for table, block in (("command", self.map.command), ("status", self.map.status)):
            for name, (need, unit, key, what) in ranges.items():
                reg = block.registers[name]
                rails = reg.full_scale()
                if rails is not None and (rails[0] > -need or rails[1] < need):
                    raise ConfigError(
                        f"{self.url}: register map {self.map.source or self.map.name}: [{table}] {name} ({reg.type}, scale "
                        f"{reg.scale:g}) carries {rails[0]:g}..{rails[1]:g} {unit}, less than the {what} +/-{need:g} "
                        f"{unit} ([driver] {key} or the controller's); widen the register's type or lower its scale")

    def _connect(self) -> None:
        try:
            ok = self.client.connect()
        except Exception as exc:  # pymodbus/pyserial raise a variety of errors here
            ok, why = False, repr(exc)
        else:
            why = "connection refused or port unavailable"
        if not ok:
            where = default = ""
            parts = common.split_url(self.url)
            if parts.scheme.endswith("tcp"):  # name the port tried, the default one when the URL gives none
                where = f" to {parts.hostname}:{parts.port or 502}"
                default = "" if parts.port else " (the Modbus TCP default port; the URL gives none)"
            elif ok is False and why.startswith("connection refused"):
                why = self._serial_refusal()
            raise CommunicationError(f"{self.url}: cannot connect{where}{default} ({why})")

    def _serial_refusal(self) -> str:
        """Why the serial port did not open (pymodbus only logs it): pyserial's own error, from
        one more opening with the same settings."""
        params = self.client.comm_params
        try:
            serial.serial_for_url(params.host, baudrate=params.baudrate, parity=params.parity, stopbits=params.stopbits,
                                  bytesize=params.bytesize, exclusive=True).close()
        except Exception as exc:  # pyserial raises SerialException, termios.error, ValueError
            return (f"serial port {params.host!r} with baudrate {params.baudrate}, parity {params.parity}, stop bits "
                    f"{params.stopbits}: {type(exc).__name__}: {exc}")
        return f"serial port {params.host!r} unavailable"

    def _read_info(self) -> None:
        for name, reg in self.map.info.items():
            try:
                rr = self.request("read_holding_registers", reg.address, count=reg.words, what=f"read of {name}")
            except ModbusExceptionError as exc:
                if exc.code != ILLEGAL_ADDRESS:
                    raise
                continue  # the controller lacks this info register
            self.info[name] = self.map.decode(reg, rr.registers)
        boot = self.info.get("boot_id")
        if self.boot_id is not None and boot is not None and boot != self.boot_id:
            raise ControllerRestartedError(
                f"{self.url}: the controller restarted (boot id {self.boot_id:.0f} -> {boot:.0f}); its state is lost, "
                "the run stops")
        self.boot_id = boot

    def close(self) -> None:
        try:
            self.client.close()
        except Exception:
            pass

    # -- requests --------------------------------------------------------------------------------
    def request(self, method: str, *args, what: str, **kwargs):
        """One Modbus request with a timeout and bounded retries; reconnects between attempts.

        An exception response is an answer, not a transport fault: it is raised at once (device
        busy excepted, which is retried).
        """
        last = ""
        for attempt in range(self.retries + 1):
            if attempt:
                self.reconnects += 1
                self.close()
                time.sleep(self.options["reconnect_delay_s"] * attempt)
                try:
                    self._connect()
                    if self.boot_id is not None and "boot_id" in self.map.info:
                        reg = self.map.info["boot_id"]
                        rr = self.client.read_holding_registers(reg.address, count=reg.words, device_id=self.device_id)
                        wrong = "" if rr.isError() else _wrong_count(rr, reg.words)
                        if wrong:  # a late reply to the request before the reconnection: not the boot id
                            last = f"{wrong} (the read of the boot id)"
                            continue
                        if not rr.isError() and self.map.decode(reg, rr.registers) != self.boot_id:
                            raise ControllerRestartedError(
                                f"{self.url}: the controller restarted during the run (new boot id); "
                                "its state is lost, the run stops")
                except ControllerRestartedError:
                    raise
                except CommunicationError as exc:
                    last = str(exc)
                    continue
                except (ModbusException, OSError) as exc:
                    last = f"{type(exc).__name__}: {exc}"
                    continue
                except Exception as exc:  # a reply pymodbus could not make sense of, as below
                    last = f"malformed reply to the read of the boot id ({type(exc).__name__}: {exc})"
                    continue
            try:
                self.requests += 1
                rr = getattr(self.client, method)(*args, device_id=self.device_id, **kwargs)
            except (ModbusException, OSError) as exc:
                last = f"{type(exc).__name__}: {exc}"
                continue
            except Exception as exc:  # a reply pymodbus could not make sense of (an echo, garbage)
                last = f"malformed reply ({type(exc).__name__}: {exc})"
                continue
            if isinstance(rr, ExceptionResponse) or rr.isError():
                code = getattr(rr, "exception_code", None)
                if code == 6:
                    last = "device busy"
                    continue
                name = EXCEPTION_NAMES.get(code, "unknown")
                raise ModbusExceptionError(f"{self.url}: {what} answered with Modbus exception {code} ({name})",
                                           code if isinstance(code, int) else -1)
            expected = kwargs.get("read_count", kwargs.get("count")) if method.startswith(("read", "readwrite")) else None
            if expected is not None and _wrong_count(rr, expected):
                # an echo of the request or a reply to another request: not an answer
                last = _wrong_count(rr, expected)
                continue
            return rr
        raise CommunicationError(
            f"{self.url}: {what}: no valid answer after {self.retries + 1} attempt(s) "
            f"with a {self.timeout_s:g} s timeout each (last: {last})")

    # -- cyclic exchange ---------------------------------------------------------------------------
    def cycle(self) -> None:
        """Real time: every axis has its command; one exchange."""
        self.exchange(advance=False)

    def advance(self, ticks: int) -> None:
        """Lockstep clock: write every command and the clock target, read every status."""
        self.ticks += int(ticks)
        self.exchange(advance=True)

    def exchange(self, advance: bool) -> None:
        for cmd in self.commands:
            cmd["watchdog"] = (cmd["watchdog"] + 1.0) % self.watchdog_mod
        stepping = advance and self.lockstep
        span = self.map.command_span(self.n, with_advance=stepping)
        try:
            words = self.map.pack_commands(self.commands, self.ticks if stepping else None, span)
        except ValueError as exc:  # a value its register cannot carry: nothing is sent
            raise LimitError(f"{self.url}: {exc} (register map {self.map.name!r}); not sent") from None
        self.submitted.clear()
        rs, rc = self._status_span
        if self.map.readwrite:
            rr = self.request("readwrite_registers", read_address=rs, read_count=rc, write_address=span[0],
                              values=words, what="cyclic write+read")
            self._take_status(self._unpack_status(rr.registers))
        else:
            self.request("write_registers", span[0], words, what="write of the commands")
            self.read_status()

    def read_status(self) -> None:
        """Read every axis' status into :attr:`status` (fresh for each axis' next feedback),
        checking the lockstep sequence."""
        self._take_status(self._fetch_status())

    def peek_status(self) -> list[dict]:
        """The status block read and unpacked, for a look only: :attr:`status`, :attr:`fresh` and
        the lockstep sequence check are untouched."""
        return self._fetch_status()

    def _fetch_status(self) -> list[dict]:
        """One read of the status block of every axis, unpacked."""
        rs, rc = self._status_span
        rr = self.request("read_holding_registers", rs, count=rc, what="read of the status")
        return self._unpack_status(rr.registers)

    def _unpack_status(self, registers) -> list[dict]:
        if len(registers) < self._status_span[1]:
            raise CommunicationError(f"{self.url}: status reply too short ({len(registers)} registers)")
        status = self.map.unpack_status(registers, self.n)
        for k, st in enumerate(status):
            word = st["status_word"]
            if not (math.isfinite(word) and word >= 0 and word == int(word)):
                raise CommunicationError(f"{self.url}: axis {k}: status word {word!r} is not a bit field (a whole number "
                                         f"0 or more): the controller's status cannot be read (register map "
                                         f"{self.map.name!r})")
        return status

    def _take_status(self, status: list[dict]) -> None:
        self.status = status
        self.status_reads += 1
        seq = self.status[0]["sequence"]
        if self.lockstep and seq != self.ticks % self.sequence_mod:
            raise CommunicationError(
                f"{self.url}: controller clock at tick {seq:.0f}, expected {self.ticks % self.sequence_mod} (lockstep lost)")
        if not self.lockstep:
            self._check_clock_runs(seq)
        self.last_sequence = seq
        self.fresh = [True] * self.n

    def _check_clock_runs(self, seq: float) -> None:
        """Real time: the controller's sequence register must advance. One that stays put for
        longer than :data:`FROZEN_S` of wall-clock time belongs to a controller whose loop does
        not run (a stopped PLC still answering, a lockstep emulator driven with [driver]
        lockstep = "off"): its measurements are stale, and the run stops."""
        now = time.monotonic()
        last, read_at, self._last_read = self.last_sequence, self._last_read, now
        if last is not None and read_at is not None:
            # A counter only wraps forwards: one that went back by less than half its range, too
            # soon after the last read to have gone round, started again: the controller restarted
            # (this also covers a map without a boot_id register).
            back = (last - seq) % self.sequence_mod
            if 0 < back < self.sequence_mod / 2 and (now - read_at) * self.rate_hz < self.sequence_mod / 4:
                raise ControllerRestartedError(
                    f"{self.url}: the controller's sequence register went back from {last:.0f} to {seq:.0f}: it "
                    "restarted; its state is lost, the run stops")
        if seq != self.last_sequence or self._sequence_seen is None:
            self._sequence_seen = now
        elif now - self._sequence_seen > FROZEN_S:
            raise CommunicationError(
                f"{self.url}: the controller's clock does not run: its sequence register stayed at {seq:.0f} for "
                f"{now - self._sequence_seen:.2f} s in real time (a controller loop that stopped, or a lockstep "
                "emulator with [driver] lockstep = \"off\"); its measurements are stale")

    def write_axis(self, axis: int, names: tuple[str, ...], what: str) -> None:
        """Write some command registers of one axis (and those between them), e.g. to hold."""
        block = self.map.command
        words = [0] * block.extent
        for name, reg in block.registers.items():
            words[reg.address:reg.address + reg.words] = self.map.encode(reg, self.commands[axis][name])
        start = min(block.registers[n].address for n in names)
        end = max(block.registers[n].address + block.registers[n].words for n in names)
        self.request("write_registers", block.base + axis * block.stride + start,
                     words[start:end], what=what)


class ModbusActuator(Actuator, ActuatorChannels):
    """One axis of a controller on a :class:`ModbusLink`."""

    def __init__(self, name: str, link: ModbusLink, axis: int, limits: Limits):
        self.name = name
        self.link = link
        self.axis = axis
        self.limits = limits
        self._mode = ControlMode.DISPLACEMENT
        self._closed = False
        self._seen_enabled = False  # the status showed the axis following since the host enabled it
        self._mode_unconfirmed: tuple[int, float] | None = None  # (status reads, time) when the status first showed another mode
        self.plausibility = common.Plausibility(f"actuator {name!r} at {link.url}", limits,
                                                1.0 / link.rate_hz, link.options)

    @property
    def mode(self) -> ControlMode:
        return self._mode

    @property
    def watchdog_s(self) -> float:
        """The controller's host watchdog time (its info register ``watchdog_s``; 0: off or not reported)."""
        value = self.link.info.get("watchdog_s", 0.0)
        return float(value) if value and value > 0 else 0.0

    def set_mode(self, mode: ControlMode) -> None:
        """Bumpless: the new command starts at the present measurement."""
        if mode is self._mode:
            return
        fb = self.feedback()
        cmd = self.link.commands[self.axis]
        cmd["mode"] = float(self.link.map.modes[mode.value])
        cmd["displacement"], cmd["force"] = fb.displacement_mm, fb.force_kN
        self._mode = mode

    def _send(self, value: float) -> None:
        self._check_status()
        cmd = self.link.commands[self.axis]
        cmd["displacement" if self._mode is ControlMode.DISPLACEMENT else "force"] = float(value)
        cmd["enable"] = 1.0
        self.link.submit(self.axis)

    def feedback(self) -> Feedback:
        link = self.link
        if not link.fresh[self.axis]:
            link.read_status()
        link.fresh[self.axis] = False
        st = link.status[self.axis]
        t = (link.ticks if link.lockstep else (st["sequence"] or 0.0)) / link.rate_hz
        cmd = link.commands[self.axis]
        self.plausibility.check(st["displacement"], st["force"], t,
                                cmd["displacement"] if self._mode is ControlMode.DISPLACEMENT and cmd["enable"] else None)
        return Feedback(st["displacement"], st["force"], t)

    def _check_status(self) -> None:
        st = self.link.status[self.axis]
        if not st:
            return
        word = st["status_word"]
        bit = self.link.map.bit
        if bit(word, "interlock"):
            raise InterlockError(f"actuator {self.name!r} at {self.link.url}: the controller's interlock tripped; holding")
        if bit(word, "watchdog"):
            watchdog_s = common.reported(self.link.info.get("watchdog_s"))
            silence = (f"no command for more than {watchdog_s:g} s" if watchdog_s is not None
                       else "no command within its watchdog time, which its register map does not report")
            raise InterlockError(
                f"actuator {self.name!r} at {self.link.url}: the controller's host watchdog expired ({silence}); it holds")
        if bit(word, "refused"):
            # A controller may refuse a command by its status rather than by an exception
            # response: the axis did not take it, and goes on with an older one.
            raise InterlockError(f"actuator {self.name!r} at {self.link.url}: the controller refused the last command "
                                 f"(its refused bit, status word {int(word)}); the run stops")
        # Enabled by the host and seen following, then no longer following with neither latch
        # bit set (a stop at the controller's panel, hydraulics off): the measurements would be
        # those of an axis that does not follow its commands.
        if not self.link.commands[self.axis]["enable"]:
            self._seen_enabled = False
        elif bit(word, "enabled"):
            self._seen_enabled = True
        elif self._seen_enabled:
            raise InterlockError(f"actuator {self.name!r} at {self.link.url}: the controller no longer follows the "
                                 f"commands (its enabled bit cleared, status word {int(word)}); the run stops")
        self._check_mode(word)

    def _check_mode(self, word: float) -> None:
        """An enabled axis' status word must show the control mode the host commands (the
        force_mode bit). A switch takes effect with the write that carries it, so the status of
        an honest controller shows it at the next read; one that still shows the other mode after
        :data:`MODE_READS` status reads (in real time also after ``timeout_s``) did not take the
        switch, and the run stops. Without a force_mode bit in the map nothing is checked."""
        link = self.link
        if not link.confirms_mode or not link.commands[self.axis]["enable"]:
            self._mode_unconfirmed = None
            return
        shown = ControlMode.FORCE if link.map.bit(word, "force_mode") else ControlMode.DISPLACEMENT
        if shown is self._mode:
            self._mode_unconfirmed = None
            return
        now = time.monotonic()
        if self._mode_unconfirmed is None:
            self._mode_unconfirmed = (link.status_reads, now)
            return
        reads = link.status_reads - self._mode_unconfirmed[0]
        waited = now - self._mode_unconfirmed[1]
        if reads >= MODE_READS and (link.lockstep or waited >= link.timeout_s):
            raise InterlockError(
                f"actuator {self.name!r} (axis {self.axis}) at {link.url}: {self._mode.value} control asked for, but the "
                f"controller reports {shown.value} control (status word {int(word)}, force_mode bit "
                f"{link.map.bits['force_mode']}) after {reads} status reads in {waited:.3g} s: it did not take the mode "
                "switch; the run stops")

    def hold(self) -> None:
        """Hold the present position: enable off, one write (no retries beyond the link's)."""
        cmd = self.link.commands[self.axis]
        cmd["enable"] = 0.0
        cmd["mode"] = float(self.link.map.modes["displacement"])
        self._mode = ControlMode.DISPLACEMENT
        self.link.write_axis(self.axis, ("mode", "enable", "watchdog"), what=f"hold of axis {self.axis}")

    def keep_alive(self) -> None:
        """While the axis holds (a pause): change the host watchdog counter, and nothing else, so
        a controller whose watchdog also watches a holding axis does not latch it. Only the
        watchdog register is written; the axis stays disabled (docs/safety.md section 4)."""
        cmd = self.link.commands[self.axis]
        if cmd["enable"]:
            return  # a commanded axis is kept alive by its commands
        cmd["watchdog"] = (cmd["watchdog"] + 1.0) % self.link.watchdog_mod
        self.link.write_axis(self.axis, ("watchdog",), what=f"watchdog of holding axis {self.axis}")

    def holding(self) -> bool:
        """Read back the controller's status word: the axis holds when its holding bit is set and
        its enabled bit clear (docs/modbus.md, status bits). A read of its own: the cyclic
        exchange's status (what the next :meth:`feedback` returns) and its lockstep check are
        left alone, so a controller that stopped stepping after a trip still reads back."""
        link = self.link
        word = link.peek_status()[self.axis]["status_word"]
        return link.map.bit(word, "holding") and not link.map.bit(word, "enabled")

    def tripped(self) -> str | None:
        """Read the status word (a read of its own, as :meth:`holding`): the controller's latched
        interlock or host watchdog, else None."""
        link = self.link
        word = link.peek_status()[self.axis]["status_word"]
        if link.map.bit(word, "interlock"):
            return f"the controller's interlock tripped (status word {int(word)})"
        if link.map.bit(word, "watchdog"):
            return f"the controller's host watchdog expired (status word {int(word)})"
        return None

    def close(self) -> None:
        common.close_axis(self)



def open_link(url: str, names: list[str], clock: Clock | None, options: dict | None = None,
              enable: bool = True) -> list[ModbusActuator]:
    """Connect to a controller and return one actuator per axis (axis k = names[k]).

    The clock is checked before any axis is enabled; a failure while opening leaves every axis
    holding. ``clock=None`` skips the clock check (diagnostics decide the clock from
    ``link.lockstep``).
    """
    link = ModbusLink(url, len(names), options)
    return common.open_axes(link, names, clock, ModbusActuator, enable)


def open_url(url: str, elements, clock: Clock, options: dict | None = None) -> list[Actuator]:
    """``modbus+tcp://`` / ``modbus+rtu://``: one actuator per experimental element."""
    return open_link(url, [n for e in elements for n in getattr(e, "actuator_names", (e.name,))], clock, options)
