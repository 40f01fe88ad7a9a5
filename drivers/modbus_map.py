"""A servo controller's Modbus register map, read from a TOML file (see docs/modbus.md).

The map is data: a lab describes its own controller by writing a TOML file in the format of
``drivers/maps/hsio_default.toml``, no code. The same map drives both ends of the wire: the
driver (:mod:`hsio.drivers.modbus`) and the emulator's server (:mod:`hsio.emulators.modbus`).

Values are converted here, once, at the protocol boundary: a register value is the engineering
value (mm, kN, s) times ``scale``, in the register's type and the map's word order.
"""

from __future__ import annotations

import math
import struct
from hsio.config import read_toml
from dataclasses import dataclass, field
from pathlib import Path

from hsio.errors import ConfigError

MAPS_DIR = Path(__file__).resolve().parent / "maps"
DEFAULT_MAP = MAPS_DIR / "hsio_default.toml"

TYPES = {  # name -> (struct format, registers)
    "float32": ("f", 2),
    "int32": ("i", 2),
    "uint32": ("I", 2),
    "int16": ("h", 1),
    "uint16": ("H", 1),
}
COMMAND_NAMES = ("displacement", "force", "mode", "enable", "watchdog")
STATUS_NAMES = ("status_word", "displacement", "force", "sequence")
MAP_KEYS = {"name", "version", "word_order", "device_id", "max_axes", "readwrite"}
MAX_AXES = 64  # more axes than one controller has; bounds the map checks
STATUS_BITS = ("enabled", "force_mode", "holding", "interlock", "watchdog", "refused", "lockstep")
# A controller that does not report its control mode leaves force_mode out; the driver then
# cannot confirm a mode switch (docs/modbus.md, "Mode confirmation").
OPTIONAL_BITS = ("force_mode",)


@dataclass(frozen=True)
class Register:
    """One value in the map: its address (absolute, or an offset in an axis block) and type."""

    name: str
    address: int
    type: str = "float32"
    scale: float = 1.0

    @property
    def words(self) -> int:
        return TYPES[self.type][1]

    def full_scale(self) -> tuple[float, float] | None:
        """The smallest and largest engineering values an integer register holds (its raw range
        over the scale); None for a float register."""
        fmt, words = TYPES[self.type]
        if fmt == "f":
            return None
        bits = 16 * words
        low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if fmt.islower() else (0, (1 << bits) - 1)
        return tuple(sorted((low / self.scale, high / self.scale)))

    def counter_modulus(self) -> int:
        """Where a counter kept in this register wraps: 2^24 in a float32 (whole numbers exact),
        else one past the largest whole value the integer register holds (2^16 in a uint16)."""
        rails = self.full_scale()
        return 1 << 24 if rails is None else max(1, min(1 << 24, int(math.floor(rails[1])) + 1))

    def encode(self, value: float, word_order: str) -> list[int]:
        """Registers for an engineering value. Raises ValueError if it does not fit the type."""
        raw = value * self.scale
        fmt, words = TYPES[self.type]
        if fmt != "f":
            if not math.isfinite(raw):
                raise ValueError(f"{self.name}: {value!r} is not a finite number")
            raw = int(round(raw))
        elif math.isfinite(raw) and abs(raw) > 3.4028234e38:
            raise ValueError(f"{self.name}: {value!r} does not fit a float32")
        try:
            data = struct.pack(">" + fmt, raw)
        except struct.error:
            raise ValueError(f"{self.name}: {value!r} does not fit a {self.type} register") from None
        regs = [int.from_bytes(data[i:i + 2], "big") for i in range(0, 2 * words, 2)]
        return regs[::-1] if word_order == "little" else regs

    def decode(self, regs, word_order: str) -> float:
        regs = list(regs)
        if word_order == "little":
            regs = regs[::-1]
        data = b"".join(int(r).to_bytes(2, "big") for r in regs)
        (raw,) = struct.unpack(">" + TYPES[self.type][0], data)
        return raw / self.scale


@dataclass(frozen=True)
class Block:
    """Registers repeated per axis: axis k's register r is at base + k * stride + r.address."""

    base: int
    stride: int
    registers: dict[str, Register]

    @property
    def extent(self) -> int:
        return max(r.address + r.words for r in self.registers.values())

    def address(self, axis: int, name: str) -> int:
        return self.base + axis * self.stride + self.registers[name].address


