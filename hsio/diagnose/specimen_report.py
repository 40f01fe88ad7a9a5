"""The specimen diagnosis as a folder: the loops and residual (PNG), report.md, diagnosis.json and
the extended specimen model (specimen_model.toml, one per segment), which
hsio.specimens.make_specimen loads (:func:`load_specimen_model`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from hsio.diagnose.outcome import ratio
from hsio.diagnose.specimen_fit import EFFECTS, NONE, TOO_FEW, UNEXPLAINED, SpecimenDiagnosis, specimen_table


def _toml(value) -> str:
    if isinstance(value, str):
        return json.dumps(value)
    if not math.isfinite(value):
        raise ValueError(f"cannot write {value!r} to TOML")
    return repr(float(value))


def write_specimen_model(path: str | Path, d: SpecimenDiagnosis) -> Path:
    """The extended model as a specimen table (kind and parameters); provenance in comments."""
    path = Path(path)
    table = specimen_table(d.extended)
    lines = ["# Specimen model fitted by `hsio diagnose --specimen`: load it with",
             "# hsio.diagnose.specimen_report.load_specimen_model or give its keys as a specimen table.",
             f"# source: {d.record.source}; model: {d.extended.name}; held-out gain {d.gain:.3f}",
             f"# load-cell offset {d.extended.params.get('offset_kN', 0.0):.6g} kN (not part of the specimen)"]
    if "skew_s" in d.extended.params:
        lines.append(f"# force channel skew {d.extended.params['skew_s']:.6g} s (a measurement effect, not the specimen's)")
    lines += [f"{k} = {_toml(v)}" for k, v in table.items()]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def load_specimen_model(path: str | Path):
    """The specimen a model file describes (hsio.specimens.make_specimen of its table)."""
    from hsio.config import read_toml
    from hsio.errors import ConfigError
    from hsio.specimens import make_specimen

    table = read_toml(Path(path), "specimen model")
    try:
        return make_specimen(table)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def plot(d: SpecimenDiagnosis, path: Path) -> Path:
    from hsio.diagnose.plotting import figure, label, mark_blocks, save

    rec = d.record
    held = slice(d.n_choose, rec.n)
    fig, axes = figure(1, 2, (12, 4.6))
    ax = axes[0]
    ax.plot(rec.displacement_mm[held], rec.force_kN[held], color="k", lw=1.4, label="measured")
    ax.plot(rec.displacement_mm[held], d.baseline.prediction[held], color="C3", lw=0.9, ls="--", label="spring + dashpot")
    ax.plot(rec.displacement_mm[held], d.extended.prediction[held], color="C0", lw=0.9, label=d.extended.name)
    label(ax, "displacement (mm)", "force (kN)", "scoring block (neither fitted nor chosen on)")
    ax = axes[1]
    t = rec.time_s
    ax.plot(t, rec.force_kN - d.baseline.prediction, color="C3", lw=0.5, label="baseline")
    ax.plot(t, rec.force_kN - d.extended.prediction, color="C0", lw=0.5, label="extended")
    mark_blocks(ax, [(d.n_train * rec.dt, "fit | choose"), (d.n_choose * rec.dt, "choose | score")], fontsize=7)
    label(ax, "time (s)", "measured - model (kN)")
    return save(fig, path, f"{Path(rec.source).name}: RMS on the scoring block {d.baseline.rms_test_kN:.4f} -> "
                           f"{d.extended.rms_test_kN:.4f} kN")


def section(d: SpecimenDiagnosis) -> list[str]:
    rec, b = d.record, d.baseline
    lines = [f"## {Path(rec.source).name}", "",
             f"{rec.n} samples at {rec.rate_hz:g} Hz ({rec.duration_s:.2f} s of motion). Fitted on samples "
             f"[0, {d.n_train}), models chosen on [{d.n_train}, {d.n_choose}), every gain scored on "
             f"[{d.n_choose}, {rec.n}): data used neither to fit nor to choose.", "",
             f"Baseline (linear spring and viscous dashpot): k = {b.params['k']:.4g} kN/mm, c = {b.params['c']:.4g} kN s/mm; "
             f"RMS error {b.rms_test_kN:.4f} kN on the scoring block, against a sensor floor of "
             f"{d.floor.sensor_floor_mm:.4f} kN (load-cell noise and quantisation, and the displacement noise through k).", ""]
    if d.too_short:
        lines += [f"No cause is named: {d.too_short}.", ""]
    if d.cause == TOO_FEW:
        lines += ["**Cause: too few samples to judge.** Neither a cause, nor none, nor unexplained: the baseline "
                  "above is fitted, but the record cannot say whether it is right.", ""]
    elif d.cause == NONE:
        lines += ["**Cause: none.** The spring and dashpot predict the force to within the sensor floor.", ""]
    elif d.cause == UNEXPLAINED:
        lines += [f"**Cause: unexplained.** No candidate improves the choosing block by {d.margin:g}x, yet the error "
                  f"stays {ratio(d.structure.rms_test_mm, d.floor.sensor_floor_mm):.1f} times the sensor floor.", ""]
    else:
        single = d.single
        e = EFFECTS[d.cause]
        lines += [f"**Cause: {e.title} ({d.cause}).** Physically: {e.cause}.",
                  f"Fitted: {e.describe(single.fit.params)}; scoring-block gain {single.gain:.2f} "
                  f"(choosing-block gain {single.choose_gain:.2f}).", ""]
        if len(d.extended.effects) > 1:
            lines += [f"Best combination: {d.extended.name}, gain {d.gain:.2f} on the scoring block."]
            for name in d.extended.effects[1:]:
                lines.append(f"- {EFFECTS[name].title}: {EFFECTS[name].describe(d.extended.params)}. {EFFECTS[name].cause}.")
            lines.append("")
        if not d.explained:
            lines += [f"What remains: RMS {d.structure.rms_test_mm:.4f} kN, {ratio(d.structure.rms_test_mm, d.floor.sensor_floor_mm):.1f} "
                      f"times the sensor floor; the model does not explain everything.", ""]
    lines += ["| cause | choosing gain | scoring gain | parameters |", "| --- | --- | --- | --- |"]
    for c in d.candidates:
        params = ", ".join(f"{k} = {v:.4g}" for k, v in c.fit.params.items())
        lines.append(f"| {c.cause} | {c.choose_gain:.3f}{' *' if c.named else ''} | {c.gain:.3f} | {params} |")
    lines += ["", f"(* clears the margin of {d.margin:g}x on the choosing block)", ""]
    return lines


def write_specimen_report(diagnoses: list[SpecimenDiagnosis], out_dir: str | Path) -> dict:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    text = ["# Specimen diagnosis", "",
            "Each record (each segment of a paused DAQ record) is fitted with a linear spring and viscous "
            "dashpot, then with each candidate effect on top; a cause is named when it lowers the error on "
            "the choosing block by the margin, and its gain is reported on the scoring block.", ""]
    for i, d in enumerate(diagnoses, start=1):
        suffix = "" if len(diagnoses) == 1 else f"_segment{i}"
        files[f"plot{suffix}"] = str(plot(d, out / f"specimen{suffix}.png"))
        files[f"model{suffix}"] = str(write_specimen_model(out / f"specimen_model{suffix}.toml", d))
        text += section(d)
        text += [f"Files: specimen{suffix}.png (loops and residual), specimen_model{suffix}.toml (the extended model).", ""]
    files["text"] = str(out / "report.md")
    (out / "report.md").write_text("\n".join(text), encoding="utf-8")
    files["json"] = str(out / "diagnosis.json")
    (out / "diagnosis.json").write_text(json.dumps(specimen_json(diagnoses), indent=2), encoding="utf-8")
    return files


def specimen_json(diagnoses: list[SpecimenDiagnosis]) -> dict:
    if len(diagnoses) == 1:
        return diagnoses[0].to_json()
    return {"segments": [d.to_json() for d in diagnoses], "causes": [d.cause for d in diagnoses]}
