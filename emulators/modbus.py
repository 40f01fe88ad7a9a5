"""The emulated controller served over Modbus TCP (pymodbus server) and Modbus RTU on a pty.

:class:`RegisterContext` is the server's data model: it answers reads from the controller's live
state and turns writes into commands, as the register map (:mod:`hsio.drivers.modbus_map`) says.
A write that touches an unmapped or read-only register gets exception 2 (illegal data address),
a value out of range exception 3 (illegal data value); neither changes anything. The status
word reports the mode each axis runs in (force_mode bit), as the controller has it.

:class:`ModbusEmulator` runs the server in a thread with its own event loop, so tests and the
``hsio emulate`` command start and stop it the same way.
"""

from __future__ import annotations

import asyncio
import logging
import os
import select
import threading
import tty

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.exceptions import NoSuchIdException
from pymodbus.pdu.device import ModbusDeviceIdentification
from pymodbus.server import ModbusSerialServer, ModbusTcpServer

from hsio.drivers.modbus_map import Register, RegisterMap
from hsio.emulators.bank import CommandRefused, ControllerBank
from hsio.emulators.faults import check_transport
from hsio.interfaces import ControlMode

log = logging.getLogger(__name__)
# pymodbus reports a missed reply on its own logger (with a hex dump); the driver retries and
# names the failure itself, so those reports stay out of a terminal unless logging is configured.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

READ_CODES = (3, 23)
_RESERVED = Register("reserved", 0, "uint16")
WRITE_CODES = (6, 16, 23)