@dataclass(frozen=True)
class RegisterMap:
    """A controller's register map: info, optional lockstep registers, command and status blocks."""

    name: str
    word_order: str
    device_id: int
    max_axes: int
    readwrite: bool
    info: dict[str, Register]
    lockstep: dict[str, Register]
    command: Block
    status: Block
    bits: dict[str, int]
    modes: dict[str, int]
    source: str = ""
    extra: dict = field(default_factory=dict)
    reset: dict[str, Register] = field(default_factory=dict)

    def check_spans(self, n_axes: int) -> None:
        """The cyclic exchange of ``n_axes`` axes must fit one Modbus request: at most 125
        registers read, 123 written (121 with function 23). Checked when the map is loaded
        (one axis) and when a link opens (its axes), never mid-run."""
        _, read = self.status_span(n_axes)
        start, write = self.command_span(n_axes, with_advance=bool(self.lockstep))
        write_max = 121 if self.readwrite else 123
        if read > 125:
            raise ConfigError(f"{self.source}: [status] {n_axes} axis/axes span {read} registers (base {self.status.base}, "
                              f"stride {self.status.stride}); one Modbus read carries at most 125")
        if write > write_max:
            raise ConfigError(f"{self.source}: [command] {n_axes} axis/axes span {write} registers from {start} (stride "
                              f"{self.command.stride}, with the lockstep advance); one Modbus write carries at most {write_max}")
        named = {a for k in range(n_axes) for r in self.command.registers.values()
                 for a in range(self.command.address(k, r.name), self.command.address(k, r.name) + r.words)}
        if self.lockstep:
            adv = self.lockstep["advance"]
            named.update(range(adv.address, adv.address + adv.words))
        gaps = [a for a in range(start, start + write) if a not in named]
        if gaps:
            raise ConfigError(f"{self.source}: [command] the write of {n_axes} axis/axes covers address {gaps[0]}, which "
                              f"no register of the map names ({len(gaps)} such address(es) from {start} to "
                              f"{start + write - 1}); the commands of every axis (and the lockstep advance) go in one "
                              "write, which would put 0 there: make the block contiguous (stride equal to its length, "
                              "no gap between its registers or before the advance)")

    # -- conversion ----------------------------------------------------------------------------
    def encode(self, reg: Register, value: float) -> list[int]:
        return reg.encode(value, self.word_order)

    def decode(self, reg: Register, regs) -> float:
        return reg.decode(regs, self.word_order)

    # -- spans on the wire ---------------------------------------------------------------------
    def command_span(self, n_axes: int, with_advance: bool) -> tuple[int, int]:
        """(first address, count) of one contiguous write of every axis' command block."""
        start = self.command.base
        end = self.command.base + (n_axes - 1) * self.command.stride + self.command.extent
        if with_advance:
            adv = self.lockstep["advance"]
            start = min(start, adv.address)
            end = max(end, adv.address + adv.words)
        return start, end - start

    def status_span(self, n_axes: int) -> tuple[int, int]:
        end = self.status.base + (n_axes - 1) * self.status.stride + self.status.extent
        return self.status.base, end - self.status.base

    def pack_commands(self, axes: list[dict], advance_to: int | None, span: tuple[int, int]) -> list[int]:
        """The registers of one write over ``span``: each axis' command block (+ the advance)."""
        start, count = span
        words = [0] * count
        for k, values in enumerate(axes):
            for name, reg in self.command.registers.items():
                a = self.command.address(k, name) - start
                words[a:a + reg.words] = self.encode(reg, values[name])
        if advance_to is not None:
            reg = self.lockstep["advance"]
            a = reg.address - start
            words[a:a + reg.words] = self.encode(reg, advance_to)
        return words

    def unpack_status(self, words, n_axes: int) -> list[dict]:
        start, _ = self.status_span(n_axes)
        out = []
        for k in range(n_axes):
            values = {}
            for name, reg in self.status.registers.items():
                a = self.status.address(k, name) - start
                values[name] = self.decode(reg, words[a:a + reg.words])
            out.append(values)
        return out

    def bit(self, word: float, name: str) -> bool:
        return bool((int(word) >> self.bits[name]) & 1)

    def make_word(self, flags: dict[str, bool]) -> int:
        """The status word of ``flags``; a flag the map has no bit for is not reported."""
        return sum(1 << self.bits[name] for name, on in flags.items() if on and name in self.bits)


