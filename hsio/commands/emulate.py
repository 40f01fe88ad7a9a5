"""`hsio emulate`: serve an emulated servo controller over Modbus TCP, Modbus RTU or CANopen
until interrupted.

The controller has one axis per experimental element of the structure in CONFIG (the same TOML
file as `hsio run`: [structure] name, [emulator] settings), so `hsio emulate modbus CONFIG` and
`hsio run CONFIG` with [hardware] url = "modbus+tcp://127.0.0.1:5020" are the lab-like pair.
The clock follows CONFIG's [hardware] clock (lockstep or realtime) unless --clock says otherwise.
"""

from __future__ import annotations

import sys

import click
from click.core import ParameterSource

from hsio.commands import BindAddress, RegularFile, stop_requested, wait_for_stop
from hsio.errors import HsioError


def _common(func):
    func = click.option("--faults", "faults_spec", default=None, metavar="SPEC",
                        help="Inject faults on a seeded schedule, e.g. 'drop@3000,spike@5000:40' or "
                             "'seed=7,every=2000' (docs/faults.md).")(func)
    func = click.option("--set", "settings", multiple=True, metavar="KEY=VALUE",
                        help="Override an [emulator] setting (repeatable), e.g. --set lag_s=0.03.")(func)
    func = click.option("--watchdog-s", default=1.0, show_default=True, type=float,
                        help="Hold an axis when the host stays silent longer than this (0: off).")(func)
    func = click.option("--watch-holding", is_flag=True,
                        help="The watchdog also watches holding axes (strict: a host that stops feeding it "
                             "during a pause trips it; docs/safety.md).")(func)
    func = click.option("--clock", type=click.Choice(["config", "lockstep", "realtime"]), default="config",
                        show_default=True, help="Lockstep (advanced by the host) or real time (own 1024 Hz loop).")(func)
    func = click.argument("config_file", required=False, type=RegularFile())(func)
    return func


def bank_from_config(config_path: str | None, lockstep: bool, watchdog_s: float = 1.0,
                     overrides: dict | None = None):
    """An emulated controller with one axis per experimental element and one per static preload
    of the structure in an ``hsio run`` configuration, named as the structure file names its
    actuators (elements loaded through setups are refused: their actuators share a specimen).

    Each axis gets the [emulator] settings and its own noise seed (seed + index), exactly as the
    in-process emulator (``emulator://``) builds them, so both give the same controller. The
    core reads the configuration and the structure; the emulator gets only the actuators.
    """
    from hsio import config as config_mod
    from hsio.emulators.bank import ControllerBank
    from hsio.emulators.servo import make_controllers
    from hsio.interfaces import ActuatorSpec
    from hsio.diagnose.modelfile import merged_emulator_table
    from hsio.runner import load_run_structure

    from hsio.errors import ConfigError

    cfg = config_mod.load(config_path)
    structure = load_run_structure(cfg)
    rigged = [e.name for e in structure.experimental if e.has_setup or e.is_multi_dof]
    if rigged:
        raise ConfigError(f"structure {structure.name!r}: element(s) {', '.join(rigged)} are loaded through a setup "
                          "(several actuators on one specimen); hsio emulate serves independent axes only: run such "
                          "a structure on emulator:// (docs/setups.md)")
    # one axis per element, then one per static preload: the order in which a run opens them
    specs = [ActuatorSpec(e.actuator, e.specimen) for e in (*structure.experimental, *structure.static)]
    table = merged_emulator_table(cfg["hardware"]["actuator_model"], cfg["emulator"])  # as emulator:// does
    controllers = make_controllers(specs, {**table, **(overrides or {})})
    return ControllerBank(controllers, [s.name for s in specs], lockstep, watchdog_s)


def instruments_from_config(config_path: str | None, bank):
    """The structure's external instruments, emulated on the bank's axes, and the DAQ map they are
    served at ([driver] instrument_map, or hsio's): served on the controller's own device, one
    wire for actuators and instruments (docs/setups.md). None for a structure without any."""
    from hsio import config as config_mod
    from hsio.drivers.modbus_daq import load_daq_map
    from hsio.emulators.local import EmulatedInstruments
    from hsio.runner import load_run_structure

    cfg = config_mod.load(config_path)
    structure = load_run_structure(cfg)
    if not structure.instruments:
        return None
    controllers = dict(zip(structure.experimental_names, bank.controllers))
    return EmulatedInstruments(structure.instruments, controllers), load_daq_map(cfg["driver"].get("instrument_map"))