class RegisterContext(ModbusServerContext):
    """Holding registers backed by a :class:`ControllerBank`, laid out by a register map."""

    def __init__(self, bank: ControllerBank, regmap: RegisterMap):  # pylint: disable=super-init-not-called
        # The base class is only a type tag for the server: this context answers requests itself.
        self.old_simulator = True
        self.simdevices = []
        self.bank = bank
        self.map = regmap
        self.n = len(bank.controllers)
        if self.n > regmap.max_axes:
            raise ValueError(f"register map {regmap.name!r} has room for {regmap.max_axes} axes, not {self.n}")
        # Each mapped register: start address -> (kind, axis, Register)
        self.readable: dict[int, tuple] = {}
        self.writable: dict[int, tuple] = {}
        for reg in regmap.info.values():
            self.readable[reg.address] = ("info", None, reg)
        for name, reg in regmap.lockstep.items():
            self.readable[reg.address] = ("lockstep", None, reg)
            if name == "advance":
                self.writable[reg.address] = ("lockstep", None, reg)
        for k in range(self.n):
            for name, reg in regmap.command.registers.items():
                at = regmap.command.address(k, name)
                self.readable[at] = self.writable[at] = ("command", k, reg)
            for name, reg in regmap.status.registers.items():
                self.readable[regmap.status.address(k, name)] = ("status", k, reg)
        # An address inside a status block that no register of the map names (a reserved word,
        # the stride's padding) reads as 0, as a controller's reserved status words do.
        status = regmap.status
        covered = {a for block in (regmap.command, status) for k in range(self.n) for r in block.registers.values()
                   for a in range(block.address(k, r.name), block.address(k, r.name) + r.words)}
        for reg in (*regmap.info.values(), *regmap.lockstep.values(), *regmap.reset.values()):
            covered.update(range(reg.address, reg.address + reg.words))
        for k in range(self.n):
            for a in range(status.base + k * status.stride, status.base + (k + 1) * status.stride):
                if a not in covered and a <= 0xFFFF:
                    self.readable[a] = ("reserved", k, _RESERVED)
        # The command registers as last written (the host reads back what it wrote).
        self.commands = [{"displacement": 0.0, "force": 0.0, "mode": float(regmap.modes["displacement"]),
                          "enable": 0.0, "watchdog": 0.0} for _ in range(self.n)]
        for reg in regmap.reset.values():
            self.readable[reg.address] = self.writable[reg.address] = ("reset", None, reg)
        self.requests = 0
        self.exceptions = 0
        self.ignored = 0  # requests for another unit id or broadcast (device id 0): not answered
        self._pending = None  # the fault of a write-then-read, applied to its read
        # Axes whose controller ignores the host's mode switch (a fault for tests,
        # docs/modbus.md "Mode confirmation"): the axis keeps the mode it runs in, and its
        # status word says so.
        self.ignore_mode: set[int] = set()

    def _accept(self, device_id) -> None:
        """Only this controller's unit id is served; another id, or a broadcast (0), is ignored
        (no reply, nothing applied): docs/modbus.md, "Unit id and broadcast"."""
        if device_id != self.map.device_id:
            self.ignored += 1
            raise NoSuchIdException(f"device id {device_id} is not {self.map.device_id}")

    async def _fault(self, fault, applied: bool = False) -> None:
        """Request faults of docs/faults.md: drop (no reply), restart, delay."""
        if fault is None:
            return
        if fault.kind == "restart":
            self.bank.restart()
            raise NoSuchIdException("fault: controller restart")
        if fault.kind == "drop" or (fault.kind == "corrupt" and applied):
            raise NoSuchIdException(f"fault: {fault.kind}")  # the server stays silent
        if fault.kind == "delay":
            await asyncio.sleep(fault.arg)

    def device_ids(self):
        return [self.map.device_id]

    def add_instruments(self, daq, daq_map) -> None:
        """Serve the instruments of ``daq`` (a DAQ such as hsio.emulators.local.EmulatedInstruments)
        on this device, at the inputs of ``daq_map`` (hsio.drivers.modbus_daq), in the
        instruments' order (docs/setups.md)."""
        if daq_map.device_id != self.map.device_id:
            raise ValueError(f"the DAQ map's device id {daq_map.device_id} is not the controller's {self.map.device_id}")
        if len(daq.instruments) > len(daq_map.inputs):
            raise ValueError(f"DAQ map {daq_map.name!r} has {len(daq_map.inputs)} inputs for "
                             f"{len(daq.instruments)} instruments")
        self.instrument_daq = daq
        self.instrument_map = daq_map
        for inst, reg in zip(daq.instruments, daq_map.inputs):
            for a in range(reg.address, reg.address + reg.words):
                if self.readable.get(a, ("reserved",))[0] != "reserved" or a in self.writable:
                    raise ValueError(f"DAQ input {reg.name!r} at {a} overlaps the controller's registers")
            self.readable[reg.address] = ("instrument", inst, reg)

    # -- reads -------------------------------------------------------------------------------------
    def _value(self, kind: str, axis, reg) -> float:
        bank = self.bank
        if kind == "instrument":  # axis: the instrument; its converter saturates at full scale
            value = self.instrument_daq.value(axis)
            rails = reg.full_scale()
            return value if rails is None else min(max(value, rails[0]), rails[1])
        if kind == "info":
            if reg.name == "boot_id":  # a random number: wrapped into the register a lab map gives it
                return float(int(bank.boot_id) % reg.counter_modulus())
            c = bank.controllers[0].config
            return {"map_version": 1.0, "axes": float(self.n), "rate_hz": bank.rate_hz, "boot_id": bank.boot_id,
                    "stroke_mm": c.stroke_mm, "force_limit_kN": c.force_limit_kN,
                    "watchdog_s": bank.watchdog_s}.get(reg.name, 0.0)
        if kind == "lockstep":
            return (1.0 if bank.lockstep else 0.0) if reg.name == "flag" else float(bank.ticks)
        if kind == "command":
            return self.commands[axis][reg.name]
        if kind in ("reset", "reserved"):
            return 0.0
        c = bank.controllers[axis]
        if reg.name == "status_word":
            return float(self.map.make_word(bank.flags(axis)))
        if reg.name == "displacement":
            return bank.displacement(axis)
        if reg.name == "force":
            return bank.force(axis)
        if reg.name == "sequence":
            return float(bank.ticks % reg.counter_modulus())
        return 0.0

    async def async_getValues(self, device_id, func_code, address, count=1):
        self._accept(device_id)
        if func_code == 23:
            fault, self._pending = self._pending, None
        else:
            fault = self.bank.fault_due()
            await self._fault(fault)
        self.requests += 1
        if func_code not in READ_CODES:
            return self._exception(ExcCodes.ILLEGAL_FUNCTION, f"function {func_code} on holding registers")
        out: list[int] = []
        with self.bank.lock:
            at = address
            while at < address + count:
                entry = self.readable.get(at)
                if entry is None:
                    return self._exception(ExcCodes.ILLEGAL_ADDRESS, f"read of unmapped register {at}")
                kind, axis, reg = entry
                value = self._value(kind, axis, reg)
                rails = reg.full_scale() if kind == "status" else None
                if rails is not None:  # a reading beyond an integer register's range saturates
                    value = min(max(value, rails[0]), rails[1])
                word_order = self.instrument_map.word_order if kind == "instrument" else self.map.word_order
                out += reg.encode(value, word_order)
                at += reg.words
        if fault is not None and fault.kind == "corrupt":
            return out[:count - 1]  # a reply cut short
        return out[:count]

    # -- writes ------------------------------------------------------------------------------------
    async def async_setValues(self, device_id, func_code, address, values):
        self._accept(device_id)
        fault = self.bank.fault_due()
        if fault is not None and fault.kind not in ("corrupt", "delay"):
            await self._fault(fault)  # a lost request or a restart: nothing applied
        self._pending = fault if func_code == 23 else None
        result = self._set(func_code, address, values)
        if result is None and fault is not None and fault.kind == "duplicate":
            result = self._set(func_code, address, values)  # the same frame, applied again
        if result is None and fault is not None and fault.kind == "corrupt" and func_code != 23:
            await self._fault(fault, applied=True)  # the write's reply is lost
        if fault is not None and fault.kind == "delay":
            # The write is applied when it arrives; its reply (a write-then-read's too) is late.
            # Held before applying, it would land after the host gave up on it, perhaps after
            # the host told the axis to hold.
            await self._fault(fault)
        return result

    def _set(self, func_code, address, values):
        if func_code != 23:  # a write-then-read is counted once, by its read
            self.requests += 1
        if func_code not in WRITE_CODES:
            return self._exception(ExcCodes.ILLEGAL_FUNCTION, f"function {func_code} on holding registers")
        decoded = []  # (kind, axis, Register, value)
        at, end = address, address + len(values)
        while at < end:
            entry = self.writable.get(at)
            if entry is None:
                return self._exception(ExcCodes.ILLEGAL_ADDRESS, f"write to unmapped or read-only register {at}")
            kind, axis, reg = entry
            if at + reg.words > end:
                return self._exception(ExcCodes.ILLEGAL_ADDRESS, f"write covers only part of {reg.name!r} at {at}")
            decoded.append((kind, axis, reg, self.map.decode(reg, values[at - address:at - address + reg.words])))
            at += reg.words
        with self.bank.lock:
            new = [dict(c) for c in self.commands]
            advance_to = None
            for kind, axis, reg, value in decoded:
                if kind == "reset":
                    if value != 1.0:
                        return self._exception(ExcCodes.ILLEGAL_VALUE, f"interlock reset: write 1, not {value!r}")
                    try:
                        self.bank.reset_interlocks()
                    except CommandRefused as exc:
                        return self._exception(ExcCodes.DEVICE_FAILURE, f"interlock reset refused: {exc}")
                    continue
                if kind == "lockstep":
                    advance_to = value
                else:
                    new[axis][reg.name] = value
            touched = sorted({axis for kind, axis, _, _ in decoded if kind == "command"})
            plans = []
            for axis in touched:
                cmd = new[axis]
                modes = {v: k for k, v in self.map.modes.items()}
                if cmd["mode"] not in modes:
                    self.bank.refuse(axis)
                    return self._exception(ExcCodes.ILLEGAL_VALUE, f"axis {axis}: unknown mode value {cmd['mode']!r}")
                mode = ControlMode(modes[cmd["mode"]])
                if axis in self.ignore_mode or self.bank.ignores_mode(axis):
                    mode = self.bank.controllers[axis].mode
                value = cmd["displacement"] if mode is ControlMode.DISPLACEMENT else cmd["force"]
                try:
                    self.bank.check_command(axis, ControlMode.DISPLACEMENT, cmd["displacement"])
                    self.bank.check_command(axis, ControlMode.FORCE, cmd["force"])
                except CommandRefused as exc:
                    self.bank.refuse(axis)
                    return self._exception(ExcCodes.ILLEGAL_VALUE, str(exc))
                plans.append((axis, mode, value, cmd["enable"] >= 0.5, cmd["watchdog"]))
            if advance_to is not None and not self.bank.lockstep:
                return self._exception(ExcCodes.ILLEGAL_VALUE, "advance written while the clock runs in real time")
            self.commands = new
            for plan in plans:
                self.bank.apply(*plan)
            if advance_to is not None:
                try:
                    self.bank.advance_to(int(advance_to))
                except CommandRefused as exc:
                    return self._exception(ExcCodes.ILLEGAL_VALUE, str(exc))
        return None

    def _exception(self, code: ExcCodes, why: str) -> ExcCodes:
        self.exceptions += 1
        log.info("modbus exception %d: %s", int(code), why)
        return code


