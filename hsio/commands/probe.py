"""`hsio probe URL`: driver-level diagnostics of a real or emulated servo controller.

Reports the connection and identity, the state of each axis, and the round-trip latency of the
driver's requests (median, p99 and max over N requests, in ms). Without --move it only reads:
no axis is enabled and nothing is commanded. With --move the axes are enabled after those reads
(an axis enabled during them would get no command, and a host watchdog would latch), then axis 0
makes a small step (ramped at 90 %
of the velocity limit, there and back) and a slow sine of two periods from where it stands (rise
time, overshoot, RMS tracking error) and comes back. The move is bounded before anything moves
(:func:`check_move`): the sine lasts at most :data:`SINE_MAX_S` (--sine-hz from
:data:`SINE_MIN_HZ` to :data:`SINE_MAX_HZ`), each ramp of the step at most :data:`RAMP_MAX_S`, the
step and the amplitude stay within 5 % of the stroke and inside it, and the sine's peak velocity
2 pi f A within the velocity limit. Every command goes through the limit checks and interlocks of
a run, and a refusal or a trip ends the probe with exit status 2.

SIGTERM and SIGINT (Ctrl-C) stop the move at the next command, as they stop a run
(:func:`hsio.safety.control.stop_on_signals`): exit status 5. Whatever ends the move (its end, a
refusal, a trip, a signal, an unexpected error, exit status 3) every axis is told to hold where it
stands and the hold is read back from the controller (docs/safety.md section 3): the report says
the axes hold only when the controller confirms it. Ctrl-C is ignored while they are told to hold.

With --config the probe uses a run configuration's [safety] interlock settings and its [driver]
options (each --option overrides one), so that it moves the rig under the same checks as the run;
without it, the defaults of docs/config.md.
"""

from __future__ import annotations

import contextlib
import json
import math
import signal
import sys
import threading
import time
from urllib.parse import urlsplit

import click
import numpy as np

from hsio.clock import OVERRUN_WARNING
from hsio.commands import RegularFile
from hsio.errors import HsioError, LimitError
from hsio.hardware import controller_options
from hsio.safety.status import OK, BAD_INPUT as REFUSED, LIMIT_OR_FAULT as UNEXPECTED, OPERATOR as STOPPED

SINE_PERIODS = 2  # the sine of --move lasts two periods, 2 / f
SINE_MIN_HZ = 0.05  # so the sine lasts at most SINE_MAX_S
SINE_MAX_S = SINE_PERIODS / SINE_MIN_HZ  # 40 s
SINE_MAX_HZ = 50.0  # at least 20 commands per period at 1024 Hz
RAMP_MAX_S = 10.0  # each ramp of the step (there, and back)
MOVE_MAX_S = 0.05 + 2 * RAMP_MAX_S + SINE_MAX_S + 0.1  # still, step, back, sine, still: 60.15 s


def latency_stats(samples_s: list[float]) -> dict:
    ms = np.asarray(samples_s) * 1e3
    return {"requests": int(ms.size), "median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99)),
            "max_ms": float(ms.max())}


def _open(url: str, axes: int, options: dict, enable: bool):
    try:
        scheme = urlsplit(url).scheme
    except ValueError as exc:
        raise click.BadParameter(f"{url!r} is malformed ({exc})", param_hint="URL") from None
    names = [f"axis{k}" for k in range(axes)]
    if scheme.startswith("modbus+"):
        from hsio.drivers.modbus import open_link
    elif scheme.startswith("canopen+"):
        from hsio.drivers.canopen import open_link
    else:
        raise click.BadParameter(f"{url!r}: probe speaks modbus+tcp://, modbus+rtu:// and canopen+...:// URLs", param_hint="URL")
    return open_link(url, names, None, options, enable=enable)


def _identity(link) -> dict:
    if hasattr(link, "info"):  # Modbus
        ident = {k: v for k, v in link.info.items()}
        ident["map"] = link.map.name
        try:
            rr = link.client.read_device_information(device_id=link.device_id)
            if not rr.isError():
                ident["device_identification"] = {str(k): v.decode(errors="replace") if isinstance(v, bytes) else str(v)
                                                  for k, v in rr.information.items()}
        except Exception:
            pass
        return ident
    return {f"node {d.id}": d.identity for d in link.drives}


