"""Resume a run after a crash, SIGKILL or power loss (docs/safety.md section 8).

Every step is durable before the next begins (docs/safety.md section 1), so the record holds the
alpha-OS state of its last committed step k: u_k, v_k, a_k, u~_k and R~_k per DOF; v~_k follows
from the corrector (v_k = v~_k + dt gamma a_k) and P_k from the record. The run goes on from step
k + 1 into the same record, against the same hardware: the command generators start from where
the actuators stand (they hold since the host fell silent) and the next target is approached over
a whole step, so the actuators come back smoothly.
"""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
from pathlib import Path

import numpy as np

import hsio
from hsio import api, config as config_mod
from hsio.errors import ConfigError, HsioError, RecordError
from hsio.experiment import INTERLOCK_TABLE, ExperimentStopped, excitation
from hsio.integrators.alpha_os import AlphaOSState
from hsio.ledger import LEDGER_FILE, Ledger
from hsio.recording import RUN_FILE, Recorder, Run, column
from hsio.result import max_error_pct
from hsio.safety.control import RunControl, stop_on_signals
from hsio.safety.inputs import compare_inputs, ground_fingerprint
from hsio.safety.settings import SafetySettings
from hsio.safety.socket import ControlServer
from hsio.safety.status import BAD_INPUT, exit_status, outcome_name

# Summary entries that describe one session of a run rather than its record: a resume leaves them
# out (the earlier session's are not those of the whole record).
SESSION_KEYS = ("final_hold", "warning", "wall_time_s", "late_steps", "clock_overruns", "rms_tracking_error_mm",
                "rms_force_tracking_error_kN", "test_time_s", "plots", "max_error_pct", "max_error_pct_per_dof",
                "compensation")


def last_state(run: Run, structure, P: np.ndarray, integrator) -> AlphaOSState:
    """The alpha-OS state after the record's last committed step."""
    steps = run.steps["step"]
    if len(steps) == 0:
        raise ConfigError(f"{run.path}: no committed step to resume from; start the run again")
    k = int(steps[-1])
    if not 0 < k < len(P):
        raise ConfigError(f"{run.path}: its last committed step is {k}, not one of the record's steps 1..{len(P) - 1}: "
                          f"the record does not belong to this ground motion; the record is unchanged and nothing moved")
    whole = np.asarray(steps, dtype=float)
    missing = np.setdiff1d(np.arange(1, k + 1), whole)
    if missing.size or len(whole) != k:  # a record is written step by step: a hole or a repeat is damage
        listed = ", ".join(str(int(m)) for m in missing[:5]) + (" ..." if missing.size > 5 else "")
        what = (f"step {listed} is missing" if missing.size == 1 else f"steps {listed} are missing" if missing.size
                else f"it holds {len(whole)} rows for steps 1..{k}")
        raise ConfigError(f"{run.path}: its steps are not 1..{k} one after the other ({what}): the record is "
                          f"damaged; the record is unchanged and nothing moved")
    try:
        row = lambda prefix: np.array([run.steps[column(prefix, d)][-1] for d in structure.dof_names])  # noqa: E731
        u, v, a, u_pred, R = row("u"), row("v"), row("a"), row("u_pred"), row("r")
    except KeyError as exc:
        raise ConfigError(f"{run.path}: the steps table has no column {exc} for the structure's DOFs "
                          f"{list(structure.dof_names)}; the record is unchanged and nothing moved") from None
    bad = [f"{prefix}_{d}" for prefix, values in (("u", u), ("v", v), ("a", a), ("u_pred", u_pred), ("r", R))
           for d, x in zip(structure.dof_names, values) if not np.isfinite(x)]
    if bad:
        raise ConfigError(f"{run.path}: the state of its last committed step {k} is not finite ({', '.join(bad)}): "
                          f"nothing to continue from; the record is unchanged and nothing moved")
    for d in structure.dof_names:  # the summary compares every step's u with NS: a hole there is damage too
        history = np.asarray(run.steps[column("u", d)], dtype=float)
        bad_rows = np.flatnonzero(~np.isfinite(history))
        if bad_rows.size:
            raise ConfigError(f"{run.path}: its step {int(steps[bad_rows[0]])} holds u_{d} = {history[bad_rows[0]]} "
                              f"(not finite): the record is damaged; the record is unchanged and nothing moved")
    v_pred = v - structure.dt * integrator.core.gamma * a
    return AlphaOSState(k, u, v, a, u_pred, v_pred, R, P[k].copy())


