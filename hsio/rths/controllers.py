"""The tracking controllers available to the RTHS loop, by name."""

from __future__ import annotations

from hsio.rths import amb, ats, pi_lead
from hsio.rths.plant import PlantParameters
from hsio.rths.stage import Stage

DESCRIPTIONS = {
    "pi-lead": "the benchmark's sample controller: PI 2 + 95/s with phase lead 50.8 (s+168.6)/(s+8570)",
    "ats": "adaptive time series compensator (Chae et al. 2013), 1 s window, refit every 16 samples",
    "amb": "hsio's adaptive model-based compensator: plant-model inverse with filtered-x NLMS adaptation",
}
NAMES = tuple(DESCRIPTIONS)


def make(name: str, fs: float, model: PlantParameters) -> Stage:
    """A fresh stage; ``model`` is the identified (nominal) plant, which model-based controllers use."""
    if name == "pi-lead":
        return pi_lead.make(fs)
    if name == "ats":
        return ats.make(fs)
    if name == "amb":
        return amb.make(fs, model)
    raise ValueError(f"unknown controller {name!r}; known: {', '.join(NAMES)}")
