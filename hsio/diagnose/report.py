"""The diagnosis as a folder: PNG plots of the residual against time, velocity, force and
frequency (before and after the extension), a short text (report.md), diagnosis.json and the
extended model (actuator_model.toml)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy import signal

from hsio.diagnose.effects import EFFECTS
from hsio.diagnose.modelfile import write_model
from hsio.diagnose.plotting import figure, label, mark_blocks, save
from hsio.diagnose.outcome import ratio
from hsio.diagnose.loop_rate import SLOW
from hsio.diagnose.selection import NONE, TOO_FEW, UNEXPLAINED, Diagnosis
from hsio.diagnose.gain_tie import OPEN as GAIN_OPEN, SETTLING as GAIN_SETTLING
from hsio.diagnose.timing import EXTRA_CHANNEL as TIMING_CHANNEL, OPEN

MAX_POINTS = 20000  # scatter plots thin the record to this many points

BEFORE = dict(color="C3", label="baseline (lag)")
AFTER = dict(color="C0", label="extended")


def _residuals(d: Diagnosis) -> tuple[np.ndarray, np.ndarray]:
    m = d.record.measured_mm
    return m - d.baseline.prediction, m - d.extended.prediction


def plot_time(d: Diagnosis, path: Path) -> Path:
    rec = d.record
    t = rec.time_s
    before, after = _residuals(d)
    t_split = d.n_train * rec.dt
    fig, axes = figure(2, 1, (11, 6.5))
    ax = axes[0]
    # A window of the held-out part where the baseline is worst, to see the departure itself.
    w = max(int(round(1.0 / rec.dt)), 50)
    power = np.convolve(before[d.n_train:] ** 2, np.ones(w) / w, mode="same")
    centre = d.n_train + int(np.argmax(power))
    span = slice(max(centre - w // 2, 0), min(centre + w // 2, rec.n))
    ax.plot(t[span], rec.command_mm[span], color="0.6", lw=1.0, label="command")
    ax.plot(t[span], rec.measured_mm[span], color="k", lw=1.6, label="measured")
    ax.plot(t[span], d.baseline.prediction[span], lw=1.0, ls="--", **BEFORE)
    ax.plot(t[span], d.extended.prediction[span], lw=1.0, **AFTER)
    label(ax, "time (s)", "displacement (mm)", "held-out part, where the baseline is worst", loc="upper right")
    ax = axes[1]
    ax.plot(t, before, lw=0.5, alpha=0.8, **BEFORE)
    ax.plot(t, after, lw=0.5, alpha=0.8, **AFTER)
    mark_blocks(ax, [(t_split, "fit | held out")])
    label(ax, "time (s)", "measured - model (mm)", loc="lower left")
    return save(fig, path, f"Residual against time: RMS held out {d.baseline.rms_test_mm:.4f} -> {d.extended.rms_test_mm:.4f} mm")


def _scatter(d: Diagnosis, x: np.ndarray, xlabel: str, title: str, path: Path) -> Path:
    before, after = _residuals(d)
    step = max(1, x.size // MAX_POINTS)
    fig, axes = figure(1, 2, (11, 4.2), sharey=True)
    for ax, r, style, name in ((axes[0], before, BEFORE, "before"), (axes[1], after, AFTER, "after")):
        ax.plot(x[::step], r[::step], ".", ms=1.5, alpha=0.4, color=style["color"])
        label(ax, xlabel, "measured - model (mm)" if ax is axes[0] else None, f"{name}: {style['label']}", legend=False)
    return save(fig, path, title)


def plot_spectrum(d: Diagnosis, path: Path) -> Path:
    before, after = _residuals(d)
    fs = d.record.rate_hz
    nper = int(min(d.record.n, 2 ** int(np.log2(max(fs * 4, 64)))))
    fig, ax = figure(1, 1, (9, 4.2))
    for r, style in ((before, BEFORE), (after, AFTER)):
        f, p = signal.welch(r, fs=fs, nperseg=nper)
        ax.semilogy(f[1:], np.sqrt(p[1:]), lw=1.0, **style)
    f, p = signal.welch(d.record.command_mm, fs=fs, nperseg=nper)
    ax.semilogy(f[1:], np.sqrt(p[1:]), color="0.6", lw=0.8, label="command")
    ax.set_xlim(0, min(fs / 2, 50.0))
    label(ax, "frequency (Hz)", "amplitude density (mm/sqrt(Hz))", "Residual against frequency", which="both")
    return save(fig, path)


def evidence(d: Diagnosis) -> dict:
    """Where the baseline departs: its residual's correlation with velocity, displacement and
    force, the worst second, and the frequency where the residual is largest."""
    rec = d.record
    before, _ = _residuals(d)
    v = rec.smoothed_velocity()

    def corr(a, b):
        if np.std(a) == 0 or np.std(b) == 0:
            return 0.0
        return float(np.corrcoef(a, b)[0, 1])

    w = max(int(round(1.0 / rec.dt)), 10)
    power = np.convolve(before**2, np.ones(w) / w, mode="same")
    worst = int(np.argmax(power))
    fs = rec.rate_hz
    nper = int(min(rec.n, 2 ** int(np.log2(max(fs * 4, 64)))))
    f, p = signal.welch(before - before.mean(), fs=fs, nperseg=nper)
    out = {
        "corr_velocity": corr(before, v),
        "corr_abs_velocity": corr(np.abs(before), np.abs(v)),
        "corr_displacement": corr(before, rec.command_mm),
        "worst_time_s": worst * rec.dt,
        "worst_rms_mm": float(np.sqrt(power[worst])),
        "worst_speed_mm_s": float(np.sqrt(np.mean(v[max(worst - w // 2, 0): worst + w // 2] ** 2))),
        "residual_peak_hz": float(f[1:][np.argmax(p[1:])]),
        "rms_first_half_mm": float(np.sqrt(np.mean(before[: rec.n // 2] ** 2))),
        "rms_second_half_mm": float(np.sqrt(np.mean(before[rec.n // 2:] ** 2))),
    }
    if rec.force_kN is not None:
        out["corr_force"] = corr(before, rec.force_kN)
    return out


def _params_text(params: dict) -> str:
    return ", ".join(f"{k} = {v:.5g}" for k, v in params.items())


def text(d: Diagnosis, ev: dict) -> str:
    rec, b = d.record, d.baseline
    lines = [f"# Actuator diagnosis: {Path(rec.source).name}", "",
             f"Record: {rec.n} samples at {rec.rate_hz:g} Hz ({rec.duration_s:.2f} s"
             + (f"; the model steps at the controller's {1.0 / rec.controller_dt:g} Hz and is compared at these samples"
                if rec.controller_dt is not None and rec.controller_dt < rec.dt else "") + "), "
             f"{'with' if rec.force_kN is not None else 'without'} force. Every model is fitted on the first "
             f"{100 * d.n_train / rec.n:.0f} % (0 to {d.n_train * rec.dt:.2f} s); models are chosen on the next "
             f"{100 * (d.n_choose - d.n_train) / rec.n:.0f} % (to {d.n_choose * rec.dt:.2f} s) and every gain is scored on the "
             f"last {100 * (rec.n - d.n_choose) / rec.n:.0f} %, which neither the fit nor the choice saw.",
             "", "## What the baseline gets wrong", "",
             f"The emulator's velocity-proportional lag (a first-order lag of the command, lag = "
             f"{1e3 * b.params['lag_s']:.2f} ms) predicts the measured displacement with an RMS error of "
             f"{b.rms_train_mm:.4f} mm on the fitted part and {b.rms_test_mm:.4f} mm held out.",
             f"Its error is largest around t = {ev['worst_time_s']:.1f} s ({ev['worst_rms_mm']:.4f} mm RMS over 1 s, "
             f"where the command moves at {ev['worst_speed_mm_s']:.1f} mm/s RMS); the residual's spectrum peaks at "
             f"{ev['residual_peak_hz']:.2f} Hz. Correlation of the residual with the command velocity "
             f"{ev['corr_velocity']:+.2f}, with its magnitude {ev['corr_abs_velocity']:+.2f}, with the command "
             f"{ev['corr_displacement']:+.2f}" + (f", with the force {ev['corr_force']:+.2f}." if "corr_force" in ev else "."),
             ""]
    floor = d.floor.sensor_floor_mm
    if d.cause in (NONE, UNEXPLAINED, TOO_FEW, SLOW):
        best = min(d.candidates, key=lambda c: c.fit.rms_choose_mm) if d.candidates else None
        why = d.too_short or d.slow_record
        lines += [f"## Cause: {d.cause}", ""] + ([f"No cause is named: {why}.", ""] if why else []) + [
                  f"No candidate improves the choosing block by the margin of {d.margin:g}x"
                  + (f" (best: {best.cause}, {best.choose_gain:.3f}x)." if best else ".")]
        if d.cause == SLOW:
            lines += ["Neither none nor unexplained: at this rate the record cannot tell the loop's period from the "
                      "actuator's dynamics. The baseline and the candidates above are fitted at the record's rate.", ""]
        elif d.cause == TOO_FEW:
            lines += ["Neither none nor unexplained: blocks this short cannot tell the lag's residual from the sensor "
                      f"floor ({floor:.4f} mm) either. The baseline above is fitted; a longer record would judge it.", ""]
        elif d.cause == NONE:
            lines += [f"The lag alone reaches the sensor floor ({floor:.4f} mm: noise and quantisation, estimated from "
                      "the data); nothing is named.", ""]
        else:
            lines += [f"Yet the baseline stays {ratio(d.structure.rms_test_mm, floor):.1f} times above the sensor floor "
                      f"({floor:.4f} mm): something the library does not hold is at work. "
                      f"{d.residual_json()['remains'].capitalize()}.", ""]
    else:
        single = d.single
        effect = EFFECTS[d.cause]
        lines += [f"## Cause: {effect.title} ({d.cause})", "",
                  f"Physically: {effect.cause}.",
                  f"Fitted: {effect.describe(single.fit.params)}. Held-out RMS error {single.fit.rms_test_mm:.4f} mm: "
                  f"{single.gain:.2f} times better than the baseline (a cause is named only above {d.margin:g}x).", ""]
        if d.timing is not None:
            lines += _timing_text(d)
        if d.gain_tie is not None:
            lines += _gain_text(d)
        if len(d.extended.effects) > 1:
            lines += [f"## Best combination: {d.extended.name}", "",
                      "; ".join(EFFECTS[e].describe(d.extended.params) for e in d.extended.effects) + ".",
                      f"Held-out RMS error {d.extended.rms_test_mm:.4f} mm, a gain of {d.gain:.2f} over the baseline; "
                      "each added effect had to clear the margin over the combination before it.", ""]
        else:
            lines += ["No further effect improves on it by the margin: the extended model is the single cause.", ""]
    if d.cause not in (NONE, UNEXPLAINED, TOO_FEW, SLOW):
        lines += ["## What remains", "",
                  ("The extended model reaches the sensor floor: " if d.explained else "The extended model stays above the sensor floor: ")
                  + d.residual_json()["remains"] + ".", ""]
    lines += ["## Candidates (each fitted on top of the lag)", "",
              "| cause | scored RMS (mm) | scoring gain | choosing gain | parameters |", "| --- | --- | --- | --- | --- |"]
    for c in d.candidates:
        lines.append(f"| {c.cause} | {c.fit.rms_test_mm:.4f} | {c.gain:.3f} | {c.choose_gain:.3f}{' *' if c.named else ''} | "
                     f"{_params_text(c.fit.params)} |")
    lines += ["", f"(* clears the margin of {d.margin:g}x on the choosing block)", "",
              "## Files", "",
              "- residual_time.png: the departure where the baseline is worst, and the residual against time",
              "- residual_velocity.png, residual_force.png: the residual against command velocity and force",
              "- residual_spectrum.png: the residual against frequency",
              "- actuator_model.toml: the extended model; [emulator] configures the emulator and `hsio run` "
              "([hardware] actuator_model = \"actuator_model.toml\")",
              "- diagnosis.json: every number above", ""]
    return "\n".join(lines)


def _timing_text(d: Diagnosis) -> list[str]:
    """A transport delay against a late displacement channel: what the force's timing says."""
    t = d.timing
    if t.verdict != OPEN:
        other = "a late displacement channel" if t.verdict == "transport_delay" else "a delay in the loop"
        return [f"A delay in the loop and a late displacement channel predict the same displacement; the force tells them "
                f"apart: {t.reason}. So it is not {other}.", ""]
    lines = ["A delay in the loop and a late displacement channel predict the same displacement from the command "
             f"(a delay commutes with the loop): {t.reason}."]
    if d.equivalent is not None:
        other = EFFECTS[d.equivalent.cause]
        lines.append(f"Equivalently: {other.describe(d.equivalent.fit.params)} ({d.equivalent.cause}) predicts the "
                     "displacement as well.")
    lines += [f"The channel that would tell them apart: {TIMING_CHANNEL}.", ""]
    return lines


