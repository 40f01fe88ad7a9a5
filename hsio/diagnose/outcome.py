"""What the actuator and the specimen diagnoses share: the answers besides a named cause, the
choice among the candidates that clear the margin, and the verdict on the sensor floor
(docs/diagnose.md, "Honest selection" and "What the model cannot explain")."""

from __future__ import annotations

import math
from typing import Callable, Sequence

from hsio.diagnose import residual as residual_mod

NONE = "none"
UNEXPLAINED = "unexplained"
TOO_FEW = "too_few_samples"  # a record too short to judge: neither a cause nor none nor unexplained
PARSIMONY = 1.02  # a candidate within this factor of the best, with fewer parameters or earlier in the library, wins


def parsimonious(named: Sequence, error: Callable, size: Callable, order: Sequence[str] | None):
    """The candidate with the lowest choosing error; among those within PARSIMONY of it, the one
    with the fewest parameters (``size``), then the earliest in the library (``order``) or, with
    ``order`` None, the lowest choosing error among those of that size (a place in the library is
    no reason to prefer a worse fit: the actuator keeps the order because its ties are models
    the record cannot tell apart, settled afterwards from a fixed first choice)."""
    best = min(named, key=error)
    close = [c for c in named if error(c) <= PARSIMONY * error(best)]
    if order is None:
        fewest = min(size(c) for c in close)
        return min((c for c in close if size(c) == fewest), key=error)
    return min(close, key=lambda c: (size(c), list(order).index(c.cause)))


def ratio(before: float, after: float) -> float:
    """The gain before / after of two RMS errors: infinite when a model predicts a block exactly
    (noise-free data), 1 when neither leaves an error."""
    if after > 0.0:
        return before / after
    return math.inf if before > 0.0 else 1.0


def grow(current, names, may_join: Callable, fit_with: Callable, error: Callable, margin: float, most: int):
    """The best combination, grown greedily from the single cause ``current``: each round fits
    every effect of ``names`` that ``may_join`` on top (``fit_with(current, name)``) and adds the
    one with the lowest choosing ``error``, while it clears ``margin`` over the combination so
    far, up to ``most`` effects."""
    while len(current.effects) < most:
        trials = [fit_with(current, name) for name in names if may_join(current, name)]
        if not trials:
            break
        trial = min(trials, key=error)
        if ratio(error(current), error(trial)) < margin:
            break
        current = trial
    return current


def unnamed(structure: residual_mod.Structure, floor: residual_mod.Floor) -> str:
    """The answer when no candidate clears the margin: none when the held-out error reaches the
    sensor floor with no structure left, unexplained otherwise."""
    return NONE if reaches_floor(structure, floor) else UNEXPLAINED


def reaches_floor(structure: residual_mod.Structure, floor: residual_mod.Floor) -> bool:
    """The held-out error is within FLOOR_FACTOR sensor floors, with no line or trend left."""
    return bool(structure.rms_test_mm <= residual_mod.FLOOR_FACTOR * floor.sensor_floor_mm and not structure.structured)


def scoring_text(n_train: int, n_choose: int, n: int) -> str:
    return (f"fit on samples [0, {n_train}), choose on [{n_train}, {n_choose}), score on [{n_choose}, {n}): "
            "the gain is measured on data used neither to fit nor to choose")


class Outcome:
    """The parts of a diagnosis that do not depend on what was diagnosed; the dataclass using it
    holds ``candidates``, ``cause``, ``floor`` and ``structure``."""

    @property
    def single(self):
        """The named cause's candidate (None for none, unexplained and too_few_samples)."""
        return next((c for c in self.candidates if c.cause == self.cause), None)

    @property
    def explained(self) -> bool:
        """The extended model reaches the sensor floor."""
        return reaches_floor(self.structure, self.floor)