def _state(link, actuators) -> list[dict]:
    out = []
    if hasattr(link, "status"):
        link.read_status()
        for k, st in enumerate(link.status):
            flags = {name: link.map.bit(st["status_word"], name) for name in link.map.bits}
            out.append({"axis": k, "displacement_mm": st["displacement"], "force_kN": st["force"],
                        "sequence": st["sequence"], "flags": flags})
        return out
    for d in link.drives:
        d.node.tpdo_values[0x6041] = d.sdo_read(0x6041, what="statusword")
        out.append({"axis": d.id - link.node_id, "node": d.id, "state": d.node.state,
                    "statusword": f"0x{d.node.statusword:04X}", "mode": d.sdo_read(0x6061, what="mode display"),
                    "displacement_mm": d.sdo_read(0x6064) / d.counts_per_mm, "force_kN": d.sdo_read(0x6077) * d.rated_N / 1e6})
    return out


def _latency(link, n: int, control=None) -> dict:
    times = []
    if hasattr(link, "status"):
        what = "Modbus read of every status register (function 3)"
        request = link.read_status
    else:
        what = "CANopen SDO upload of the statusword 0x6041"
        d = link.drives[0]
        request = lambda: d.sdo_read(0x6041)  # noqa: E731
    for _ in range(n):
        if control is not None:
            control.check_stop()
        t = time.perf_counter()
        request()
        times.append(time.perf_counter() - t)
    return {"what": what, **latency_stats(times)}


class _Guard:
    """The checks every command of a run goes through (docs/safety.md section 3), for probe's
    motion: the stroke and force limits (:meth:`hsio.interfaces.Actuator.command`), the velocity
    limit against the previous command, and the interlocks of the control loop (following error,
    implausible measurement) on every sample; and, before each command, a stop asked by a signal
    (``control``, :class:`hsio.safety.control.RunControl`). A refusal, a trip or a stop raises;
    the caller holds."""

    def __init__(self, actuator, clock, safety=None, control=None, others=()):
        from hsio.safety.interlocks import InterlockMonitor
        from hsio.safety.settings import SafetySettings

        self.actuator = actuator
        self.others = list(others)  # the link's other axes: commanded where they stand
        self.clock = clock
        self.control = control
        safety = safety or SafetySettings.from_table({})
        self.monitor = InterlockMonitor([actuator, *self.others], safety) if safety.interlocks else None
        self.start = self.previous = actuator.feedback().displacement_mm
        self.stands = [o.feedback().displacement_mm for o in self.others]
        self.modes = [actuator.mode, *(o.mode for o in self.others)]  # the move is in displacement throughout

    def send(self, command: float) -> float:
        """One checked command (and the other axes' where they stood: in real time a link sends
        once every axis has its command); axis 0's measured displacement one period later."""
        if self.control is not None:
            self.control.check_stop()
        a = self.actuator
        a.limits.check_velocity((command - self.previous) / self.clock.period_s, f"actuator {a.name!r}")
        a.command(command)
        for other, x in zip(self.others, self.stands):
            other.command(x)
        self.previous = command
        self.clock.tick()
        fbs = [a.feedback(), *(o.feedback() for o in self.others)]
        if self.monitor is not None:
            self.monitor.check(self.clock.now_s, [command, *self.stands], fbs, self.modes)
        return fbs[0].displacement_mm


def _drive(guard: _Guard, commands) -> np.ndarray:
    """Command each sample at the controller rate, checked; return measured displacements."""
    return np.array([guard.send(float(c)) for c in commands])


def _ramp(x_from: float, x_to: float, speed_mm_s: float, rate: float) -> np.ndarray:
    """From ``x_from`` (excluded) to ``x_to`` at ``speed_mm_s``: the fastest "step" the velocity
    limit allows."""
    n = max(int(math.ceil(abs(x_to - x_from) / (speed_mm_s / rate))), 1)
    return x_from + (x_to - x_from) * np.arange(1, n + 1) / n


