"""Fault injection in the emulated controllers (docs/faults.md).

A :class:`FaultSchedule` is a list of faults, each at a controller tick, parsed from a SPEC
string (``hsio emulate ... --faults SPEC``) or built in code. The protocol front-ends
(:mod:`hsio.emulators.modbus`, :mod:`hsio.emulators.canopen`) ask it, request by request, what
to do; the bank (:mod:`hsio.emulators.bank`) asks it what the transducers read.

SPEC: items separated by commas.

* ``KIND@TICK`` or ``KIND@TICK:ARG``: one fault at the first request at or after controller
  tick TICK (ARG: the fault's parameter, see :data:`KINDS`).
* ``seed=S``, ``every=N``, ``kinds=K1+K2+...``, ``until=T``: a seeded random schedule, one
  fault every N ticks on average (gaps uniform in N/2..3N/2) up to tick T (default 10**7),
  kinds drawn from the list (default the recoverable ones: drop, delay, corrupt, duplicate).

Kinds (what happens, and the outcome the driver gives; docs/faults.md):

=========== ============================================================== ==================================
drop        the request is lost: nothing applied, no reply                  retried, completes
delay:S     the reply is held S seconds (default 0.05)                      completes
corrupt     the reply is cut short (a reply the driver cannot use)          retried, completes
duplicate   the request is applied twice (a repeated frame)                 completes
restart     the controller restarts: new boot id, clock at 0, axes hold     stops (restarted)
spike:MM    one displacement reading of axis 0 off by MM (default 50)       interlock (implausible)
stuck:N     axis 0's displacement reading frozen for N ticks (0: for good)  interlock (stuck transducer)
nan         one displacement reading of axis 0 is NaN                       interlock (implausible)
valve       axis 0's servo-valve fails: the controller trips and holds      interlock
mode        from TICK on, axis 0 ignores the host's mode switches           interlock at the first switch (none
                                                                            in a run that never switches)
fspike:KN   one force reading of axis 0 off by KN (default 50)              interlock above half the capacity,
                                                                            else passes (not told from a real
                                                                            change of force)
fstuck:N    axis 0's force reading frozen for N ticks (0: for good)         interlock (stuck load cell) once the
                                                                            displacement moved force_stuck_mm
fnan        one force reading of axis 0 is NaN (CANopen: int16 -32768)      interlock (implausible)
warn:CODE   CANopen only: a warning EMCY of axis 0 (default 0x4210), the    warning printed once, completes
            drive staying operation enabled
=========== ============================================================== ==================================

``warn`` has no Modbus counterpart: a Modbus emulator given a schedule with it refuses to start
(:func:`check_transport`).
"""

from __future__ import annotations

import math
import random
import threading
from dataclasses import dataclass, field

from hsio.errors import ConfigError

KINDS = {  # kind -> default argument
    "drop": 0.0, "delay": 0.05, "corrupt": 0.0, "duplicate": 0.0, "restart": 0.0,
    "spike": 50.0, "stuck": 0.0, "nan": 0.0, "valve": 0.0,
    "mode": 0.0, "fspike": 50.0, "fstuck": 0.0, "fnan": 0.0, "warn": 0x4210,
}
REQUEST_KINDS = ("drop", "delay", "corrupt", "duplicate", "restart")
RECOVERABLE = ("drop", "delay", "corrupt", "duplicate")
TRANSPORT_ONLY = {"warn": "canopen"}  # kind -> the only transport that has it
TICK_ARGS = ("stuck", "fstuck")  # kinds whose ARG counts ticks (a whole number)
MAX_FAULTS = 100_000
MAX_TICK = 10**9
MAX_DELAY_S = 10.0


@dataclass
class Fault:
    kind: str
    tick: int
    arg: float = 0.0
    done: bool = False