def check_inputs(run: Run, cfg, notify) -> None:
    """The files the resume reads again (structure, record, the driver's) as the run read them
    when it began (their SHA-256 in meta ``inputs``), else a ConfigError naming each that changed
    or is missing; a record without fingerprints is resumed with a warning."""
    recorded = run.meta.get("inputs")
    if recorded is not None and not (isinstance(recorded, list) and all(
            isinstance(e, dict) and all(isinstance(e.get(k), str) for k in ("what", "path", "sha256")) for e in recorded)):
        raise ConfigError(f"{run.path}: meta inputs is not a list of fingerprints ({{what, path, sha256}} each): "
                          f"{json.dumps(recorded)[:80]}; cannot check the run's input files; the record is "
                          f"unchanged and nothing moved")
    if recorded is None:
        notify(f"WARNING: {run.path} holds no fingerprints of the run's input files (recorded by an hsio "
               f"that took none): cannot check that the structure, record and driver files are those the run "
               f"began with")
        return
    changed, unchecked = compare_inputs(recorded, cfg)
    if changed:
        raise ConfigError(f"{run.path}: the resume would not continue the same test: input files differ from "
                          f"those the run began with:\n  " + "\n  ".join(changed)
                          + "\nrestore them as they were, or start a new run; the record is unchanged and nothing moved")
    for line in unchecked:
        notify(f"WARNING: {line} has no fingerprint in the record: cannot check that it is unchanged")


def check_ground(run: Run, ground) -> None:
    """The ground motion built again from the configuration is the one the run began with (its
    SHA-256 in meta ``ground_motion_sha256``), else a ConfigError: a record given in code, or a
    synthetic record that this hsio builds differently."""
    recorded = run.meta.get("ground_motion_sha256")
    if recorded is not None and ground_fingerprint(ground) != recorded:
        raise ConfigError(f"{run.path}: the resume would not continue the same test: the ground motion built "
                          f"from the configuration ({ground.name}) differs from the one the run began with "
                          f"({run.meta.get('record', '?')}; the sha256 of their samples differ); the record is "
                          f"unchanged and nothing moved")


def open_ledger(run: Run, notify) -> Ledger | None:
    """The specimen ledger the run is listed in (meta ``ledger``); None for a run without one."""
    folder = run.meta.get("ledger")
    if not isinstance(folder, str) or not folder:
        return None
    if not (Path(folder) / LEDGER_FILE).is_file():
        notify(f"WARNING: the specimen ledger {Path(folder) / LEDGER_FILE} the run was listed in is gone: "
               f"this resumed session is not listed")
        return None
    return Ledger(folder, run.meta.get("specimen_id") or "", warn=notify)


def restore_interlocks(site, run: Run, step: int, notify) -> None:
    """The interlocks go on with the running state the record holds at ``step`` (table
    ``interlocks``: the peak force per actuator), so the force-drop interlock judges the resumed
    steps against the peak the specimen reached before the interruption (docs/safety.md section 8)."""
    monitor = getattr(getattr(site, "loop", None), "monitor", None)
    table = run.table(INTERLOCK_TABLE)
    if monitor is None or not len(table.get("step", ())):
        return
    rows = np.flatnonzero(table["step"] <= step)
    if not rows.size:
        return
    last = int(rows[-1])
    peaks = {ch.name: float(table[column("peak_force_kN", ch.name)][last]) for ch in monitor.channels
             if column("peak_force_kN", ch.name) in table}
    monitor.restore(peaks)
    if peaks and monitor.settings.force_drop_fraction > 0:
        notify("the force-drop interlock goes on from the peaks the run reached: "
               + "; ".join(f"{name} {peak:.3f} kN" for name, peak in peaks.items()))


# How far an actuator may stand from the record's last measurement for a resume to go on (mm).
MAX_GAP_MM = 1.0


