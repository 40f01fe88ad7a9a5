"""`hsio monitor RUN_DIR`: the live page of a run in progress, or the replay of a recorded run."""

from __future__ import annotations

import contextlib
import sqlite3
import sys
import time
from pathlib import Path

import click

from hsio.errors import HsioError
from hsio.recording import RUN_FILE, RecordError, Run, being_written, connect_read_only

CREATION_S = 0.5  # more than a run takes between creating its record's file and locking it


def _refuse_foreign_record(path: Path) -> None:
    """A record no run is writing is all there will be: it is refused before the page is served
    if :class:`~hsio.recording.Run` does not read it (damaged, of another kind, or a run killed as
    it created its record: the page would wait for it for ever), naming the file and what is
    wrong. A record a run is writing (or being created: it may hold no tables yet) is followed;
    where it cannot be told whether one is, a file that SQLite cannot read is refused, and a
    finished record (one with a summary) that Run does not read whole. Nor is a file that is not
    a regular file (a FIFO would block the reader for ever)."""
    if path.exists() and not path.is_file():
        raise HsioError(f"{path}: not a regular file, so not an hsio recording")
    if not path.is_file():
        return
    writing = being_written(path)
    if writing is False:
        try:
            Run(path, read=False)  # a RecordError names what is wrong (the steps not read into memory)
        except RecordError:
            time.sleep(CREATION_S)  # a run that had just made the file and not yet locked it: it has now
            if being_written(path) is False:
                raise
        return
    if writing or path.stat().st_size == 0:
        return
    try:
        with contextlib.closing(connect_read_only(path)) as db:
            db.execute("SELECT name FROM sqlite_master").fetchall()
            finished = db.execute("SELECT name FROM sqlite_master WHERE type = 'table' AND name = 'summary'").fetchone() \
                and db.execute("SELECT 1 FROM summary LIMIT 1").fetchone()
    except sqlite3.DatabaseError as exc:
        raise HsioError(f"{path}: not an hsio recording ({exc})") from None
    if finished:
        Run(path, read=False)


def _point_to_run_folders(folder: Path) -> None:
    """A folder with no record that holds run folders (runs/validation, not runs/validation/run-0007)
    is watched all the same, but the operator is told where the records are."""
    if (folder / RUN_FILE).exists():
        return
    try:
        runs = sorted(p.name for p in folder.iterdir() if (p / RUN_FILE).is_file())
    except OSError:
        return
    if runs:
        shown = ", ".join(runs[-3:]) + (f" (and {len(runs) - 3} more)" if len(runs) > 3 else "")
        click.echo(f"hsio monitor: {folder} holds no {RUN_FILE} but run folders with one: {shown}; "
                   "watching it for a run to start there", err=True)


@click.command()
@click.argument("run_dir", type=click.Path(file_okay=False, exists=True))
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on. Any address but the loopback requires the token printed at start-up.")
@click.option("--port", default=8765, show_default=True, type=click.IntRange(0, 65535),
              help="Port to listen on (0: any free port).")
@click.option("--token", default=None, help="The token asked of browsers when not on the loopback: letters, digits and - _ . ~ "
                   "(default: a new random one).")
def monitor(run_dir: str, host: str, port: int, token: str | None) -> None:
    """Serve the monitor page of the run in RUN_DIR (docs/monitor.md).

    A finished record is replayed; a run in progress is followed as it commits steps, and its
    pause, resume and stop buttons reach the run's control socket. A folder with no record yet is
    watched until the run creates it (`hsio run --monitor` does this). Stop with Ctrl-C.
    """
    from hsio.monitor.server import serve

    def announce(line: str) -> None:
        click.echo(line)
        sys.stdout.flush()

    try:
        _refuse_foreign_record(Path(run_dir) / RUN_FILE)
        _point_to_run_folders(Path(run_dir))
        serve(run_dir, host=host, port=port, token=token, announce=announce)
    except HsioError as exc:
        click.echo(f"hsio monitor: error: {exc}", err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        pass