def identity(regmap: RegisterMap) -> ModbusDeviceIdentification:
    ident = ModbusDeviceIdentification()
    ident.VendorName = "hsio"
    ident.ProductCode = "hsio-servo-emulator"
    ident.ProductName = "hsio emulated servo controller"
    ident.ModelName = regmap.name
    ident.MajorMinorRevision = "1.0"
    return ident


class PtyBridge:
    """Two pseudo-terminal pairs joined back to back, like a null-modem cable.

    The server opens ``server_path``; a client (the driver, a terminal tool) opens ``path``.
    As on a cable, what one end sends while the other does not read is lost once the other end's
    buffer is full: the sender is never blocked by a reader that is not there.
    """

    def __init__(self):
        self._a_master, a_slave = os.openpty()
        self._b_master, b_slave = os.openpty()
        for fd in (a_slave, b_slave):
            tty.setraw(fd)
        for fd in (self._a_master, self._b_master):
            os.set_blocking(fd, False)
        self.server_path = os.ttyname(a_slave)
        self.path = os.ttyname(b_slave)
        self._slaves = (a_slave, b_slave)  # kept open so the pair stays alive
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="pty-bridge", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        pair = {self._a_master: self._b_master, self._b_master: self._a_master}
        while not self._stop.is_set():
            ready, _, _ = select.select(list(pair), [], [], 0.1)
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                if data:
                    try:
                        os.write(pair[fd], data)
                    except OSError:  # the other end's buffer is full (nobody reads it): lost
                        pass

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        for fd in (self._a_master, self._b_master, *self._slaves):
            try:
                os.close(fd)
            except OSError:
                pass


