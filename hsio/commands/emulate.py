"""`hsio emulate`: serve an emulated servo controller over Modbus TCP, Modbus RTU or CANopen
until interrupted.

The controller has one axis per experimental element of the structure in CONFIG (the same TOML
file as `hsio run`: [structure] name, [emulator] settings), so `hsio emulate modbus CONFIG` and
`hsio run CONFIG` with [hardware] url = "modbus+tcp://127.0.0.1:5020" are the lab-like pair.
The clock follows CONFIG's [hardware] clock (lockstep or realtime) unless --clock says otherwise.
"""

from __future__ import annotations

import signal
import sys
import threading

import click

from hsio.errors import HsioError


def _common(func):
    func = click.option("--set", "settings", multiple=True, metavar="KEY=VALUE",
                        help="Override an [emulator] setting (repeatable), e.g. --set lag_s=0.03.")(func)
    func = click.option("--watchdog-s", default=1.0, show_default=True, type=float,
                        help="Hold an axis when the host stays silent longer than this (0: off).")(func)
    func = click.option("--clock", type=click.Choice(["config", "lockstep", "realtime"]), default="config",
                        show_default=True, help="Lockstep (advanced by the host) or real time (own 1024 Hz loop).")(func)
    func = click.argument("config_file", required=False, type=click.Path(dir_okay=False))(func)
    return func


def _bank(config_file, clock, watchdog_s, settings):
    from hsio.emulators.bank import bank_from_config, parse_settings
    from hsio import config as config_mod

    if clock == "config":
        clock = config_mod.load(config_file)["hardware"]["clock"]
    return bank_from_config(config_file, lockstep=(clock == "lockstep"), watchdog_s=watchdog_s,
                            overrides=parse_settings(settings))


def _serve(emulator, bank, lines: list[str]) -> None:
    for line in lines:
        click.echo(line)
    click.echo(f"axes      {', '.join(bank.names)}")
    click.echo(f"clock     {'lockstep (advanced by the host)' if bank.lockstep else 'real time, %g Hz' % bank.rate_hz}")
    click.echo(f"watchdog  {bank.watchdog_s:g} s" if bank.watchdog_s else "watchdog  off")
    click.echo("Ctrl-C stops the emulator.")
    sys.stdout.flush()
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    try:
        while not done.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()
        click.echo("emulator stopped; the axes hold.")


@click.group()
def emulate() -> None:
    """Serve an emulated servo controller over a real protocol until interrupted."""


@emulate.command("modbus")
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to bind (127.0.0.1: this machine only).")
@click.option("--port", default=5020, show_default=True, type=int, help="TCP port (0: any free port; the banner shows the one bound).")
@click.option("--map", "map_file", default=None, type=click.Path(dir_okay=False), help="Register map TOML (default: hsio's).")
@_common
def modbus_tcp(host, port, map_file, config_file, clock, watchdog_s, settings) -> None:
    """Modbus TCP server (pymodbus) on HOST:PORT."""
    from hsio.drivers import modbus_map
    from hsio.emulators.modbus import ModbusEmulator

    try:
        bank = _bank(config_file, clock, watchdog_s, settings)
        emulator = ModbusEmulator(bank, modbus_map.load(map_file), "tcp", host=host, port=port).start()
    except (HsioError, RuntimeError, ValueError) as exc:
        click.echo(f"hsio emulate modbus: error: {exc}", err=True)
        sys.exit(2)
    _serve(emulator, bank, [f"url       {emulator.url}", f"map       {emulator.map.name} ({emulator.map.source})"])


@emulate.command("modbus-rtu")
@click.option("--baudrate", default=115200, show_default=True, type=int)
@click.option("--map", "map_file", default=None, type=click.Path(dir_okay=False), help="Register map TOML (default: hsio's).")
@_common
def modbus_rtu(baudrate, map_file, config_file, clock, watchdog_s, settings) -> None:
    """Modbus RTU server on a pseudo-terminal; prints the pty path for the client."""
    from hsio.drivers import modbus_map
    from hsio.emulators.modbus import ModbusEmulator

    try:
        bank = _bank(config_file, clock, watchdog_s, settings)
        emulator = ModbusEmulator(bank, modbus_map.load(map_file), "rtu", baudrate=baudrate).start()
    except (HsioError, RuntimeError, ValueError, OSError) as exc:
        click.echo(f"hsio emulate modbus-rtu: error: {exc}", err=True)
        sys.exit(2)
    _serve(emulator, bank, [f"pty       {emulator.path}", f"url       {emulator.url}",
                            f"map       {emulator.map.name} ({emulator.map.source})"])


@emulate.command("canopen")
@click.option("--channel", required=True, help="CAN channel name (virtual bus: shared inside one process only).")
@click.option("--interface", default="virtual", show_default=True, help="python-can interface (virtual, socketcan, ...).")
@click.option("--node-id", default=1, show_default=True, type=click.IntRange(1, 127), help="Node id of axis 0 (axis k: +k).")
@click.option("--heartbeat-ms", default=100, show_default=True, type=int)
@_common
def canopen_cmd(channel, interface, node_id, heartbeat_ms, config_file, clock, watchdog_s, settings) -> None:
    """CiA 402 drives (canopen LocalNode) on a python-can bus."""
    from hsio.emulators.canopen import CanopenEmulator

    try:
        bank = _bank(config_file, clock, watchdog_s, settings)
        emulator = CanopenEmulator(bank, channel, node_id, interface, heartbeat_ms).start()
    except Exception as exc:  # python-can raises various errors for a missing interface
        click.echo(f"hsio emulate canopen: error: {exc}", err=True)
        sys.exit(2)
    _serve(emulator, bank, [f"url       {emulator.url}", f"nodes     {node_id}..{node_id + len(bank.controllers) - 1}"])