def _with_instruments(emulator, config_file):
    """``emulator`` (a ModbusEmulator, not started) serving the configuration's instruments too."""
    found = instruments_from_config(config_file, emulator.bank)
    if found is not None:
        emulator.context.add_instruments(*found)
    return emulator


def _bank(config_file, clock, watchdog_s, settings, faults_spec=None, watch_holding=False):
    from hsio.emulators.bank import parse_settings
    from hsio.emulators.faults import parse
    from hsio import config as config_mod
    from hsio.errors import ConfigError

    if not (watchdog_s >= 0 and watchdog_s <= 3600):
        raise ConfigError(f"--watchdog-s {watchdog_s!r}: must be within 0..3600 s")
    if watch_holding and watchdog_s == 0:
        raise ConfigError("--watch-holding needs a watchdog: give --watchdog-s above 0")
    schedule = parse(faults_spec) if faults_spec is not None else None  # given empty: refused by name
    if clock == "config":
        clock = config_mod.load(config_file)["hardware"]["clock"]
    bank = bank_from_config(config_file, lockstep=(clock == "lockstep"), watchdog_s=watchdog_s,
                            overrides=parse_settings(settings))
    bank.faults = schedule
    bank.watch_holding = bool(watch_holding)
    return bank


def _instrument_line(emulator) -> list[str]:
    daq = getattr(emulator.context, "instrument_daq", None)
    if daq is None:
        return []
    inputs = ", ".join(f"{i.name} ({r.name} at {r.address})" for i, r in zip(daq.instruments, emulator.context.instrument_map.inputs))
    return [f"daq       {inputs}"]


def _fault_line(bank) -> list[str]:
    f = bank.faults
    if not f:
        return []
    return [f"faults    {len(f.faults)} scheduled, first at tick {f.faults[0].tick} (docs/faults.md)"]


def _serve(emulator, bank, lines: list[str]) -> None:
    done = stop_requested()
    for line in lines:
        click.echo(line)
    click.echo(f"axes      {', '.join(bank.names)}")
    click.echo(f"clock     {'lockstep (advanced by the host)' if bank.lockstep else 'real time, %g Hz' % bank.rate_hz}")
    strict = ", holding axes watched too" if bank.watch_holding else ""
    click.echo(f"watchdog  {bank.watchdog_s:g} s{strict}" if bank.watchdog_s else "watchdog  off")
    click.echo("Ctrl-C stops the emulator.")
    sys.stdout.flush()
    try:
        wait_for_stop(done)
    finally:
        emulator.stop()
        if bank.faults:
            done_kinds = ", ".join(f"{k} {n}" for k, n in sorted(bank.faults.injected.items()))
            click.echo(f"faults    injected {bank.faults.total}: {done_kinds or 'none'}")
        click.echo("emulator stopped; the axes hold.")


@click.group()
def emulate() -> None:
    """Serve an emulated servo controller over a real protocol until interrupted."""


@emulate.command("modbus")
@click.option("--host", default="127.0.0.1", show_default=True, type=BindAddress(), help="Address to bind (127.0.0.1: this machine only).")
@click.option("--port", default=5020, show_default=True, type=int, help="TCP port (0: any free port; the banner shows the one bound).")
@click.option("--map", "map_file", default=None, type=click.Path(dir_okay=False), help="Register map TOML (default: hsio's).")
@_common
def modbus_tcp(host, port, map_file, config_file, clock, watchdog_s, watch_holding, settings, faults_spec) -> None:
    """Modbus TCP server (pymodbus) on HOST:PORT."""
    from hsio.drivers import modbus_map
    from hsio.emulators.modbus import ModbusEmulator

    try:
        if not 0 <= port <= 65535:
            raise click.BadParameter(f"{port} is not in 0..65535", param_hint="--port")
        bank = _bank(config_file, clock, watchdog_s, settings, faults_spec, watch_holding)
        emulator = _with_instruments(ModbusEmulator(bank, modbus_map.load(map_file), "tcp", host=host, port=port),
                                     config_file).start()
    except (HsioError, RuntimeError, ValueError, OSError) as exc:
        click.echo(f"hsio emulate modbus: error: {exc}", err=True)
        sys.exit(2)
    _serve(emulator, bank, [f"url       {emulator.url}", f"map       {emulator.map.name} ({emulator.map.source})",
                            *_instrument_line(emulator), *_fault_line(bank)])