@dataclass
class FaultSchedule:
    """Faults by controller tick; thread-safe; counts what it injected."""

    faults: list[Fault] = field(default_factory=list)
    injected: dict = field(default_factory=dict)

    def __post_init__(self):
        self.faults.sort(key=lambda f: f.tick)
        self._lock = threading.Lock()
        self._next = 0
        self.stuck_until: int | None = None
        self.stuck_value: float | None = None
        self.spike_mm = 0.0
        self.nan = False
        self.valve = False
        self.fstuck_until: int | None = None
        self.fstuck_value: float | None = None
        self.fspike_kN = 0.0
        self.fnan = False
        self.mode_ignored = False  # axis 0 ignores the host's mode switches (for good)
        self.warn_code: int | None = None  # a warning EMCY to send (CANopen)

    def __bool__(self) -> bool:
        return bool(self.faults)

    def _count(self, kind: str) -> None:
        self.injected[kind] = self.injected.get(kind, 0) + 1

    def due(self, tick: int, kinds=REQUEST_KINDS) -> Fault | None:
        """The next request fault due at ``tick`` (at most one per request), marked done.
        Measurement faults that fall due are armed for the bank."""
        with self._lock:
            while self._next < len(self.faults) and self.faults[self._next].tick <= tick:
                f = self.faults[self._next]
                self._next += 1
                f.done = True
                self._count(f.kind)
                if f.kind in kinds:
                    return f
                self._arm(f, tick)
        return None

    def _arm(self, f: Fault, tick: int) -> None:
        if f.kind == "spike":
            self.spike_mm = f.arg
        elif f.kind == "nan":
            self.nan = True
        elif f.kind == "stuck":
            self.stuck_until = tick + int(f.arg) if f.arg > 0 else MAX_TICK * 10
            self.stuck_value = None
        elif f.kind == "valve":
            self.valve = True
        elif f.kind == "fspike":
            self.fspike_kN = f.arg
        elif f.kind == "fnan":
            self.fnan = True
        elif f.kind == "fstuck":
            self.fstuck_until = tick + int(f.arg) if f.arg > 0 else MAX_TICK * 10
            self.fstuck_value = None
        elif f.kind == "mode":
            self.mode_ignored = True
        elif f.kind == "warn":
            self.warn_code = int(f.arg)

    def measured(self, axis: int, tick: int, displacement: float) -> float:
        """What axis ``axis``'s displacement transducer reports (faults apply to axis 0)."""
        if axis != 0:
            return displacement
        with self._lock:
            if self.nan:
                self.nan = False
                return math.nan
            if self.spike_mm:
                spike, self.spike_mm = self.spike_mm, 0.0
                return displacement + spike
            if self.stuck_until is not None:
                if tick < self.stuck_until:
                    if self.stuck_value is None:
                        self.stuck_value = displacement
                    return self.stuck_value
                self.stuck_until = self.stuck_value = None
        return displacement

    def measured_force(self, axis: int, tick: int, force: float) -> float:
        """What axis ``axis``'s load cell reports (faults apply to axis 0)."""
        if axis != 0:
            return force
        with self._lock:
            if self.fnan:
                self.fnan = False
                return math.nan
            if self.fspike_kN:
                spike, self.fspike_kN = self.fspike_kN, 0.0
                return force + spike
            if self.fstuck_until is not None:
                if tick < self.fstuck_until:
                    if self.fstuck_value is None:
                        self.fstuck_value = force
                    return self.fstuck_value
                self.fstuck_until = self.fstuck_value = None
        return force

    def take_warn(self) -> int | None:
        """The code of a warning EMCY that fell due (once), or None."""
        with self._lock:
            code, self.warn_code = self.warn_code, None
            return code

    def take_valve(self) -> bool:
        with self._lock:
            v, self.valve = self.valve, False
            return v

    @property
    def total(self) -> int:
        return sum(self.injected.values())


def _number(item: str, text: str, kind=float, low=0.0, high=math.inf):
    try:
        value = kind(text)
    except ValueError:
        raise ConfigError(f"--faults {item!r}: {text!r} is not a {'whole number' if kind is int else 'number'}") from None
    if not (math.isfinite(value) and low <= value <= high):
        raise ConfigError(f"--faults {item!r}: {text} is not in {low:g}..{high:g}")
    return value


