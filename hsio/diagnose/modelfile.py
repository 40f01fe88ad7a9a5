"""The extended actuator model as a TOML file: an [emulator] table of ServoConfig fields for the
emulator and ``hsio run``, and a [diagnose] table with its provenance.

    [emulator]
    lag_s = 0.0216
    transport_delay_s = 0.00518

    [diagnose]
    source = "0A.txt"
    cause = "transport_delay"
    gain = 4.68
    ...

A run uses it with ``[hardware] actuator_model = "model.toml"``: the model's [emulator] table
is merged under the run's own [emulator] table (the run's keys win).
"""

from __future__ import annotations

import json
import math
from hsio.config import read_toml
from pathlib import Path

from hsio.errors import ConfigError

# Model parameters that are emulator settings (ServoConfig fields) and the ranges it accepts.
EMULATED = ("lag_s", "transport_delay_s", "velocity_threshold_mm_s", "velocity_limit_mm_s", "backlash_mm",
            "lag_retract_s", "compliance_mm_per_kN", "displacement_gain", "dead_band_mm", "servo_frequency_hz",
            "servo_damping", "sensor_drift_mm_s", "channel_skew_s")
NON_NEGATIVE = ("transport_delay_s", "velocity_threshold_mm_s", "backlash_mm", "compliance_mm_per_kN", "dead_band_mm",
                "servo_frequency_hz", "channel_skew_s")


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        if not math.isfinite(value):
            raise ValueError(f"cannot write {value!r} to TOML")
        return repr(float(value)) if isinstance(value, float) else str(value)
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string is a JSON string for these characters
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def emulator_table(params: dict) -> tuple[dict, dict]:
    """Split fitted parameters into the emulator's settings and those it cannot take (with why)."""
    table, refused = {}, {}
    for name in EMULATED:
        if name not in params:
            continue
        value = float(params[name])
        if name in NON_NEGATIVE and value < 0:
            refused[name] = (value, "negative: the force channel's sign is opposite to the emulator's "
                                    "(flip the force scale to emulate it)")
            continue
        table[name] = value
    return table, refused


def write_model(path: str | Path, params: dict, provenance: dict) -> Path:
    """Write the extended model: [emulator] (what the emulator takes) and [diagnose] (provenance)."""
    path = Path(path)
    table, refused = emulator_table(params)
    lines = ["# Actuator model fitted by `hsio diagnose`; the [emulator] table holds emulator settings",
             "# (hsio.emulators.servo.ServoConfig). Use it in a run with [hardware] actuator_model = \"<this file>\".",
             "", "[emulator]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in table.items()]
    lines += ["", "[diagnose]"]
    prov = dict(provenance)
    for name, (value, why) in refused.items():
        prov[f"not_emulated_{name}"] = value
        prov[f"not_emulated_{name}_why"] = why
    for key, value in prov.items():
        if value is None:
            continue
        lines.append(f"{key} = {_toml_value(value)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def load_model(path: str | Path) -> dict:
    """The [emulator] table of an actuator-model file, checked by the emulator's own ServoConfig."""
    from hsio.emulators.servo import ServoConfig

    path = Path(path)
    data = read_toml(path, "actuator model")
    table = data.get("emulator")
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: an actuator model needs an [emulator] table")
    try:
        ServoConfig.from_dict(table)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return dict(table)


def servo_config(path: str | Path, **overrides):
    """A ServoConfig from an actuator-model file, with ``overrides`` on top."""
    from hsio.emulators.servo import ServoConfig

    return ServoConfig.from_dict({**load_model(path), **overrides})


def merged_emulator_table(model_path: str | Path | None, table: dict) -> dict:
    """The run's [emulator] table over the model file's (``model_path`` empty: the table unchanged)."""
    if not model_path:
        return table
    return {**load_model(model_path), **table}