@emulate.command("modbus-rtu")
@click.option("--baudrate", default=115200, show_default=True, type=click.IntRange(1, 10_000_000))
@click.option("--map", "map_file", default=None, type=click.Path(dir_okay=False), help="Register map TOML (default: hsio's).")
@_common
def modbus_rtu(baudrate, map_file, config_file, clock, watchdog_s, watch_holding, settings, faults_spec) -> None:
    """Modbus RTU server on a pseudo-terminal; prints the pty path for the client."""
    from hsio.drivers import modbus_map
    from hsio.emulators.modbus import ModbusEmulator

    try:
        bank = _bank(config_file, clock, watchdog_s, settings, faults_spec, watch_holding)
        emulator = _with_instruments(ModbusEmulator(bank, modbus_map.load(map_file), "rtu", baudrate=baudrate),
                                     config_file).start()
    except (HsioError, RuntimeError, ValueError, OSError) as exc:
        click.echo(f"hsio emulate modbus-rtu: error: {exc}", err=True)
        sys.exit(2)
    _serve(emulator, bank, [f"pty       {emulator.path}", f"url       {emulator.url}",
                            f"map       {emulator.map.name} ({emulator.map.source})", *_instrument_line(emulator),
                            *_fault_line(bank)])


@emulate.command("canopen")
@click.option("--channel", default="", help="python-can channel (virtual bus: shared inside one process only).")
@click.option("--interface", default="virtual", show_default=True, help="python-can interface (virtual, socketcan, ...).")
@click.option("--slcan", type=click.Choice(["pty", "tcp"]), default=None,
              help="Serve the bus as a Lawicel (SLCAN) adapter another process opens: on a pseudo-terminal, or on "
                   "a TCP port of 127.0.0.1 (socket://). Replaces --channel/--interface (docs/canopen.md).")
@click.option("--port", default=0, show_default=True, type=click.IntRange(0, 65535), help="TCP port for --slcan tcp (0: any free port).")
@click.option("--node-id", default=1, show_default=True, type=click.IntRange(1, 127), help="Node id of axis 0 (axis k: +k).")
@click.option("--heartbeat-ms", default=100, show_default=True, type=click.IntRange(0, 65535))
@_common
def canopen_cmd(channel, interface, slcan, port, node_id, heartbeat_ms, config_file, clock, watchdog_s, watch_holding,
                settings,
                faults_spec) -> None:
    """CiA 402 drives (canopen LocalNode) on a python-can bus, or on an SLCAN port for another process."""
    from hsio.emulators.canopen import CanopenEmulator, slcan_emulator

    if port and slcan != "tcp":  # an option that would do nothing is refused, not ignored
        raise click.BadParameter(f"--port {port} is the TCP port of --slcan tcp; it is not used "
                                 f"{'with --slcan pty' if slcan else 'without --slcan'}", param_hint="--port")
    if slcan and channel:
        raise click.BadParameter(f"--channel {channel!r} is not used with --slcan {slcan} (it serves its own bus)",
                                 param_hint="--channel")
    if slcan and click.get_current_context().get_parameter_source("interface") is not ParameterSource.DEFAULT:
        raise click.BadParameter(f"--interface {interface!r} is not used with --slcan {slcan} (it serves its own bus)",
                                 param_hint="--interface")
    try:
        bank = _bank(config_file, clock, watchdog_s, settings, faults_spec, watch_holding)
        if slcan:
            emulator = slcan_emulator(bank, slcan, node_id, port=port, heartbeat_ms=heartbeat_ms)
        else:
            if not channel:
                raise click.BadParameter("give --channel (or --slcan pty|tcp to reach the bus from another process)")
            emulator = CanopenEmulator(bank, channel, node_id, interface, heartbeat_ms).start()
    except click.BadParameter:
        raise
    except Exception as exc:  # python-can raises various errors for a missing interface
        click.echo(f"hsio emulate canopen: error: {exc}", err=True)
        sys.exit(2)
    lines = [f"url       {emulator.url}", f"nodes     {node_id}..{node_id + len(bank.controllers) - 1}"]
    if slcan:
        lines.insert(0, f"slcan     {emulator.slcan.path}")
    _serve(emulator, bank, lines + _fault_line(bank))
