"""`hsio serve opensees CONFIG`: serve experimental elements to OpenSees' genericClient elements.

CONFIG is a `hsio run` configuration ([structure], [hardware], [test], [emulator], ...) with an
[opensees] table naming the elements served (docs/opensees.md). Each element listens on its own
port, printed at start-up; the server runs until interrupted.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from hsio.commands import BindAddress, RegularFile, stop_requested, wait_for_stop
from hsio.errors import HsioError


@click.group()
def serve() -> None:
    """Serve hsio's actuators to other programs."""


@serve.command("opensees")
@click.argument("config_file", type=RegularFile())
@click.option("--host", default="127.0.0.1", show_default=True, type=BindAddress(), help="Address to bind (127.0.0.1: this machine only).")
@click.option("--port", default=8090, show_default=True, type=click.IntRange(0, 65535),
              help="Port of the first element; the next elements take the next ports (0: any free ports).")
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False),
              help="Folder for the session records (default: [opensees] out).")
def opensees(config_file: str, host: str, port: int, out_dir: str | None) -> None:
    """Serve the [opensees] elements of CONFIG to OpenSees genericClient elements."""
    from hsio.opensees.lab import Lab
    from hsio.opensees.server import OpenSeesServer
    from hsio.opensees.settings import split_config, unread_settings
    from hsio.runner import check_dwell, check_hardware, load_run_structure

    def log(line: str) -> None:
        click.echo(f"hsio serve opensees: {line}", err=True)

    try:
        settings, config = split_config(config_file)
        unread = unread_settings(config)
        if unread:
            log(f"{config_file}: {', '.join(unread)} not read by a server (OpenSees sends the motion and "
                "integrates it; no dry run, plots, NS or specimen ledger here)")
        if out_dir is not None:
            settings = type(settings)(**{**settings.__dict__, "out": out_dir})
        structure = load_run_structure(config)
        check_hardware(config)  # before serving: a bad URL would otherwise wait for the first client
        check_dwell(config, structure)  # likewise an average longer than a step's dwell
        try:  # likewise a records folder that cannot be created
            Path(settings.out).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise HsioError(f"{settings.out}: cannot create the records folder: {exc.strerror or exc}") from None
        lab = Lab(settings, config, structure, log=log)
        ports = [0] * lab.n if port == 0 else [port + j for j in range(lab.n)]
        if port and ports[-1] > 65535:
            raise HsioError(f"--port {port}: {lab.n} elements need ports up to {ports[-1]}, beyond 65535")
        server = OpenSeesServer(lab, host, ports, log=log).start()
    except HsioError as exc:
        click.echo(f"hsio serve opensees: error: {exc}", err=True)
        sys.exit(2)
    done = stop_requested()
    f = settings.force_factor
    click.echo(f"structure {lab.structure.name}, hardware {config['hardware']['url']} ({config['hardware']['clock']}), "
               f"TR = {config['test']['rate']:g}")
    click.echo(f"units     model length x {settings.length_factor:g} = mm, model force x {f:g} = kN")
    for j, (name, bound) in enumerate(zip(lab.names, server.ports)):
        dofs = [lab.structure.dof_names[d] for d in lab.structure.experimental[j].basic_dofs]
        basic = f" ({lab.n_basic[j]} basic DOFs, in this order: {', '.join(dofs)})" if lab.n_basic[j] > 1 else ""
        click.echo(f"element {name} on {host}:{bound}{basic}")
    click.echo(f"records   {settings.out}")
    click.echo("Ctrl-C stops the server.")
    sys.stdout.flush()
    try:
        wait_for_stop(done)
    finally:
        server.close()
        click.echo(f"server stopped; {lab.hold_message}.")