def last_measured(standing: dict, run: Run, external=()) -> dict[str, float]:
    """Per actuator that ``standing`` names, the displacement the record's last committed step
    measured of it (mm): for elements on one actuator each, the record's channel of that actuator;
    through setups, where the record's channels are the elements' basic DOFs, the actuator's own
    stroke in the ``actuators`` table at that step. Empty where the two cannot be compared (a
    state that could not be read, a record that lacks the actuator). Channels in ``external``
    record an instrument's reading (``displacement_from``), which a compliant load train keeps
    c F short of the rod: for them the rod's own transducer in the last controller sample of that
    step (:func:`last_rods`; left out in a record without samples). Through setups the table
    holds the rod's stroke."""
    if not standing or "error" in standing or not len(run.steps.get("step", ())):
        return {}
    if set(standing) == set(run.actuator_names):
        rods = last_rods(run, [name for name in run.actuator_names if name in set(external)])
        return {name: rods[name] if name in external else float(run.steps[column("disp", name)][-1])
                for name in run.actuator_names if name not in set(external) or name in rods}
    table = run.table("actuators")
    rows = np.flatnonzero(np.asarray(table.get("step", ()), dtype=float) == run.steps["step"][-1])
    if not rows.size or not all(column("disp", name) in table for name in standing):
        return {}
    return {name: float(table[column("disp", name)][rows[-1]]) for name in standing}


def last_rods(run: Run, names) -> dict[str, float]:
    """Per actuator in ``names``, its transducer's displacement in the last controller sample of
    the record's last committed step (mm); an actuator without a finite one there is left out."""
    if not names:
        return {}
    step = float(run.steps["step"][-1])
    try:
        samples = run.samples(first_step=int(step))
    except RecordError:
        return {}
    rows = np.flatnonzero(samples.get("step", np.empty(0)) == step)
    if not rows.size:
        return {}
    last = {name: float(samples[column("disp", name)][rows[-1]]) for name in names if column("disp", name) in samples}
    return {name: value for name, value in last.items() if np.isfinite(value)}


def gaps(standing: dict, run: Run, external=()) -> dict[str, float]:
    """Per actuator, where it stands less what the record's last step measured of it (mm;
    :func:`last_measured`); empty where the two cannot be compared."""
    last = last_measured(standing, run, external)
    return {name: float(standing[name]["displacement_mm"]) - value for name, value in last.items()}


def check_gaps(gap: dict[str, float], max_gap_mm: float, url: str) -> None:
    """Refuse to go on where an actuator stands more than ``max_gap_mm`` from where the record
    stops: the first step would take it back within one step, faster than the test moves, to a
    specimen that may no longer be where the record says (ConfigError; nothing has moved)."""
    far = {name: g for name, g in gap.items() if not abs(g) <= max_gap_mm}
    if not far:
        return
    where = "; ".join(f"{name} stands {g:+.3f} mm from the record's last step" for name, g in far.items())
    why = ("the in-process emulator does not outlive hsio: a new one starts at rest, its specimen without "
           "the run's history; resume against a controller that outlives the run (`hsio emulate`, real hardware) "
           "or start the run again" if url.startswith("emulator") else
           "the actuators moved since the run stopped (hydraulics off, a manual move, a controller restarted); "
           "bring them back to where the record stops, or give `hsio resume --max-gap MM` if the specimen "
           "may take that move within one step")
    raise ConfigError(f"{where}, more than {max_gap_mm:g} mm: not resumed, nothing moved ({why})")