def _register(where: str, name: str, table, key: str) -> Register:
    if not isinstance(table, dict) or key not in table:
        raise ConfigError(f"{where}: register {name!r} must be a table with {key!r}, got {table!r}")
    unknown = set(table) - {key, "type", "scale"}
    if unknown:
        raise ConfigError(f"{where}: register {name!r}: unknown key(s) {', '.join(sorted(unknown))}")
    address, kind, scale = table[key], table.get("type", "float32"), table.get("scale", 1.0)
    if isinstance(address, bool) or not isinstance(address, int) or address < 0 or address > 0xFFFF:
        raise ConfigError(f"{where}: register {name!r}: {key} must be an integer in 0..65535, got {address!r}")
    if kind not in TYPES:
        raise ConfigError(f"{where}: register {name!r}: type must be one of {', '.join(TYPES)}, got {kind!r}")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (math.isfinite(scale) and scale != 0):
        raise ConfigError(f"{where}: register {name!r}: scale must be a non-zero number, got {scale!r}")
    return Register(name, address, kind, float(scale))


def _registers(where: str, table: dict, key: str, required: tuple[str, ...], skip=()) -> dict[str, Register]:
    regs = {n: _register(where, n, t, key) for n, t in table.items() if n not in skip}
    missing = [n for n in required if n not in regs]
    if missing:
        raise ConfigError(f"{where}: missing register(s) {', '.join(missing)}")
    _check_overlap(where, regs.values())
    return regs


def _check_overlap(where: str, regs) -> None:
    used: dict[int, str] = {}
    for r in regs:
        for a in range(r.address, r.address + r.words):
            if a in used:
                raise ConfigError(f"{where}: registers {used[a]!r} and {r.name!r} overlap at {a}")
            used[a] = r.name


def _block(where: str, table, required, only: bool = False) -> Block:
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: must be a table")
    for key in ("base", "stride"):
        if isinstance(table.get(key), bool) or not isinstance(table.get(key), int) or not 0 <= table[key] <= 0xFFFF:
            raise ConfigError(f"{where}: {key} must be an integer in 0..65535, got {table.get(key)!r}")
    regs = _registers(where, table, "offset", required, skip=("base", "stride"))
    unknown = set(regs) - set(required)
    if only and unknown:
        raise ConfigError(f"{where}: unknown register(s) {', '.join(sorted(unknown))}; known: {', '.join(required)}")
    block = Block(table["base"], table["stride"], regs)
    if block.stride < block.extent:
        raise ConfigError(f"{where}: stride {block.stride} is shorter than the block ({block.extent} registers)")
    return block


