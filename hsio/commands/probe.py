"""`hsio probe URL`: driver-level diagnostics of a real or emulated servo controller.

Reports the connection and identity, the state of each axis, and the round-trip latency of the
driver's requests (median, p99 and max over N requests, in ms). Without --move it only reads:
no axis is enabled and nothing is commanded. With --move, axis 0 makes a small step (ramped at 90 %
of the velocity limit, there and back) and a slow sine from where it stands (rise time, overshoot,
RMS tracking error) and comes back; a sine whose peak velocity 2 pi f A is beyond the velocity
limit is refused before anything moves. Every command goes through the limit checks and
interlocks of a run, and a refusal or a trip ends the probe with exit status 2. At the end every
axis is told to hold and the hold is read back from the controller (docs/safety.md section 3):
the report says the axes hold only when the controller confirms it.

With --config the probe uses a run configuration's [safety] interlock settings and its [driver]
options (each --option overrides one), so that it moves the rig under the same checks as the run;
without it, the defaults of docs/config.md.
"""

from __future__ import annotations

import json
import math
import sys
import time
from urllib.parse import urlsplit

import click
import numpy as np

from hsio.commands import RegularFile
from hsio.errors import HsioError, LimitError
from hsio.hardware import controller_options


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


def _latency(link, n: int) -> dict:
    times = []
    if hasattr(link, "status"):
        what = "Modbus read of every status register (function 3)"
        for _ in range(n):
            t = time.perf_counter()
            link.read_status()
            times.append(time.perf_counter() - t)
    else:
        what = "CANopen SDO upload of the statusword 0x6041"
        d = link.drives[0]
        for _ in range(n):
            t = time.perf_counter()
            d.sdo_read(0x6041)
            times.append(time.perf_counter() - t)
    return {"what": what, **latency_stats(times)}


class _Guard:
    """The checks every command of a run goes through (docs/safety.md section 3), for probe's
    motion: the stroke and force limits (:meth:`hsio.interfaces.Actuator.command`), the velocity
    limit against the previous command, and the interlocks of the control loop (following error,
    implausible measurement) on every sample. A refusal or a trip raises; the caller holds."""

    def __init__(self, actuator, clock, safety=None):
        from hsio.safety.interlocks import InterlockMonitor
        from hsio.safety.settings import SafetySettings

        self.actuator = actuator
        self.clock = clock
        safety = safety or SafetySettings.from_table({})
        self.monitor = InterlockMonitor([actuator], safety) if safety.interlocks else None
        self.previous = actuator.feedback().displacement_mm

    def send(self, command: float) -> float:
        """One checked command; the measured displacement after one controller period."""
        a = self.actuator
        a.limits.check_velocity((command - self.previous) / self.clock.period_s, f"actuator {a.name!r}")
        a.command(command)
        self.previous = command
        self.clock.tick()
        fb = a.feedback()
        if self.monitor is not None:
            self.monitor.check(self.clock.now_s, [command], [fb], [a.mode])
        return fb.displacement_mm


def _drive(guard: _Guard, commands) -> np.ndarray:
    """Command each sample at the controller rate, checked; return measured displacements."""
    return np.array([guard.send(float(c)) for c in commands])


def _ramp(x_from: float, x_to: float, speed_mm_s: float, rate: float) -> np.ndarray:
    """From ``x_from`` (excluded) to ``x_to`` at ``speed_mm_s``: the fastest "step" the velocity
    limit allows."""
    n = max(int(math.ceil(abs(x_to - x_from) / (speed_mm_s / rate))), 1)
    return x_from + (x_to - x_from) * np.arange(1, n + 1) / n