def resume(run_dir: str | Path, progress=None, control: RunControl | None = None, notify=None,
           max_gap_mm: float = MAX_GAP_MM, keys=None) -> dict:
    """Continue the run recorded in ``run_dir`` from its last committed step; returns the summary.
    Refused (nothing moves) where an actuator stands more than ``max_gap_mm`` from the record's
    last measured displacement (:func:`check_gaps`). ``keys`` (a callable taking ``control``,
    returning an object with ``close()``: the terminal's keys, :class:`hsio.safety.terminal.KeyReader`)
    is started as the run's ``[safety] keys`` says, for the session."""
    from hsio.runner import (_state, build_record, check_dwell, describe, format_state, integrator_options,
                             load_run_structure, write_summary)

    run_dir = Path(run_dir)
    path = run_dir / RUN_FILE
    try:
        run = Run(path)
    except (FileNotFoundError, sqlite3.DatabaseError, KeyError) as exc:
        raise ConfigError(f"{path}: not a run record that can be resumed ({exc})") from None
    recorded = run.summary.get("exit_status")
    if recorded is not None and (isinstance(recorded, bool) or not isinstance(recorded, int)):
        raise ConfigError(f"{path}: not a run record that can be resumed (its summary's exit_status is "
                          f"{json.dumps(recorded)[:40]}, not a whole number)")
    if recorded == 0:
        raise ConfigError(f"{path}: the run finished; nothing to resume")
    if not isinstance(run.meta.get("config"), dict):
        raise ConfigError(f"{path}: not a run record that can be resumed (its meta holds no configuration table: "
                          f"config = {json.dumps(run.meta.get('config'))[:60]})")
    cfg = config_mod.from_dict(run.meta["config"], f"{path} (meta config)", replay=True)
    if cfg["integrator"]["method"] != "alpha_os":
        raise ConfigError(f"{path}: resume is available for the alpha_os method, not {cfg['integrator']['method']!r}")
    notify = notify or (lambda line: None)
    check_inputs(run, cfg, notify)
    structure = load_run_structure(cfg)
    if not structure.numerical_assembly().is_linear:
        raise ConfigError(f"{path}: resume needs a linear numerical part (its state is not in the record)")
    if cfg["compensation"]["mode"] != "off":
        raise ConfigError(f"{path}: the run compensated its actuators ([compensation] mode = "
                          f"{cfg['compensation']['mode']!r}), and the compensation's state (the commands of eq. 2, "
                          f"the online estimates) is not in the record: a resume would go on uncompensated, a "
                          f"different test; the record is unchanged and nothing moved")
    if structure.static:
        raise ConfigError(f"{path}: the structure holds static preloads ({', '.join(s.name for s in structure.static)}), "
                          f"which a resume cannot take over where the run left them (it would ramp them in again); "
                          f"the record is unchanged and nothing moved")
    ground = build_record(cfg, structure, replay=True)
    check_ground(run, ground)
    check_dwell(cfg, structure)  # before the record is opened for writing
    _, P = excitation(structure, ground)
    integrator = api.make_integrator(structure, "alpha_os", cfg["integrator"]["alpha"], **integrator_options(cfg, structure))
    state = last_state(run, structure, P, integrator)
    control = control or RunControl()
    test, hardware = cfg["test"], cfg["hardware"]
    safety = SafetySettings.from_table(cfg["safety"])
    error = None
    with stop_on_signals(control), contextlib.ExitStack() as cleanup:
        control.check_stop()  # a Ctrl-C while the program started: nothing opened, the record untouched
        summary_file = run_dir / "summary.json"
        if summary_file.exists() and not os.access(summary_file, os.W_OK):
            raise RecordError(f"{summary_file}: cannot write to it; the record is unchanged and nothing moved")
        ledger = open_ledger(run, notify)
        if ledger is not None:
            cleanup.callback(ledger.close)
        recorder = Recorder.append(path)
        cleanup.callback(recorder.close)
        if safety.control_socket:  # before the ledger and the record hear of the session
            server = ControlServer(run_dir, control)
            cleanup.callback(server.close)
        # a row of its own for this session (the earlier rows are left as they are), before the
        # record hears of the session: a ledger that cannot take it leaves the record as it was
        ledger_id = ledger.begin(run_dir, cfg.tables, structure.name, f"{ground.name} (resumed after step {state.i})",
                                 hsio.__version__) if ledger is not None else None
        why = run.stop_reason()  # read before this session's resume event, which would hide the stop events
        try:  # before anything opens: a disk that is full (or gone) refuses the session here
            if safety.control_socket:
                recorder.write_meta({"control_socket": str(server.path)})  # this session's (a long path: a new one)
            recorder.write_event(None, state.i, "resume", "", f"resumed after step {state.i} (hsio {hsio.__version__})")
        except (sqlite3.Error, RecordError) as exc:
            recorder.db.rollback()
            reason = str(exc).rpartition(" could not be written ")[2] if isinstance(exc, RecordError) else f"({exc})"
            refused = RecordError(f"{path}: cannot write to the record {reason}; the record is unchanged and "
                                  f"nothing moved")
            if ledger is not None:
                ledger.finish(ledger_id, outcome_name(BAD_INPUT), BAD_INPUT, str(refused))
            raise refused from None
        if keys is not None and safety.keys:
            cleanup.callback(keys(control).close)
        notify(f"resuming {path} after step {state.i}" + (f" (the run recorded its stop: {why})" if why else ""))
        site = end_state = stopped = None
        hold = {}
        try:
            control.enter("start-up")
            site = api.open_site(structure, hardware["url"], clock=hardware["clock"], test_rate=test["rate"],
                                 hold_fraction=test["hold_fraction"], n_avg=test["n_avg"],
                                 keep_samples=cfg["output"]["samples"],
                                 options=run.meta.get("emulator_settings", {}) if hardware["url"].startswith("emulator")
                                 else cfg["driver"], safety=safety)
            cleanup.callback(site.close)
            standing = _state(site)
            if ledger is not None:
                ledger.update(ledger_id, start_state=standing)
            line = format_state("the actuators stand at", standing)
            external = [e.name for e in structure.experimental if e.displacement_from]
            last = last_measured(standing, run, external)
            gap = gaps(standing, run, external)
            if last:
                line += "; the record's last step measured " + "; ".join(
                    f"{name} {value:+.3f} mm" for name, value in last.items())
            notify(line + (" (the first step goes on from where they stand)" if all(
                abs(g) <= max_gap_mm for g in gap.values()) else ""))
            check_gaps(gap, max_gap_mm, hardware["url"])
            restore_interlocks(site, run, state.i, notify)
            # the per-trial tables (instruments, actuators through setups) go on after their last trial
            trials = [t for t in (run.table(name).get("step") for name in ("instruments", "actuators"))
                      if t is not None and t.size]
            if trials:
                site.continue_trials(int(max(np.nanmax(t) for t in trials)))
            control.check_stop()
            control.enter("HS")
            try:
                api.simulate(structure, ground, site, recorder=recorder, progress=progress, integrator=integrator,
                             control=control, resume_state=state)
            except ExperimentStopped as exc:
                error = exc
            end_state = _state(site)  # where the specimen stands now, before the link closes
            site.close()
            steps = recorder.db.execute("SELECT COUNT(*) FROM steps").fetchone()[0]
            hold = site.report_final_hold(recorder, notify, steps)  # read back; a warning when not confirmed
        except (Exception, KeyboardInterrupt) as exc:  # before the steps (the hardware opening): hold, record
            error = exc
            held = site.hold() if site is not None else None
            reason = (str(exc) if isinstance(exc, HsioError) else "interrupted (Ctrl-C)"
                      if isinstance(exc, KeyboardInterrupt) else f"unexpected {exc!r}")
            if held is not None:
                reason += f"; {held.message}"
                if not isinstance(exc, ExperimentStopped):  # the operator hears the hold, as the record has it
                    exc.stop_message = reason
            try:
                if held is not None:  # as the run records a stop before its steps: the hold, then the stop
                    recorder.write_event(site.lab_time_s, state.i, "hold", "", held.message, commit=False)
                recorder.write_event(None, state.i, "stop", "", reason)
            except RecordError:  # a full disk took the record's last page: the message carries the stop
                pass
            stopped = reason  # the summary and the ledger say how the hold went, as the message does
            end_state = _state(site)
        status = exit_status(error)
        steps = recorder.db.execute("SELECT COUNT(*) FROM steps").fetchone()[0]
        # what the earlier session measured of itself alone (its wall time, late steps, tracking,
        # plots) would misdescribe the whole record: kept are the run's description and start; the
        # earlier sessions' summaries as they were are under ``earlier_sessions``
        # a run killed before its summary left none: its description is written again from the
        # record (the configuration, and the meta of the run's start)
        summary = {**describe(structure, cfg, ground, run_dir),
                   **{k: run.meta[k] for k in ("start_state", "dry_run_override", "version") if k in run.meta},
                   **{k: v for k, v in run.summary.items() if k not in SESSION_KEYS}}
        earlier = {k: v for k, v in run.summary.items() if k != "earlier_sessions"}  # kept whole, in order
        summary["earlier_sessions"] = [*run.summary.get("earlier_sessions", []), earlier] if earlier else \
            list(run.summary.get("earlier_sessions", []))
        summary.update(hold)
        summary.update(steps=steps, resumed_from=state.i, exit_status=status, outcome=outcome_name(status),
                       stopped=stopped or (str(error) if error else ""), run_dir=str(run_dir), end_state=end_state)
        u = np.array(recorder.db.execute("SELECT " + ", ".join(column("u", d) for d in structure.dof_names)
                                         + " FROM steps ORDER BY step").fetchall(), dtype=float)
        summary["peak_displacement_mm"] = [float(x) for x in np.max(np.abs(u), axis=0)] if len(u) else []
        ns = run.ns
        if len(u) and len(ns.get("step", ())):
            u_ns = np.column_stack([ns[column("u", d)] for d in structure.dof_names])[1:]  # NS from step 1, as u
            summary["max_error_pct"], summary["max_error_pct_per_dof"] = max_error_pct(u, u_ns)
            summary.setdefault("ns_peak_displacement_mm", [float(x) for x in np.max(np.abs(u_ns), axis=0)])
        write_summary(run_dir, recorder, summary, notify, replace=True)
        if ledger is not None:
            ledger.finish(ledger_id, summary["outcome"], status, summary["stopped"], end_state)
    if error is not None:
        error.run_dir = run_dir
        raise error
    return summary
