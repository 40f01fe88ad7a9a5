"""Operator control of a run: pause, resume, stop (docs/safety.md section 4).

A :class:`RunControl` takes requests from any thread (the terminal keys, the control socket) and
from signal handlers (SIGTERM, SIGINT); the experiment loop acts on them between two steps
(:meth:`RunControl.checkpoint`): a pause finishes the step, holds the actuators and waits for
resume or stop, for as long as the operator wants; a stop holds the actuators and closes the
record. A second SIGINT while a stop is pending interrupts at once.

While paused, the wait feeds the controllers' host watchdogs every :attr:`RunControl.WAIT_SLICE_S`,
or every quarter of the shortest watchdog time the controllers report where that is shorter,
down to :attr:`RunControl.MIN_SLICE_S` (the site's ``keep_alive`` and ``keep_alive_period_s``: the
axes keep holding), so a pause may last any time; a host that dies stops feeding them, and the
controllers' watchdogs trip as they should. A controller that cannot be reached to feed it is
told and recorded as a trip is (below): its hold cannot be confirmed, and the run stays paused.

While paused, the wait also watches the controllers every :attr:`RunControl.WATCH_S` (the site's
``watch_controllers``: each controller's latched trip, its interlock, its host watchdog, a drive
in FAULT). A trip seen there is told at once (the listeners), recorded as a ``controller_trip``
event with its UTC time, and a resume is refused until the operator acknowledges it
(:meth:`RunControl.request_ack`, recorded as ``acknowledge``): the operator knows of the trip
before resuming, not from the stop of the first command after it.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from datetime import datetime, timezone
from typing import Callable

from hsio.safety.status import OperatorStop

RUNNING, PAUSING, PAUSED, STOPPING = "running", "pausing", "paused", "stopping"


class RunControl:
    """Pause / resume / stop requests, and where the run stands."""

    WAIT_SLICE_S = 0.1  # a paused run wakes this often to look for a stop and feed the watchdogs
    MIN_SLICE_S = 0.005  # however short a controller's watchdog, the wait wakes no more often than this
    WATCH_S = 0.5  # a paused run asks the controllers this often whether they tripped

    def __init__(self):
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self.state = RUNNING
        self.phase = "start-up"  # start-up, NS, ramp-in, HS, ramp-off, closing (ramps: of static preloads)
        self.step = 0
        self.stop_reason = ""
        self._pause_wanted = False
        self.trips: list[str] = []  # controller trips seen during the pauses of this run, as told
        self._unacknowledged: list[str] = []  # trips seen during this pause, not yet acknowledged
        self._acknowledged: list[str] = []  # acknowledgements to record (by the loop's thread)
        self._cancelled: list[str] = []  # pauses a resume cancelled before they took effect, to record
        self.paused_s = 0.0  # wall time spent paused in this run, all pauses
        self.listeners: list[Callable[[str], None]] = []  # told of each pause, resume and stop

    # -- requests (any thread) ------------------------------------------------------------
    def request_pause(self, source: str = "operator") -> str:
        with self._lock:
            if self.state in (STOPPING,):
                return f"error: the run is stopping ({self.stop_reason})"
            self._pause_wanted = True
            if self.state == RUNNING:
                self.state = PAUSING
        self._wake.set()
        return f"ok {self.state}"

    def request_resume(self, source: str = "operator") -> str:
        with self._lock:
            if self.state == STOPPING:
                return f"error: the run is stopping ({self.stop_reason})"
            if self._unacknowledged:
                return (f"error: not resumed: a controller tripped during the pause ({'; '.join(self._unacknowledged)}); "
                        f"acknowledge it first (ack), or stop the run")
            self._pause_wanted = False
            if self.state == PAUSING:
                self.state = RUNNING
                self._cancelled.append(f"pause cancelled by a resume ({source}) before it took effect (phase "
                                       f"{self.phase}, after step {self.step}): nothing was held")
        self._wake.set()
        return f"ok {self.state if self.state != PAUSED else 'resuming'}"

    def request_ack(self, source: str = "operator") -> str:
        """The operator has seen the controller trips reported during the pause: a resume may go on
        (a controller still tripped then stops the run at its first command, as any trip does)."""
        with self._lock:
            if not self._unacknowledged:
                return "error: no controller trip to acknowledge"
            seen, self._unacknowledged = self._unacknowledged, []
            self._acknowledged.append(f"controller trip acknowledged by {source}: {'; '.join(seen)}")
        self._wake.set()
        return "ok acknowledged"

    def request_stop(self, reason: str = "stopped by the operator") -> str:
        with self._lock:
            if self.state != STOPPING:
                self.state = STOPPING
                self.stop_reason = reason
        self._wake.set()
        return "ok stopping"

    @property
    def stop_requested(self) -> bool:
        return self.state == STOPPING

    def status(self) -> str:
        return f"ok {self.state} phase {self.phase} step {self.step}"

    def _tell(self, message: str) -> None:
        for listener in list(self.listeners):
            try:
                listener(message)
            except Exception:
                pass

    # -- the experiment loop's side (main thread) -----------------------------------------
    def enter(self, phase: str) -> None:
        """A new phase of the run (start-up, NS, HS, closing); steps count from zero again."""
        self.phase = phase
        self.step = 0

    def check_stop(self) -> None:
        """Raise :class:`OperatorStop` if a stop was asked (start-up and between phases)."""
        if self.state == STOPPING:
            raise OperatorStop(self.stop_reason)

    def checkpoint(self, site, step: int, log: Callable[[str, str], None] | None = None) -> None:
        """Between two steps: stop, or pause (hold, wait, resume), as requested."""
        self.step = step
        self.check_stop()
        self._record(self._cancelled, "pause_cancelled", log)
        if not self._pause_wanted:
            return
        pause = getattr(site, "pause", None)
        report = pause() if pause is not None else None
        message = f"paused after step {step}: " + (report.message if report is not None else "no actuators to hold")
        with self._lock:
            if self.state != STOPPING:
                self.state = PAUSED
        if log:
            log("pause", message)
        self._tell(message)
        started = time.monotonic()
        watch = getattr(site, "watch_controllers", None)
        seen: set[str] = set()
        watched = started
        keep_alive = getattr(site, "keep_alive", None)
        period = getattr(site, "keep_alive_period_s", None)
        period = period() if period is not None else None
        wait_s = self.WAIT_SLICE_S if not period else max(self.MIN_SLICE_S, min(self.WAIT_SLICE_S, period))
        while True:  # as long as the operator wants; each wait is bounded
            self._wake.wait(wait_s)
            self._wake.clear()
            if self.state == STOPPING:  # a stop ends the pause: its time is pause all the same
                self.paused_s += time.monotonic() - started
                raise OperatorStop(self.stop_reason)
            self._record_acknowledgements(log)
            leaving = not self._pause_wanted
            if watch is not None and (leaving or time.monotonic() - watched >= self.WATCH_S):
                watched = time.monotonic()
                if self._watch(watch, seen, log) and leaving:  # a trip seen as the resume came: refused
                    continue
            if leaving:
                break
            if keep_alive is not None:  # the controllers' host watchdogs see a live host
                self._keep_alive(keep_alive, seen, log)
        with self._lock:  # resuming: a pause asked from here on is for the next step boundary
            if self.state != STOPPING:
                self.state = PAUSING if self._pause_wanted else RUNNING
        resume = getattr(site, "resume", None)
        if resume is not None:
            resume()
        self.paused_s += time.monotonic() - started
        message = f"resumed after {time.monotonic() - started:.1f} s of pause"
        if log:
            log("resume", message)
        self._tell(message)


    def _keep_alive(self, keep_alive, seen: set[str], log) -> None:
        """Feed the controllers' host watchdogs. A controller that cannot be reached is told and
        recorded as a trip (:meth:`_watch`): the run stays paused, its hold not confirmed, until
        the operator acknowledges it or stops the run; the feeding goes on meanwhile."""
        try:
            lost = keep_alive() or []
        except Exception as exc:  # a site that raises rather than names the controller
            lost = [f"the controllers could not be reached to feed their host watchdogs ({type(exc).__name__}): "
                    f"whether the actuators hold cannot be confirmed"]
        if lost:
            self._watch(lambda: lost, seen, log)

    def _watch(self, watch, seen: set[str], log) -> bool:
        """Ask the controllers whether they tripped; tell and record each trip not seen before in
        this pause. True when one was new (the resume waits for its acknowledgement)."""
        new = [line for line in watch() if line not in seen]
        if not new:
            return False
        seen.update(new)
        when = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-4] + "Z"
        with self._lock:
            self._unacknowledged.extend(new)
            self._pause_wanted = True  # a resume asked meanwhile waits for the acknowledgement
        for line in new:
            message = (f"controller trip during the pause after step {self.step} (at {when}): {line}; "
                       f"resume refused until acknowledged (ack), or stop the run")
            if log:
                log("controller_trip", message)
            self._tell(message)
            self.trips.append(message)  # last: whoever watches trips finds it recorded and told
        return True

    def _record_acknowledgements(self, log) -> None:
        self._record(self._acknowledged, "acknowledge", log)

    def _record(self, pending: list[str], kind: str, log) -> None:
        """Record and tell what a request made of the run (by the loop's thread), once each."""
        with self._lock:
            done = pending[:]
            pending.clear()
        for message in done:
            if log:
                log(kind, message)
            self._tell(message)


@contextlib.contextmanager
def stop_on_signals(control: RunControl):
    """SIGTERM and SIGINT ask ``control`` to stop (the run holds and closes its record); a second
    SIGINT interrupts at once. Installed only in the main thread; the old handlers come back. A
    program started with SIGINT ignored keeps ignoring it (hsio.entry)."""
    if threading.current_thread() is not threading.main_thread():
        yield control
        return

    def handler(signum, frame):
        name = signal.Signals(signum).name
        if control.stop_requested and signum == signal.SIGINT:
            raise KeyboardInterrupt
        control.request_stop(f"stopped by {name} during {control.phase}")

    from hsio.entry import after_start_up, noted_interrupt, started_ignoring_sigint

    # a program started with SIGINT ignored (a background job) keeps ignoring it: SIGTERM stops it
    signals = (signal.SIGTERM,) if started_ignoring_sigint() else (signal.SIGTERM, signal.SIGINT)
    previous = {s: signal.signal(s, handler) for s in signals}

    if noted_interrupt():  # Ctrl-C while the program started (hsio.entry)
        control.request_stop("stopped by SIGINT during start-up")
    try:
        yield control
    finally:
        for s, h in previous.items():  # Python's own SIGINT handling after the start-up's (hsio.entry)
            signal.signal(s, after_start_up(h))
