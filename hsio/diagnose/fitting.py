"""Least-squares fit of the model (baseline lag plus chosen effects) to the training part of a record.

The prediction is a free-run simulation of the whole record from the command alone (an
output-error fit): the training part fixes the parameters, the held-out part is predicted
without any feedback from the measurement. The offset between transducers is solved in
closed form (the mean residual on the training part) at every evaluation.

The record is cut in three blocks in time: the first 60 % fits the parameters, the next 20 %
chooses between models, the last 20 % scores the chosen one (its gain is measured on data used
neither to fit nor to choose).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from hsio.diagnose.effects import BASELINE_PARAMS, EFFECTS, Context, Param
from hsio.diagnose.loop_rate import predict
from hsio.diagnose.model import NEUTRAL
from hsio.diagnose.record import ActuatorRecord

TRAIN_FRACTION = 0.6
CHOOSE_FRACTION = 0.2


@dataclass
class Fit:
    """A fitted model: which effects, the parameters, and how well it predicts."""

    effects: tuple[str, ...]
    params: dict
    rms_train_mm: float
    rms_choose_mm: float  # the block that chooses between models
    rms_test_mm: float  # the block that scores the chosen one
    prediction: np.ndarray  # the whole record, mm
    nfev: int = 0

    @property
    def name(self) -> str:
        return "lag" + "".join(f" + {e}" for e in self.effects)

    def summary(self) -> dict:
        return {"model": self.name, "effects": list(self.effects), "params": dict(self.params),
                "rms_train_mm": self.rms_train_mm, "rms_choose_mm": self.rms_choose_mm, "rms_test_mm": self.rms_test_mm}


def split_index(record: ActuatorRecord, train_fraction: float = TRAIN_FRACTION) -> int:
    """Samples [0, n_train) fit the model."""
    return int(round(train_fraction * record.n))


def blocks(n: int, train_fraction: float = TRAIN_FRACTION, choose_fraction: float = CHOOSE_FRACTION) -> tuple[int, int]:
    """(n_train, n_choose): [0, n_train) fits, [n_train, n_choose) chooses, [n_choose, n) scores."""
    n_train = int(round(train_fraction * n))
    return n_train, min(int(round((train_fraction + choose_fraction) * n)), n - 1)


def param_specs(effects: tuple[str, ...], ctx: Context) -> list[Param]:
    specs = [BASELINE_PARAMS(ctx)]
    for name in effects:
        specs.extend(EFFECTS[name].params(ctx))
    return specs


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def evaluate(record: ActuatorRecord, effects: tuple[str, ...], params: dict, n_train: int, nfev: int = 0,
             n_choose: int | None = None) -> Fit:
    """Simulate the whole record with ``params`` (offset fitted on the training part) and score it."""
    params = dict(params)
    params["offset_mm"] = 0.0
    pred = predict(record, params)
    offset = float(np.mean(record.measured_mm[:n_train] - pred[:n_train]))
    params["offset_mm"] = offset
    pred = pred + offset
    r = record.measured_mm - pred
    n_choose = blocks(record.n, n_train / record.n)[1] if n_choose is None else n_choose
    return Fit(tuple(effects), params, rms(r[:n_train]), rms(r[n_train:n_choose]), rms(r[n_choose:]), pred, nfev)


def _neutral(name: str, ctx: Context) -> float:
    value = NEUTRAL.get(name)
    if name == "lag_retract_s" or value is None:
        return ctx.lag_s
    if name == "velocity_limit_mm_s":
        return 5.0 * max(ctx.v_cmd_peak, 1e-3)
    return float(value)


def fit(record: ActuatorRecord, effects: tuple[str, ...], ctx: Context, n_train: int, starts: list[dict],
        max_nfev: int = 60, n_choose: int | None = None) -> Fit:
    """Fit lag_s and the effects' parameters on samples [0, n_train) from each start; keep the best."""
    specs = param_specs(effects, ctx)
    lower = np.array([s.lower for s in specs])
    upper = np.array([s.upper for s in specs])
    scale = np.array([s.scale for s in specs])
    names = [s.name for s in specs]
    m = record.measured_mm[:n_train]

    def to_params(z):
        return dict(zip(names, (z * scale).tolist()))

    def residual(z):
        r = m - predict(record, to_params(z), n_train)
        return r - r.mean()

    best, nfev = None, 0
    for start in starts:
        # A parameter a start leaves out begins at its neutral value (the effect absent).
        x0 = np.array([start.get(name, ctx.lag_s if name == "lag_s" else _neutral(name, ctx)) for name in names], dtype=float)
        x0 = np.clip(x0, lower + 1e-9 * (upper - lower), upper - 1e-9 * (upper - lower))
        sol = optimize.least_squares(residual, x0 / scale, bounds=(lower / scale, upper / scale), method="trf",
                                     x_scale=1.0, max_nfev=max_nfev, xtol=1e-6, ftol=1e-8)
        nfev += sol.nfev
        if best is None or sol.cost < best.cost:
            best = sol
    return evaluate(record, effects, to_params(best.x), n_train, nfev, n_choose)
