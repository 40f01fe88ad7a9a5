"""A Modbus DAQ module of external instruments, described by a TOML register map (docs/setups.md).

The map (``drivers/maps/daq_default.toml`` is the default and a template) lists analog inputs
as holding registers with a type and a scale, in the same register format as the servo
controller's map (docs/modbus.md). The structure's instruments are assigned to the inputs in
their order. :class:`ModbusDAQ` reads every input, one request per run of adjacent inputs (of at
most 125 registers; never across a gap the module may not map), and returns engineering values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from hsio.config import read_toml
from hsio.drivers.modbus_map import MAPS_DIR, Register, _check_overlap, _register
from hsio.errors import CommunicationError, ConfigError, ImplausibleMeasurementError
from hsio.interfaces import DAQ, Channel

DEFAULT_DAQ_MAP = MAPS_DIR / "daq_default.toml"
MAX_READ_REGISTERS = 125  # holding registers in one read (function 3), by the Modbus specification


@dataclass(frozen=True)
class DaqMap:
    name: str
    word_order: str
    device_id: int
    inputs: tuple[Register, ...]
    source: str = ""

    def spans(self, n: int) -> list[tuple[int, int]]:
        """The reads (first address, count) that cover the registers of the first ``n`` inputs,
        each of at most :data:`MAX_READ_REGISTERS` (one Modbus read) and of inputs' registers
        only (a module may refuse a read of an address it does not map, as hsio's emulator does):
        one read per run of adjacent inputs."""
        out: list[list[int]] = []
        for r in sorted(self.inputs[:n], key=lambda r: r.address):
            end = r.address + r.words
            if out and r.address <= out[-1][1] and end - out[-1][0] <= MAX_READ_REGISTERS:
                out[-1][1] = max(out[-1][1], end)
            else:
                out.append([r.address, end])
        return [(a, e - a) for a, e in out]


def daq_map_from_dict(data: dict, source: str = "<dict>") -> DaqMap:
    """Check a DAQ map; errors name the file, the table and the register."""
    unknown = set(data) - {"map", "inputs"}
    if unknown:
        raise ConfigError(f"{source}: unknown table(s) {', '.join(sorted(unknown))}; known: inputs, map")
    head = data.get("map", {})
    word_order = head.get("word_order", "big")
    if word_order not in ("big", "little"):
        raise ConfigError(f"{source}: [map] word_order must be 'big' or 'little', got {word_order!r}")
    device_id = head.get("device_id", 1)
    if not isinstance(device_id, int) or not 0 <= device_id <= 247:
        raise ConfigError(f"{source}: [map] device_id must be an integer in 0..247, got {device_id!r}")
    table = data.get("inputs")
    if not isinstance(table, dict) or not table:
        raise ConfigError(f"{source}: [inputs] missing: one register per analog input")
    inputs = tuple(_register(f"{source}: [inputs]", n, t, "address") for n, t in table.items())
    _check_overlap(f"{source}: [inputs]", inputs)
    return DaqMap(str(head.get("name", Path(source).stem)), word_order, device_id, inputs, source)


def load_daq_map(path: str | Path | None = None) -> DaqMap:
    path = Path(path) if path else DEFAULT_DAQ_MAP
    return daq_map_from_dict(read_toml(path, "DAQ map"), str(path))


class ModbusDAQ(DAQ):
    """The instruments behind a Modbus DAQ module (TCP), read through its register map."""

    def __init__(self, url: str, instruments, daq_map: DaqMap | None = None, timeout_s: float = 1.0):
        from pymodbus.client import ModbusTcpClient

        self.map = daq_map or load_daq_map()
        self.instruments = list(instruments)
        if len(self.instruments) > len(self.map.inputs):
            raise ConfigError(f"DAQ map {self.map.name!r} has {len(self.map.inputs)} inputs for "
                              f"{len(self.instruments)} instruments")
        parts = urlsplit(url)
        if parts.scheme != "modbus+tcp" or not parts.hostname:
            raise ConfigError(f"{url!r}: a DAQ module is read at modbus+tcp://HOST:PORT")
        self.url = url
        self.client = ModbusTcpClient(parts.hostname, port=parts.port or 502, timeout=timeout_s, retries=0)
        if not self.client.connect():
            raise CommunicationError(f"{url}: cannot connect to the DAQ module")
        self._spans = self.map.spans(len(self.instruments))

    @property
    def channels(self) -> tuple[Channel, ...]:
        return tuple(Channel(i.name, i.unit) for i in self.instruments)

    def read(self) -> dict[str, float]:
        words: dict[int, int] = {}  # address -> register
        for start, count in self._spans:
            rr = self.client.read_holding_registers(start, count=count, device_id=self.map.device_id)
            if rr.isError():
                raise CommunicationError(f"{self.url}: read of the DAQ inputs {start}..{start + count - 1} failed: {rr}")
            words.update(zip(range(start, start + count), rr.registers))
        out = {}
        for inst, reg in zip(self.instruments, self.map.inputs):
            value = reg.decode([words[a] for a in range(reg.address, reg.address + reg.words)], self.map.word_order)
            if not math.isfinite(value):  # a float input of a broken channel
                raise ImplausibleMeasurementError(
                    f"{self.url}: instrument {inst.name!r} on input {reg.name!r} reads {value!r}: not a number "
                    f"(a broken or disconnected channel); the run stops")
            rails = reg.full_scale()
            # a saturated converter: the true value is beyond the rail. An unsigned input's rail at
            # 0 is also where its instrument stands at rest: a reading, not an over range.
            if rails is not None and value in rails and value != 0.0:
                raise ImplausibleMeasurementError(
                    f"{self.url}: instrument {inst.name!r} on input {reg.name!r} reads {value:g} {inst.unit}, the full "
                    f"scale of its {reg.type} register ({rails[0]:g}..{rails[1]:g} with scale {reg.scale:g}): over "
                    f"range; give the input a smaller scale or a wider type in the DAQ map")
            out[inst.name] = value
        return out

    def close(self) -> None:
        self.client.close()


def open_daq(url: str, instruments, map_path=None) -> ModbusDAQ:
    return ModbusDAQ(url, instruments, load_daq_map(map_path) if map_path else None)