def _gain_text(d: Diagnosis) -> list[str]:
    """A transducer gain error against a compliant load train (hsio/diagnose/gain_tie.py)."""
    t = d.gain_tie
    if t.verdict != GAIN_OPEN:
        return [f"A transducer gain and a load-train compliance tie on this record: {t.reason}.", ""]
    return [f"Equally likely: {t.reason}. The cause is named {d.cause} by the library's order only; "
            f"{d.equivalent.cause if d.equivalent else 'the other'} is as likely.",
            f"What would tell them apart: {GAIN_SETTLING}.", ""]


def provenance(d: Diagnosis) -> dict:
    return {
        "source": d.record.source, "samples": d.record.n, "rate_hz": d.record.rate_hz,
        "controller_rate_hz": None if d.record.controller_dt is None else 1.0 / d.record.controller_dt,
        "train_fraction": d.n_train / d.record.n, "cause": d.cause, "combination": list(d.extended.effects),
        "baseline_lag_s": d.baseline.params["lag_s"], "baseline_rms_test_mm": d.baseline.rms_test_mm,
        "extended_rms_test_mm": d.extended.rms_test_mm, "gain": d.gain,
        "offset_mm": d.extended.params.get("offset_mm", 0.0),
    }


def model_params(d: Diagnosis) -> dict:
    return {k: v for k, v in d.extended.params.items() if k != "offset_mm"}


def write_report(d: Diagnosis, out_dir: str | Path) -> dict:
    """Write the plots, report.md, diagnosis.json and actuator_model.toml; return their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {"time": plot_time(d, out / "residual_time.png"),
             "velocity": _scatter(d, d.record.smoothed_velocity(), "command velocity over 5 ms (mm/s)",
                                  "Residual against command velocity", out / "residual_velocity.png")}
    if d.record.force_kN is not None:
        files["force"] = _scatter(d, d.record.force_kN, "measured force (kN)", "Residual against force", out / "residual_force.png")
    files["spectrum"] = plot_spectrum(d, out / "residual_spectrum.png")
    ev = evidence(d)
    files["model"] = write_model(out / "actuator_model.toml", model_params(d), provenance(d))
    files["text"] = out / "report.md"
    files["text"].write_text(text(d, ev), encoding="utf-8")
    files["json"] = out / "diagnosis.json"
    files["json"].write_text(json.dumps({**d.to_json(), "evidence": ev}, indent=2), encoding="utf-8")
    return {k: str(v) for k, v in files.items()}