def from_dict(data: dict, source: str = "<dict>") -> RegisterMap:
    """Check a map table by table; errors name the file, the table and the register."""
    known = {"map", "info", "lockstep", "reset", "command", "status", "status_bits", "modes"}
    unknown = set(data) - known
    if unknown:
        raise ConfigError(f"{source}: unknown table(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(known))}")
    head = data.get("map", {})
    if not isinstance(head, dict):
        raise ConfigError(f"{source}: [map] must be a table")
    unknown_keys = set(head) - MAP_KEYS
    if unknown_keys:
        raise ConfigError(f"{source}: [map] unknown key(s) {', '.join(sorted(unknown_keys))}; known: {', '.join(sorted(MAP_KEYS))}")
    word_order = head.get("word_order", "big")
    if word_order not in ("big", "little"):
        raise ConfigError(f"{source}: [map] word_order must be 'big' or 'little', got {word_order!r}")
    device_id = head.get("device_id", 1)
    if isinstance(device_id, bool) or not isinstance(device_id, int) or not 1 <= device_id <= 247:
        raise ConfigError(f"{source}: [map] device_id must be an integer in 1..247 (0 is broadcast), got {device_id!r}")
    max_axes = head.get("max_axes", 8)
    if isinstance(max_axes, bool) or not isinstance(max_axes, int) or not 1 <= max_axes <= MAX_AXES:
        raise ConfigError(f"{source}: [map] max_axes must be an integer in 1..{MAX_AXES}, got {max_axes!r}")
    readwrite = head.get("readwrite", False)
    if not isinstance(readwrite, bool):
        raise ConfigError(f"{source}: [map] readwrite must be true or false (unquoted), got {readwrite!r}")
    for key in ("info", "lockstep", "reset", "status_bits", "modes"):
        if not isinstance(data.get(key, {}), dict):
            raise ConfigError(f"{source}: [{key}] must be a table")
    info = _registers(f"{source}: [info]", data.get("info", {}), "address", ())
    lockstep = _registers(f"{source}: [lockstep]", data.get("lockstep", {}), "address", ())
    if lockstep and set(lockstep) != {"flag", "advance"}:
        raise ConfigError(f"{source}: [lockstep] needs exactly the registers 'flag' and 'advance'")
    reset = _registers(f"{source}: [reset]", data.get("reset", {}), "address", ())
    if reset and set(reset) != {"interlock"}:
        raise ConfigError(f"{source}: [reset] has one register, 'interlock'; got {', '.join(sorted(reset))}")
    command = _block(f"{source}: [command]", data.get("command"), COMMAND_NAMES, only=True)
    status = _block(f"{source}: [status]", data.get("status"), STATUS_NAMES)
    bits = dict(data.get("status_bits", {}))
    missing = [b for b in STATUS_BITS if b not in bits and b not in OPTIONAL_BITS]
    if missing:
        raise ConfigError(f"{source}: [status_bits] missing {', '.join(missing)}")
    extra_bits = set(bits) - set(STATUS_BITS)
    if extra_bits:
        raise ConfigError(f"{source}: [status_bits] unknown bit(s) {', '.join(sorted(extra_bits))}; known: {', '.join(STATUS_BITS)}")
    owner: dict[int, str] = {}
    for name, b in bits.items():
        if isinstance(b, bool) or not isinstance(b, int) or not 0 <= b < 24:
            raise ConfigError(f"{source}: [status_bits] {name} must be a bit number in 0..23, got {b!r}")
        if b in owner:
            raise ConfigError(f"{source}: [status_bits] {owner[b]} and {name} share bit {b}")
        owner[b] = name
    modes = dict(data.get("modes", {"displacement": 0, "force": 1}))
    if set(modes) != {"displacement", "force"} \
            or not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 0xFFFF for v in modes.values()) \
            or len(set(modes.values())) != 2:
        raise ConfigError(f"{source}: [modes] needs distinct whole numbers (0..65535) for 'displacement' and 'force', "
                          f"got {modes!r}")
    word = status.registers["status_word"]
    for name, b in bits.items():
        try:
            word.encode(float(1 << b), word_order)
        except ValueError:
            raise ConfigError(f"{source}: [status_bits] {name} = {b} does not fit the [status] status_word register "
                              f"({word.type}, scale {word.scale:g})"
                              + ("; declare a bit field type = \"uint16\" to use bit 15" if word.type == "int16" else "")) from None
    for name, value in modes.items():
        try:
            command.registers["mode"].encode(value, word_order)
        except ValueError:
            raise ConfigError(f"{source}: [modes] {name} = {value} does not fit the [command] mode register "
                              f"({command.registers['mode'].type}, scale {command.registers['mode'].scale:g})") from None
    regmap = RegisterMap(
        name=str(head.get("name", Path(source).stem)), word_order=word_order, device_id=device_id,
        max_axes=max_axes, readwrite=readwrite, info=info, lockstep=lockstep,
        command=command, status=status, bits=bits, modes=modes, source=source, reset=reset,
    )
    _check_layout(regmap)
    regmap.check_spans(1)
    return regmap


def _check_layout(m: RegisterMap) -> None:
    """No two registers of the whole map (every axis up to max_axes) share an address, and every
    one lies in the 0..65535 address space."""
    for block, tag in ((m.command, "command"), (m.status, "status")):
        last = block.base + (m.max_axes - 1) * block.stride + block.extent - 1
        if last > 0xFFFF:
            raise ConfigError(f"{m.source}: [{tag}] axis {m.max_axes - 1} ends at address {last}, beyond 65535 "
                              f"(base {block.base}, stride {block.stride}, [map] max_axes {m.max_axes})")
    absolute = list(m.info.values()) + list(m.lockstep.values()) + list(m.reset.values())
    for block, tag in ((m.command, "command"), (m.status, "status")):
        for k in range(m.max_axes):
            absolute += [Register(f"{tag}[{k}].{r.name}", block.address(k, r.name), r.type) for r in block.registers.values()]
    _check_overlap(f"{m.source} (with {m.max_axes} axes)", absolute)


def load(path: str | Path | None = None) -> RegisterMap:
    """Read a register map; ``None`` gives hsio's default map."""
    path = Path(path) if path else DEFAULT_MAP
    data = read_toml(path, "register map")
    return from_dict(data, str(path))
