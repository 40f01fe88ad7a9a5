"""Holding, and saying so only when it is confirmed (docs/safety.md section 3).

After a stop every actuator is told to hold; then each is asked whether it holds
(:meth:`hsio.interfaces.Actuator.holding`). An actuator that cannot tell is reported as
unconfirmed, never as holding.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class HoldReport:
    """Per actuator: True (holds, read back), False (reported not holding), None (cannot tell)."""

    states: dict

    @property
    def confirmed(self) -> bool:
        return bool(self.states) and all(v is True for v in self.states.values())

    @property
    def message(self) -> str:
        if not self.states:
            return "no actuators were open"
        if self.confirmed:
            return "the actuators hold (confirmed by read-back)"
        parts = []
        refused = [n for n, v in self.states.items() if v is False]
        unknown = [n for n, v in self.states.items() if v is None]
        held = [n for n, v in self.states.items() if v is True]
        if refused:
            parts.append(f"WARNING: {', '.join(refused)} did not confirm the hold (reads back not holding)")
        if unknown:
            parts.append(f"the hold of {', '.join(unknown)} could not be confirmed (no read-back)")
        if held:
            parts.append(f"{', '.join(held)} hold (confirmed)")
        return "; ".join(parts)

    def as_dict(self) -> dict:
        return {"confirmed": self.confirmed, "states": {k: v for k, v in self.states.items()},
                "message": self.message}


def read_back(actuators) -> HoldReport:
    """Ask each actuator whether it holds; an error while asking counts as 'cannot tell'."""
    states = {}
    for actuator in actuators:
        try:
            value = actuator.holding()
        except Exception:
            value = None
        states[actuator.name] = None if value is None else bool(value)
    return HoldReport(states)