def check_move(limits, step_mm: float, sine_mm: float, sine_hz: float) -> None:
    """Before anything moves: the step and the sine amplitude within 5 % of the stroke, and the
    sine's peak velocity 2 pi f A within the velocity limit (a sine beyond it would be refused
    part way through, with the axis away from where it stood)."""
    small = 0.05 * limits.stroke_mm
    if step_mm == 0 or abs(step_mm) > small:
        raise click.BadParameter(f"{step_mm:g} mm: must be non-zero and within 5 % of the stroke "
                                 f"(+/-{small:g} mm)", param_hint="--step-mm")
    if sine_mm > small:
        raise click.BadParameter(f"{sine_mm:g} mm: must be within 5 % of the stroke ({small:g} mm)",
                                 param_hint="--sine-mm")
    peak = 2.0 * math.pi * sine_hz * sine_mm
    if peak > limits.velocity_mm_s:
        raise LimitError(f"--sine-mm {sine_mm:g} at --sine-hz {sine_hz:g}: peak velocity 2 pi f A = {peak:.1f} mm/s "
                         f"is beyond the velocity limit ({limits.velocity_mm_s:.1f} mm/s); refused, nothing moved")


def _move(actuator, clock, step_mm: float, sine_mm: float, sine_hz: float, safety=None) -> dict:
    """A step and back (each ramped at 90 % of the velocity limit), a slow sine, back: every
    command checked as in a run (:class:`_Guard`, with the interlock settings ``safety``). The
    caller holds the axis afterwards."""
    rate = clock.rate_hz
    speed = 0.9 * actuator.limits.velocity_mm_s
    guard = _Guard(actuator, clock, safety)
    x0 = guard.previous
    _drive(guard, np.full(int(0.05 * rate), x0))
    rise_cmd = _ramp(x0, x0 + step_mm, speed, rate)
    step = np.concatenate([rise_cmd, np.full(max(int(0.5 * rate) - len(rise_cmd), 1), x0 + step_mm)])
    y = _drive(guard, step) - x0
    t = np.arange(len(y)) / rate
    i10 = np.argmax(y >= 0.1 * step_mm) if np.any(y >= 0.1 * step_mm) else None
    i90 = np.argmax(y >= 0.9 * step_mm) if np.any(y >= 0.9 * step_mm) else None
    rise = float(t[i90] - t[i10]) if i10 is not None and i90 is not None else math.nan
    overshoot = float(max(y.max() - step_mm, 0.0) / step_mm * 100.0)
    back = _ramp(x0 + step_mm, x0, speed, rate)
    _drive(guard, np.concatenate([back, np.full(max(int(0.25 * rate) - len(back), 1), x0)]))
    n = int(2.0 / sine_hz * rate)
    ts = np.arange(n) / rate
    cmd = x0 + sine_mm * np.sin(2 * np.pi * sine_hz * ts)
    meas = _drive(guard, cmd)
    settle = int(0.25 / sine_hz * rate)
    rms = float(np.sqrt(np.mean((cmd[settle:] - meas[settle:]) ** 2)))
    _drive(guard, np.full(int(0.1 * rate), x0))
    return {"step_mm": step_mm, "step_ramp_s": len(rise_cmd) / rate, "rise_time_s": rise, "overshoot_pct": overshoot,
            "sine_amplitude_mm": sine_mm, "sine_hz": sine_hz, "rms_tracking_error_mm": rms}


POSITIVE = click.FloatRange(min=0, min_open=True)


def _finite(ctx, param, value: float) -> float:
    if not math.isfinite(value):
        raise click.BadParameter(f"{value!r} is not a finite number")
    return value


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


@click.command()
@click.argument("url")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
@click.option("--move", is_flag=True, help="Also make a small step and a slow sine on axis 0 (moves the actuator).")
@click.option("--axes", default=1, show_default=True, type=click.IntRange(1, 64), help="Number of axes to open.")
@click.option("--requests", "n_requests", default=200, show_default=True, type=click.IntRange(1, 100000),
              help="Requests for the latency figures.")
@click.option("--step-mm", default=1.0, show_default=True, type=float, callback=_finite,
              help="Step of axis 0 with --move (non-zero, within 5 % of the stroke; either sign).")