def _sine_hz(ctx, param, value: float) -> float:
    """--sine-hz: the sine lasts two periods, so at most SINE_MAX_S; at most SINE_MAX_HZ."""
    if SINE_MIN_HZ <= value <= SINE_MAX_HZ:
        return value
    allowed = f"allowed {SINE_MIN_HZ:g} to {SINE_MAX_HZ:g} Hz"
    if 0 < value < SINE_MIN_HZ:
        why = f"the sine of --move lasts two periods, 2/f = {SINE_PERIODS / value:.4g} s, beyond {SINE_MAX_S:g} s"
    elif value > SINE_MAX_HZ:
        why = f"beyond {SINE_MAX_HZ:g} Hz (20 commands a period at 1024 Hz)"
    else:
        why = f"the sine of --move lasts two periods, at most {SINE_MAX_S:g} s"
    raise click.BadParameter(f"{value:g} Hz: {why}; {allowed}", param_hint=None if param is not None else "--sine-hz")


def check_move(limits, x0: float, step_mm: float, sine_mm: float, sine_hz: float) -> None:
    """Before anything moves: the step within 5 % of the stroke and within what a ramp at 90 % of
    the velocity limit covers in :data:`RAMP_MAX_S`; the sine amplitude within 5 % of the stroke;
    both from where axis 0 stands (``x0``) inside the stroke; the sine's frequency within
    :data:`SINE_MIN_HZ` .. :data:`SINE_MAX_HZ` (so it lasts at most :data:`SINE_MAX_S`) and its
    peak velocity 2 pi f A within the velocity limit (a sine beyond it would be refused part way
    through, with the axis away from where it stood)."""
    small = 0.05 * limits.stroke_mm
    reach = 0.9 * limits.velocity_mm_s * RAMP_MAX_S
    half = limits.half_stroke_mm
    if step_mm == 0 or not abs(step_mm) <= min(small, reach):
        raise click.BadParameter(f"{step_mm:g} mm: must be non-zero and within +/-{min(small, reach):.4g} mm "
                                 f"(5 % of the stroke, {small:g} mm; a ramp at 90 % of the velocity limit, "
                                 f"{limits.velocity_mm_s:g} mm/s, for at most {RAMP_MAX_S:g} s, {reach:.4g} mm)",
                                 param_hint="--step-mm")
    if not abs(x0 + step_mm) <= half:
        raise click.BadParameter(f"{step_mm:g} mm: axis 0 stands at {x0:.3f} mm, the step would end at "
                                 f"{x0 + step_mm:.3f} mm, beyond the stroke (+/-{half:g} mm); allowed here "
                                 f"{max(-small, -reach, -half - x0):.4g} to {min(small, reach, half - x0):.4g} mm",
                                 param_hint="--step-mm")
    if not 0 < sine_mm <= small:
        raise click.BadParameter(f"{sine_mm:g} mm: must be within 5 % of the stroke (0 to {small:g} mm)",
                                 param_hint="--sine-mm")
    if not abs(x0) + sine_mm <= half:
        raise click.BadParameter(f"{sine_mm:g} mm: axis 0 stands at {x0:.3f} mm, the sine would reach "
                                 f"{abs(x0) + sine_mm:.3f} mm from the centre, beyond the stroke (+/-{half:g} mm); "
                                 f"allowed here up to {half - abs(x0):.4g} mm", param_hint="--sine-mm")
    _sine_hz(None, None, sine_hz)
    peak = 2.0 * math.pi * sine_hz * sine_mm
    if peak > limits.velocity_mm_s:
        raise LimitError(f"--sine-mm {sine_mm:g} at --sine-hz {sine_hz:g}: peak velocity 2 pi f A = {peak:.1f} mm/s "
                         f"is beyond the velocity limit ({limits.velocity_mm_s:.1f} mm/s); refused, nothing moved "
                         f"(at {sine_hz:g} Hz the amplitude may be up to "
                         f"{limits.velocity_mm_s / (2.0 * math.pi * sine_hz):.4g} mm)")


