"""The `hsio` console command (``[project.scripts]``): Ctrl-C while the program starts.

Python raises KeyboardInterrupt wherever a SIGINT finds it; while the program imports numpy,
click or a driver that tears the import apart and ends in a traceback from deep inside a
library. So from its first line until a command is ready to answer it, `hsio` notes a SIGINT
instead of raising it:

* `hsio run` and `hsio resume` take it as a stop asked before the first step (exit 5, nothing
  moved; :func:`hsio.safety.control.stop_on_signals`);
* the serving commands (`hsio serve opensees`, `hsio emulate`) as a stop asked as soon as they
  are ready (:func:`hsio.commands.stop_requested`): what they opened closes as on any stop;
* every other command gets Python's own handling back before it starts (:func:`release`), and a
  SIGINT noted meanwhile is raised there (click reports "Aborted!").

A second SIGINT during start-up is raised at once, wherever it lands: the way out of a start-up
that hangs. A process started with SIGINT ignored (a background job of a script, a service) is
left alone: nothing is noted and SIGINT stays ignored, during a run too (SIGTERM stops it).
"""

from __future__ import annotations

import signal

_noted: list[int] = []
_previous = None
_program = False


def _note(signum, frame) -> None:
    if _noted:
        raise KeyboardInterrupt
    _noted.append(signum)


def main():
    global _previous, _program
    _program = True
    _previous = signal.getsignal(signal.SIGINT)
    if _previous is not signal.SIG_IGN:
        signal.signal(signal.SIGINT, _note)
    import matplotlib

    matplotlib.use("Agg")  # the command line writes its plots to files, never to a window
    from hsio.cli import main as cli

    return cli()


def noted_interrupt() -> bool:
    """Whether a SIGINT came while the program started (each one is reported once)."""
    hit = bool(_noted)
    _noted.clear()
    return hit


def started_ignoring_sigint() -> bool:
    """Whether the program was started with SIGINT ignored (then it keeps ignoring it)."""
    return _previous is signal.SIG_IGN


def running_as_program() -> bool:
    """Whether hsio runs as the `hsio` program (:func:`main`), not as a command called in process."""
    return _program


def after_start_up(handler):
    """The SIGINT handler to put back where ``handler`` was: Python's own for the start-up's."""
    if handler is not _note:
        return handler
    return _previous if _previous is not None else signal.default_int_handler


def release() -> None:
    """Give SIGINT back to Python; one noted during start-up is raised now, as KeyboardInterrupt."""
    if signal.getsignal(signal.SIGINT) is _note:
        signal.signal(signal.SIGINT, after_start_up(_note))
    if noted_interrupt():
        raise KeyboardInterrupt
