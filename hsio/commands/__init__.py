"""The `hsio` subcommands, each in its own module (imported only when it runs)."""

from __future__ import annotations

import math
import os
import signal
import threading

import click


class RegularFile(click.Path):
    """A path to a regular file: a directory, a device (/dev/zero) or a FIFO, which would be read
    for ever, is refused naming it."""

    def __init__(self, **kwargs):
        super().__init__(dir_okay=False, **kwargs)

    def convert(self, value, param, ctx):
        path = super().convert(value, param, ctx)
        if os.path.exists(path) and not os.path.isfile(path):
            self.fail(f"{os.fsdecode(path)!r} is not a regular file", param, ctx)
        return path


class BindAddress(click.ParamType):
    """The address a server binds: an empty one (an unset variable, a typing error) would bind every
    interface and is refused; 0.0.0.0 says so on purpose."""

    name = "address"

    def convert(self, value, param, ctx):
        if not str(value).strip():
            self.fail("the address to bind is empty: give one (127.0.0.1, this machine; 0.0.0.0, every interface)",
                      param, ctx)
        return value


class PlotFile(click.Path):
    """The file a figure is written to, its format named by its extension. A format matplotlib
    cannot write is refused before any work starts, naming those it can; a name without an
    extension gets ``.png`` so that the path the command prints is the file written (matplotlib
    would add it silently). The value is the path to write to."""

    name = "plot file"

    def __init__(self, **kwargs):
        super().__init__(dir_okay=False, **kwargs)

    def convert(self, value, param, ctx):
        path = os.fsdecode(super().convert(value, param, ctx))
        folder, name = os.path.split(path)
        ext = os.path.splitext(name)[1]
        if not name.strip("."):
            self.fail(f"{path!r} names no file", param, ctx)
        if not ext.strip("."):  # no extension, or a trailing dot
            return os.path.join(folder, name.rstrip(".") + ".png")
        fmt = ext[1:].lower()
        formats = plot_formats()
        if fmt == "pgf" and fmt not in formats:
            import matplotlib

            self.fail(f"{path!r}: matplotlib writes .pgf with {matplotlib.rcParams['pgf.texsystem']}, which is not "
                      "installed", param, ctx)
        if fmt not in formats:
            self.fail(f"{path!r}: format {ext[1:]!r} is not one matplotlib writes; give a file ending in one "
                      f"of {', '.join('.' + f for f in formats)} (or none, for .png)", param, ctx)
        return path


def plot_formats() -> list[str]:
    """The file formats (extensions) matplotlib writes a figure in: pgf only where the TeX it runs
    is installed."""
    import shutil

    import matplotlib
    from matplotlib.backend_bases import FigureCanvasBase

    formats = set(FigureCanvasBase.get_supported_filetypes())
    if shutil.which(matplotlib.rcParams["pgf.texsystem"]) is None:
        formats.discard("pgf")
    return sorted(formats)


def refuse_repeated_options(command: click.Command) -> click.Command:
    """An option that takes one value and is given twice is refused naming it (click would keep the
    last one silently: ``--out a --out b`` writes to b); flags and repeatable options are not
    concerned. So is a number option given as nan or inf (click's float types take them). A group
    passes the guard on to its subcommands."""
    if getattr(command, "_refuses_repeats", False):
        return command
    command._refuses_repeats = True
    if isinstance(command, click.Group):
        get_command = command.get_command

        def guarded_get_command(ctx, name):
            sub = get_command(ctx, name)
            return refuse_repeated_options(sub) if sub is not None else None

        command.get_command = guarded_get_command
        return command
    single = {name: p for p in command.params if isinstance(p, click.Option)
              and not (p.multiple or p.is_flag or p.count) for name in p.opts}
    parse_args = command.parse_args

    def guarded_parse_args(ctx, args):
        seen: dict[str, str] = {}
        for arg in args:
            if arg == "--":
                break
            name = arg.partition("=")[0]
            option = single.get(name)
            if option is None:
                continue
            if option.name in seen:
                raise click.UsageError(f"option {name} is given twice; give it once", ctx)
            seen[option.name] = name
        rest = parse_args(ctx, args)
        for param in command.params:
            if not isinstance(param.type, click.types.FloatParamType):
                continue
            given = ctx.params.get(param.name)
            values = given if isinstance(given, (tuple, list)) else (given,)
            for value in values:
                if isinstance(value, float) and not math.isfinite(value):
                    raise click.BadParameter(f"{value} is not a finite number", ctx=ctx, param=param)
        return rest

    command.parse_args = guarded_parse_args
    return command


def output_error(exc: OSError, what: str = "") -> str:
    """An output file or folder that cannot be written, as a line naming it and why."""
    where = exc.filename if exc.filename is not None else what
    return f"{os.fsdecode(where) if where is not None else ''}: cannot write {what or 'it'}: {exc.strerror or exc}"


def stop_requested() -> threading.Event:
    """An event set by SIGTERM or SIGINT (Ctrl-C). A serving command installs it before it says it
    is ready, so that a signal sent as soon as the banner appears stops it cleanly."""
    from hsio.entry import noted_interrupt, started_ignoring_sigint

    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    if not started_ignoring_sigint():  # started with SIGINT ignored (a background job): it stays so
        signal.signal(signal.SIGINT, lambda *_: done.set())
    if noted_interrupt():  # Ctrl-C while the program started (hsio.entry): stop once ready
        done.set()
    return done


def wait_for_stop(done: threading.Event, poll_s: float = 0.5) -> None:
    """Block until ``done`` (from :func:`stop_requested`) is set: how a serving command (an
    emulator, a site server) waits for its operator."""
    try:
        while not done.wait(poll_s):
            pass
    except KeyboardInterrupt:
        pass
