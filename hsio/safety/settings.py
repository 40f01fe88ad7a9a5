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


# The interlocks' thresholds, each bounded: beyond these a threshold never trips on any rig.
UPPER_BOUNDS = (("following_error_mm", 10000.0, "mm"), ("following_error_kN", 100000.0, "kN"),
                ("jump_mm", 10000.0, "mm"), ("jump_kN", 100000.0, "kN"), ("force_drop_window_s", 3600.0, "s"))


def check_table(table: dict, where: str) -> None:
    """Ranges of the [safety] keys; raises ConfigError naming the key."""
    from hsio.errors import ConfigError

    for key in ("stroke_margin", "force_margin", "velocity_margin"):
        if not 0.0 <= table[key] < 1.0:
            raise ConfigError(f"{where}: {key} must be in [0, 1) (a fraction of the limit), got {table[key]}")
    for key, high, unit in UPPER_BOUNDS:
        if not 0 < table[key] <= high:
            raise ConfigError(f"{where}: {key} must be positive and at most {high:g} {unit} (a larger value "
                              f"turns the interlock off in effect: use interlocks = false to say so), got {table[key]}")
    if not 0 <= table["following_time_s"] <= 60.0:
        raise ConfigError(f"{where}: following_time_s must be within 0..60 s (a larger value turns the following-error "
                          f"interlock off in effect), got {table['following_time_s']}")
    if not 0.0 < table["warning_fraction"] <= 1.0:
        raise ConfigError(f"{where}: warning_fraction must be in (0, 1], got {table['warning_fraction']}")
    if not 0.0 <= table["force_drop_fraction"] < 1.0:
        raise ConfigError(f"{where}: force_drop_fraction must be in [0, 1) (0: off), got {table['force_drop_fraction']}")
    if not table["force_drop_min_kN"] >= 0:
        raise ConfigError(f"{where}: force_drop_min_kN must not be negative, got {table['force_drop_min_kN']}")