@click.option("--sine-mm", default=1.0, show_default=True, type=POSITIVE, callback=_finite,
              help="Sine amplitude with --move (within 5 % of the stroke).")
@click.option("--sine-hz", default=0.5, show_default=True, type=POSITIVE, callback=_finite,
              help="Sine frequency with --move (2 pi f A within the velocity limit).")
@click.option("--option", "options", multiple=True, metavar="KEY=VALUE", help="A [driver] setting (repeatable).")
@click.option("--reset-interlock", is_flag=True,
              help="Modbus: hold every axis and clear the latched interlocks (docs/modbus.md, Interlock reset).")
@click.option("--config", "config_path", type=RegularFile(), default=None,
              help="A run configuration: its [safety] interlocks and its [driver] options (--option overrides).")
def probe(url, as_json, move, axes, n_requests, step_mm, sine_mm, sine_hz, options, reset_interlock=False,
          config_path=None) -> None:
    """Diagnose the controller at URL: identity, state, latency; with --move, step and sine."""
    from hsio.clock import LockstepClock, RealTimeClock
    from hsio.safety.settings import SafetySettings

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
    actuators = []
    try:
        started = time.perf_counter()
        actuators = _open(url, axes, table, enable=move)
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
        report["latency"] = _latency(link, n_requests)
        if move:
            clock = LockstepClock() if link.lockstep else RealTimeClock()
            clock.attach(link)
            check_move(actuators[0].limits, step_mm, sine_mm, sine_hz)
            report["move"] = _move(actuators[0], clock, step_mm, sine_mm, sine_hz, safety)
    except HsioError as exc:
        report["error"] = str(exc)
    finally:
        if actuators and move:
            report["hold"] = _hold(actuators).as_dict()
        for a in actuators:
            try:
                a.close() if move else None
            except Exception:
                pass
        if actuators and not move:
            actuators[0].link.close()
    if as_json:
        click.echo(json.dumps(report, indent=2, default=str))
    else:
        _print(report)
    if "error" in report:
        sys.exit(2)


def _print(r: dict) -> None:
    click.echo(f"url        {r['url']}")
    if "config" in r:
        click.echo(f"config     {r['config']} ([safety] and [driver]; interlocks {r['interlocks']})")
    if "clock" in r:
        click.echo(f"connected  in {r['connect_s'] * 1e3:.1f} ms; clock {r['clock']}")
        click.echo(f"identity   {json.dumps(r['identity'], default=str)}")
        for a in r["axes"]:
            click.echo(f"axis {a['axis']}     d = {a['displacement_mm']:.4f} mm, F = {a['force_kN']:.4f} kN, "
                       + (f"flags {', '.join(k for k, v in a['flags'].items() if v) or '-'}" if "flags" in a
                          else f"state {a['state']} ({a['statusword']}), mode {a['mode']}"))
        lat = r["latency"]
        click.echo(f"latency    {lat['what']}: median {lat['median_ms']:.3f} ms, p99 {lat['p99_ms']:.3f} ms, "
                   f"max {lat['max_ms']:.3f} ms over {lat['requests']} requests")
    if "move" in r:
        m = r["move"]
        click.echo(f"step       {m['step_mm']:g} mm, ramped over {m['step_ramp_s'] * 1e3:.1f} ms: rise time "
                   f"(10-90 %, ramp included) {m['rise_time_s'] * 1e3:.1f} ms, overshoot {m['overshoot_pct']:.2f} %")
        click.echo(f"sine       {m['sine_amplitude_mm']:g} mm at {m['sine_hz']:g} Hz: RMS tracking error "
                   f"{m['rms_tracking_error_mm']:.4f} mm")
    if "hold" in r:
        click.echo(f"hold       {r['hold']['message']}")
    if "error" in r:
        click.echo(f"error      {r['error']}", err=True)