def _move(guard: _Guard, step_mm: float, sine_mm: float, sine_hz: float, control=None) -> dict:
    """A step and back (each ramped at 90 % of the velocity limit), a slow sine of two periods,
    back: every command checked as in a run (:class:`_Guard`). Checked beforehand by
    :func:`check_move`, it lasts at most :data:`MOVE_MAX_S`. The caller holds the axis afterwards."""
    phase = control.enter if control is not None else (lambda name: None)
    actuator, rate = guard.actuator, guard.clock.rate_hz
    speed = 0.9 * actuator.limits.velocity_mm_s
    x0 = guard.start
    phase("the step")
    _drive(guard, np.full(int(0.05 * rate), x0))
    rise_cmd = _ramp(x0, x0 + step_mm, speed, rate)
    step = np.concatenate([rise_cmd, np.full(max(int(0.5 * rate) - len(rise_cmd), 1), x0 + step_mm)])
    y = (_drive(guard, step) - x0) / step_mm  # the response as a fraction of the step, either sign
    t = np.arange(len(y)) / rate
    i10 = np.argmax(y >= 0.1) if np.any(y >= 0.1) else None
    i90 = np.argmax(y >= 0.9) if np.any(y >= 0.9) else None
    rise = float(t[i90] - t[i10]) if i10 is not None and i90 is not None else math.nan
    overshoot = float(max(y.max() - 1.0, 0.0) * 100.0)
    back = _ramp(x0 + step_mm, x0, speed, rate)
    _drive(guard, np.concatenate([back, np.full(max(int(0.25 * rate) - len(back), 1), x0)]))
    phase("the sine")
    n = int(SINE_PERIODS / sine_hz * rate)
    ts = np.arange(n) / rate
    cmd = x0 + sine_mm * np.sin(2 * np.pi * sine_hz * ts)
    meas = _drive(guard, cmd)
    settle = int(0.25 / sine_hz * rate)
    rms = float(np.sqrt(np.mean((cmd[settle:] - meas[settle:]) ** 2)))
    phase("the return")
    _drive(guard, np.full(int(0.1 * rate), x0))
    return {"step_mm": step_mm, "step_ramp_s": len(rise_cmd) / rate, "rise_time_s": rise, "overshoot_pct": overshoot,
            "sine_amplitude_mm": sine_mm, "sine_hz": sine_hz, "rms_tracking_error_mm": rms}


POSITIVE = click.FloatRange(min=0, min_open=True)


def _finite(ctx, param, value: float) -> float:
    if not math.isfinite(value):
        raise click.BadParameter(f"{value!r} is not a finite number")
    return value