def parse(spec: str) -> FaultSchedule:
    """A SPEC string (see the module's docstring) as a schedule; an empty SPEC, an empty item or a
    bad one is a ConfigError quoting the item as given."""
    faults: list[Fault] = []
    rnd: dict[str, tuple[str, str]] = {}  # key -> (the item as given, its value)
    if len(spec) > 100_000:
        raise ConfigError(f"--faults: SPEC of {len(spec)} characters is too long (at most 100000)")
    if not spec.strip():
        raise ConfigError(f"--faults {spec!r}: empty SPEC; give items such as 'drop@3000' or 'seed=7,every=2000' "
                          "separated by commas (docs/faults.md)")
    for n, item in enumerate((s.strip() for s in spec.split(",")), 1):
        if not item:
            raise ConfigError(f"--faults {spec!r}: item {n} is empty (a comma at the start or the end, or two "
                              "in a row)")
        if "=" in item:
            key, _, value = item.partition("=")
            key = key.strip()
            if key not in ("seed", "every", "kinds", "until"):
                raise ConfigError(f"--faults {item!r}: unknown key {key!r}; known: seed, every, kinds, until")
            if key in rnd:
                raise ConfigError(f"--faults {item!r}: {key} is given twice (also {rnd[key][0]!r}); give it once")
            rnd[key] = (item, value.strip())
            continue
        kind, at, rest = item.partition("@")
        kind = kind.strip()
        if kind not in KINDS:
            raise ConfigError(f"--faults {item!r}: unknown fault {kind!r}; known: {', '.join(KINDS)}")
        if not at:
            raise ConfigError(f"--faults {item!r}: expected KIND@TICK or KIND@TICK:ARG")
        tick_text, _, arg_text = rest.partition(":")
        tick = _number(item, tick_text.strip(), int, 0, MAX_TICK)
        if kind == "warn":
            arg = KINDS[kind] if not arg_text else float(_emcy_code(item, arg_text.strip()))
        else:
            arg_kind = int if kind in TICK_ARGS else float  # stuck:N, fstuck:N count ticks
            arg = KINDS[kind] if not arg_text else float(_number(item, arg_text.strip(), arg_kind, 0, _arg_max(kind)))
        faults.append(Fault(kind, tick, arg))
        if len(faults) > MAX_FAULTS:
            raise ConfigError(f"--faults: more than {MAX_FAULTS} faults")
    if rnd:
        def number(key, default, kind, low, high):
            item, value = rnd.get(key, (f"{key}={default}", str(default)))
            return _number(item, value, kind, low, high)

        item, value = rnd.get("kinds", ("", "+".join(RECOVERABLE)))
        faults += random_faults(
            seed=number("seed", 0, int, 0, 2**32 - 1),
            every=number("every", 1000, int, 10, MAX_TICK),
            kinds=_kinds(item, value),
            until=number("until", 10**7, int, 1, MAX_TICK),
        )
    return FaultSchedule(faults)


def _arg_max(kind: str) -> float:
    return {"delay": MAX_DELAY_S, "spike": 1e30, "stuck": MAX_TICK, "fspike": 1e30, "fstuck": MAX_TICK}.get(kind, 0.0)


def _emcy_code(item: str, text: str) -> int:
    """warn's ARG: an EMCY error code (:func:`hsio.drivers.common.emcy_code`)."""
    from hsio.drivers.common import emcy_code

    try:
        return emcy_code(text)
    except ValueError as exc:
        raise ConfigError(f"--faults {item!r}: {exc}") from None


def _kinds(item: str, text: str) -> tuple[str, ...]:
    """The kinds of ``kinds=K1+K2+...`` (``item`` as given), each a known one."""
    kinds = tuple(k.strip() for k in text.split("+"))
    if not any(kinds):
        raise ConfigError(f"--faults {item!r}: no kind given; known: {', '.join(KINDS)}")
    if not all(kinds):
        raise ConfigError(f"--faults {item!r}: an empty kind (a '+' at the start or the end, or two in a row)")
    bad = [k for k in kinds if k not in KINDS]
    if bad:
        raise ConfigError(f"--faults {item!r}: unknown fault(s) {', '.join(map(repr, bad))}; known: {', '.join(KINDS)}")
    return kinds


def check_transport(schedule: "FaultSchedule | None", transport: str) -> None:
    """Refuse, before the emulator serves, a kind its transport does not have (``warn`` is
    CANopen's): a ConfigError naming the kind, its tick and both transports."""
    if not schedule:
        return
    names = {"canopen": "CANopen", "modbus": "Modbus"}
    for f in schedule.faults:
        only = TRANSPORT_ONLY.get(f.kind)
        if only is not None and only != transport:
            here = names.get(transport, transport)
            raise ConfigError(f"--faults: {f.kind!r} (at tick {f.tick}) is a {names[only]} fault (a warning EMCY), "
                              f"which a {here} controller cannot send; refused over {here} (its kinds: "
                              f"{', '.join(k for k in KINDS if TRANSPORT_ONLY.get(k, transport) == transport)})")


def random_faults(seed: int, every: int, kinds=RECOVERABLE, until: int = 10**7, start: int = 0) -> list[Fault]:
    """A seeded schedule: one fault every ``every`` ticks on average, up to ``until``."""
    rng = random.Random(seed)
    out, tick = [], start
    while True:
        tick += rng.randint(max(every // 2, 1), max(3 * every // 2, 1))
        if tick > until:
            return out
        if len(out) == MAX_FAULTS:  # refused, not cut short: the faults would end long before until
            raise ConfigError(f"--faults: a fault every {every} ticks up to tick {until} is more than {MAX_FAULTS} "
                              f"faults (the {MAX_FAULTS}th falls at tick {out[-1].tick}); give a larger every= or a "
                              "smaller until=")
        kind = rng.choice(kinds)
        out.append(Fault(kind, tick, KINDS[kind]))