class ModbusEmulator:
    """A Modbus server for a :class:`ControllerBank`, in a thread; TCP or RTU over a pty.

    ``transport="tcp"`` listens on ``host:port``; ``port=0`` lets the system choose a free port,
    and ``self.port`` is the port bound once :meth:`start` returns. ``transport="rtu"`` creates a
    pty pair and serves one end (``self.path`` is the other end, for the client).
    """

    def __init__(self, bank: ControllerBank, regmap: RegisterMap, transport: str = "tcp",
                 host: str = "127.0.0.1", port: int = 0, baudrate: int = 115200, faults=None):
        if transport not in ("tcp", "rtu"):
            raise ValueError(f"transport must be 'tcp' or 'rtu', got {transport!r}")
        self.bank = bank
        if faults is not None:
            bank.faults = faults
        check_transport(bank.faults, "modbus")  # warn is CANopen's (docs/faults.md)
        self.map = regmap
        self.context = RegisterContext(bank, regmap)
        self.transport = transport
        self.host, self.port, self.baudrate = host, port, baudrate
        self.bridge: PtyBridge | None = None
        self.path = ""
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        if self.transport == "tcp":
            host = f"[{self.host}]" if ":" in self.host else self.host  # an IPv6 address in brackets (RFC 3986)
            return f"modbus+tcp://{host}:{self.port}"
        return f"modbus+rtu://{self.path}?baudrate={self.baudrate}"

    def start(self) -> "ModbusEmulator":
        if self.transport == "rtu":
            self.bridge = PtyBridge()
            self.path = self.bridge.path
        self.bank.start()
        self._thread = threading.Thread(target=self._serve, name="modbus-emulator", daemon=True)
        self._thread.start()
        if not self._ready.wait(5.0) or self._error is not None:
            self.stop()
            raise RuntimeError(f"Modbus emulator did not start on {self.url}: {self._error!r}")
        return self

    def _serve(self) -> None:
        async def main():
            if self.transport == "tcp":
                self._server = ModbusTcpServer(self.context, address=(self.host, self.port), identity=identity(self.map),
                                               ignore_missing_devices=True)
            else:
                self._server = ModbusSerialServer(self.context, port=self.bridge.server_path, baudrate=self.baudrate,
                                                  ignore_missing_devices=True,
                                                  identity=identity(self.map), timeout=0.1)
            self._loop = asyncio.get_running_loop()
            await self._server.serve_forever(background=True)
            if self.transport == "tcp":  # the port actually bound (port 0: chosen by the system)
                self.port = self._server.transport.sockets[0].getsockname()[1]
            self._ready.set()
            await self._server.serving

        try:
            asyncio.run(main())
        except BaseException as exc:  # reported by start()
            self._error = exc
            self._ready.set()

    def stop(self) -> None:
        """Stop serving; the controller's axes hold."""
        loop, server, self._loop, self._server = self._loop, self._server, None, None
        if loop is not None and server is not None and loop.is_running():
            try:
                asyncio.run_coroutine_threadsafe(server.shutdown(), loop).result(timeout=3.0)
            except Exception:
                pass
        if self._thread is not None:
            self._thread.join(timeout=3.0)
            self._thread = None
        self.bank.stop()
        for k in range(len(self.bank.controllers)):
            self.bank.hold(k)
        if self.bridge is not None:
            self.bridge.close()
            self.bridge = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
