"""The [safety] table as settings (docs/safety.md; defaults documented in docs/config.md)."""

from __future__ import annotations

from dataclasses import dataclass, fields

DEFAULTS = {
    # Dry run (section 2): refuse when the prediction exceeds (1 - margin) x the limit.
    "dry_run": True,
    "override": False,
    "stroke_margin": 0.05,
    "force_margin": 0.05,
    "velocity_margin": 0.05,
    # Interlocks of the control loop (section 3), checked every controller period.
    "interlocks": True,
    "following_error_mm": 10.0,
    "following_error_kN": 25.0,
    "following_time_s": 0.5,
    "jump_mm": 10.0,
    "jump_kN": 100.0,
    "warning_fraction": 0.9,
    "force_drop_fraction": 0.0,
    "force_drop_min_kN": 1.0,
    "force_drop_window_s": 2.0,
    # Operator control (section 4).
    "control_socket": True,
    "keys": True,
}


@dataclass(frozen=True)
class SafetySettings:
    """Checked [safety] keys (hsio.config checks types and ranges)."""

    dry_run: bool = True
    override: bool = False
    stroke_margin: float = 0.05
    force_margin: float = 0.05
    velocity_margin: float = 0.05
    interlocks: bool = True
    following_error_mm: float = 10.0
    following_error_kN: float = 25.0
    following_time_s: float = 0.5
    jump_mm: float = 10.0
    jump_kN: float = 100.0
    warning_fraction: float = 0.9
    force_drop_fraction: float = 0.0
    force_drop_min_kN: float = 1.0
    force_drop_window_s: float = 2.0
    control_socket: bool = True
    keys: bool = True

    @classmethod
    def from_table(cls, table: dict | None) -> "SafetySettings":
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in (table or {}).items() if k in known})


def check_table(table: dict, where: str) -> None:
    """Ranges of the [safety] keys; raises ConfigError naming the key."""
    from hsio.errors import ConfigError

    for key in ("stroke_margin", "force_margin", "velocity_margin"):
        if not 0.0 <= table[key] < 1.0:
            raise ConfigError(f"{where}: {key} must be in [0, 1) (a fraction of the limit), got {table[key]}")
    for key in ("following_error_mm", "following_error_kN", "jump_mm", "jump_kN", "force_drop_window_s"):
        if not table[key] > 0:
            raise ConfigError(f"{where}: {key} must be positive, got {table[key]}")
    if not table["following_time_s"] >= 0:
        raise ConfigError(f"{where}: following_time_s must not be negative, got {table['following_time_s']}")
    if not 0.0 < table["warning_fraction"] <= 1.0:
        raise ConfigError(f"{where}: warning_fraction must be in (0, 1], got {table['warning_fraction']}")
    if not 0.0 <= table["force_drop_fraction"] < 1.0:
        raise ConfigError(f"{where}: force_drop_fraction must be in [0, 1) (0: off), got {table['force_drop_fraction']}")
    if not table["force_drop_min_kN"] >= 0:
        raise ConfigError(f"{where}: force_drop_min_kN must not be negative, got {table['force_drop_min_kN']}")