@contextlib.contextmanager
def _sigint_ignored():
    """Ctrl-C is ignored while the axes are told to hold and the hold is read back: the stop is
    under way, and a second Ctrl-C must not cut it short (each request is bounded by the driver's
    timeout). The handler before comes back afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _hold(actuators):
    """Every axis holds (each is tried), then the hold is read back as `hsio run` reads it
    (:func:`hsio.safety.hold.read_back`)."""
    from hsio.safety.hold import read_back

    for a in actuators:
        try:
            a.hold()
        except Exception:
            pass  # the read-back says whether it holds
    return read_back(actuators)


def _stands(actuators, x0: float | None) -> str:
    """Where axis 0 stands after the hold (read from the controller), and how far from its start."""
    try:
        d = _state(actuators[0].link, actuators)[0]["displacement_mm"]
    except Exception as exc:
        return f"where axis 0 stands could not be read ({exc})"
    where = f"axis 0 stands at {d:.3f} mm"
    return where + (f", {d - x0:+.3f} mm from where it stood" if x0 is not None else "")


@click.command()
@click.argument("url")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
@click.option("--move", is_flag=True, help="Also make a small step and a slow sine on axis 0 (moves the actuator; "
                                           f"at most {MOVE_MAX_S:.0f} s).")
@click.option("--axes", default=1, show_default=True, type=click.IntRange(1, 64), help="Number of axes to open.")
@click.option("--requests", "n_requests", default=200, show_default=True, type=click.IntRange(1, 100000),
              help="Requests for the latency figures.")
@click.option("--step-mm", default=1.0, show_default=True, type=float, callback=_finite,
              help="Step of axis 0 with --move (non-zero, within 5 % of the stroke and what a ramp at 90 % of "
                   f"the velocity limit covers in {RAMP_MAX_S:g} s; either sign).")
@click.option("--sine-mm", default=1.0, show_default=True, type=POSITIVE, callback=_finite,
              help="Sine amplitude with --move (within 5 % of the stroke).")
@click.option("--sine-hz", default=0.5, show_default=True, type=float, callback=_sine_hz,
              help=f"Sine frequency with --move, {SINE_MIN_HZ:g} to {SINE_MAX_HZ:g} Hz (two periods: at most "
                   f"{SINE_MAX_S:g} s; 2 pi f A within the velocity limit).")
@click.option("--option", "options", multiple=True, metavar="KEY=VALUE", help="A [driver] setting (repeatable).")
@click.option("--reset-interlock", is_flag=True,
              help="Modbus: hold every axis and clear the latched interlocks (docs/modbus.md, Interlock reset).")
@click.option("--config", "config_path", type=RegularFile(), default=None,
              help="A run configuration: its [safety] interlocks and its [driver] options (--option overrides).")
def probe(url, as_json, move, axes, n_requests, step_mm, sine_mm, sine_hz, options, reset_interlock=False,
          config_path=None) -> None:
    """Diagnose the controller at URL: identity, state, latency; with --move, step and sine.

    Exit status: 0 done, 2 bad input, a refusal or a trip, 3 an unexpected error, 5 stopped by a
    signal (SIGTERM, SIGINT). With --move every axis holds at the end, read back.
    """
    from hsio.clock import LockstepClock, RealTimeClock
    from hsio.entry import running_as_program
    from hsio.safety.control import RunControl, stop_on_signals
    from hsio.safety.settings import SafetySettings
    from hsio.safety.status import OperatorStop

    bad = [o for o in options if "=" not in o]
    if bad:
        raise click.BadParameter(f"{bad[0]!r}: expected KEY=VALUE", param_hint="--option")
    table = dict(o.partition("=")[::2] for o in options)
    safety = SafetySettings.from_table({})
    report: dict = {"url": url}
    if config_path is not None:
        from hsio import config as config_mod
        from hsio.errors import ConfigError

        try:
            cfg = config_mod.load(config_path)
        except ConfigError as exc:
            raise click.BadParameter(str(exc), param_hint="--config") from None
        safety = SafetySettings.from_table(cfg["safety"])
        hardware_url = cfg["hardware"]["url"]
        family = urlsplit(url).scheme.partition("+")[0]
        if hardware_url.partition("+")[0] in ("modbus", "canopen") and hardware_url.partition("+")[0] != family:
            raise click.BadParameter(f"{config_path}: its [hardware] url {hardware_url!r} is not a {family} "
                                     f"controller; its [driver] options are not for {url!r}", param_hint="--config")
        table = {**controller_options(cfg["driver"]), **table}
        report["config"] = str(config_path)
        report["interlocks"] = "on" if safety.interlocks else "off ([safety] interlocks = false)"
    control = RunControl()
    actuators: list = []
    refusal: click.ClickException | None = None
    start: float | None = None
    status = OK
    with stop_on_signals(control):  # SIGTERM and SIGINT ask the probe to stop (exit 5), as they ask a run
        try:
            started = time.perf_counter()
            actuators = _open(url, axes, table, enable=False)  # --move enables after the reads
            control.check_stop()
            link = actuators[0].link
            report["connect_s"] = round(time.perf_counter() - started, 4)
            report["clock"] = "lockstep" if link.lockstep else "realtime"
            report["identity"] = _identity(link)
            if reset_interlock:
                if not hasattr(link, "reset_interlock"):
                    raise click.BadParameter("--reset-interlock: only Modbus controllers have a reset register")
                link.reset_interlock()
                report["interlock_reset"] = True
            report["axes"] = _state(link, actuators)
            control.enter("the latency measurement")
            report["latency"] = _latency(link, n_requests, control)
            if move:
                control.enter("the enabling of the axes")
                link.enable()  # now: an axis enabled during the reads above would get no command
                clock = LockstepClock() if link.lockstep else RealTimeClock()
                clock.attach(link)
                guard = _Guard(actuators[0], clock, safety, control, others=actuators[1:])
                start = guard.start
                check_move(actuators[0].limits, start, step_mm, sine_mm, sine_hz)
                periods = clock.ticks
                report["move"] = _move(guard, step_mm, sine_mm, sine_hz, control)
                overruns = getattr(clock, "overruns", 0)
                report["move"]["clock_overruns"] = overruns
                if overruns > OVERRUN_WARNING * (clock.ticks - periods):
                    report["move"]["warning"] = (
                        f"{overruns} of {clock.ticks - periods} controller periods started more than one period late "
                        "(the link is slower than the period): the move ran slower than commanded, and its times "
                        "and frequency are in controller periods, not wall-clock time")
            control.check_stop()
        except click.ClickException as exc:  # a bad value found once the controller answered: nothing moved
            refusal = exc
        except OperatorStop as exc:
            report["stopped"], status = str(exc), STOPPED
        except KeyboardInterrupt:  # a second Ctrl-C
            report["stopped"], status = f"interrupted (Ctrl-C) during {control.phase}", STOPPED
        except HsioError as exc:
            report["error"], status = str(exc), REFUSED
        except Exception as exc:
            report["error"], status = f"unexpected {exc!r}", UNEXPECTED
        finally:
            with _sigint_ignored():
                _release(actuators, move, report, start)
    if running_as_program():  # the axes hold: the program only reports and ends, whatever a late Ctrl-C says
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    _report(report, as_json, refusal, status)


def _release(actuators, move: bool, report: dict, start: float | None) -> None:
    """After --move, whatever ended it: every axis holds, the hold is read back (``report["hold"]``),
    and a stop says where axis 0 stands; then the link closes."""
    if actuators and move:
        report["hold"] = _hold(actuators).as_dict()
        if "stopped" in report:
            report["stopped"] += f"; {_stands(actuators, start)}"
    for a in actuators:
        try:
            a.close() if move else None
        except Exception:
            pass
    if actuators and not move:
        try:
            actuators[0].link.close()
        except Exception:
            pass


def _report(report: dict, as_json: bool, refusal, status: int) -> None:
    """The report on stdout, a stop or an error on stderr, and the exit status."""
    if refusal is not None:
        if "hold" in report:
            click.echo(f"hsio probe: refused before anything moved; {report['hold']['message']}", err=True)
        raise refusal
    if as_json:
        click.echo(json.dumps(report, indent=2, default=str))
    else:
        _print(report)
    if "stopped" in report:
        held = report["hold"]["message"] if "hold" in report else "nothing was enabled"
        click.echo(f"hsio probe: {report['stopped']}; {held}", err=True)
    if status != OK:
        sys.exit(status)


def _print(r: dict) -> None:
    click.echo(f"url        {r['url']}")
    if "config" in r:
        click.echo(f"config     {r['config']} ([safety] and [driver]; interlocks {r['interlocks']})")
    if "clock" in r:
        click.echo(f"connected  in {r['connect_s'] * 1e3:.1f} ms; clock {r['clock']}")
        click.echo(f"identity   {json.dumps(r['identity'], default=str)}")
    if r.get("interlock_reset"):
        click.echo("reset      the latched interlocks are cleared (the axes opened hold; none shows an interlock or "
                   "watchdog bit)")
    for a in r.get("axes", []):
        click.echo(f"axis {a['axis']}     d = {a['displacement_mm']:.4f} mm, F = {a['force_kN']:.4f} kN, "
                   + (f"flags {', '.join(k for k, v in a['flags'].items() if v) or '-'}" if "flags" in a
                      else f"state {a['state']} ({a['statusword']}), mode {a['mode']}"))
    if "latency" in r:
        lat = r["latency"]
        click.echo(f"latency    {lat['what']}: median {lat['median_ms']:.3f} ms, p99 {lat['p99_ms']:.3f} ms, "
                   f"max {lat['max_ms']:.3f} ms over {lat['requests']} requests")
    if "move" in r:
        m = r["move"]
        click.echo(f"step       {m['step_mm']:g} mm, ramped over {m['step_ramp_s'] * 1e3:.1f} ms: rise time "
                   f"(10-90 %, ramp included) {m['rise_time_s'] * 1e3:.1f} ms, overshoot {m['overshoot_pct']:.2f} %")
        click.echo(f"sine       {m['sine_amplitude_mm']:g} mm at {m['sine_hz']:g} Hz: RMS tracking error "
                   f"{m['rms_tracking_error_mm']:.4f} mm")
        if "warning" in m:
            click.echo(f"WARNING    {m['warning']}")
    if "hold" in r:
        click.echo(f"hold       {r['hold']['message']}")
    if "error" in r:
        click.echo(f"error      {r['error']}", err=True)
