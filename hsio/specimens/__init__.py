"""Specimen models: the restoring force of a physical element as a function of its deformation.

The same models serve the emulated controller (the "physical" specimen behind an emulated
actuator), the purely numerical simulation (NS) and the numerical elements of a structure file.
Each kind is a class with a ``kind`` name; :func:`make_specimen` builds one from a table such as
``{"kind": "linear", "k": 0.613}`` (docs/structures.md lists every kind and its parameters).
"""

from __future__ import annotations

import math
import numbers

from hsio.errors import ConfigError
from hsio.specimens.base import Specimen
from hsio.specimens.degrading import PeakOriented
from hsio.specimens.elastic import BilinearGap, Linear, MenegottoPinto
from hsio.specimens.diagnosed import Diagnosed
from hsio.specimens.infill import CrackingInfill
from hsio.specimens.wood import PinchedWood

SPECIMEN_KINDS: dict[str, type[Specimen]] = {
    cls.kind: cls for cls in (Linear, BilinearGap, MenegottoPinto, PinchedWood, PeakOriented, Diagnosed, CrackingInfill)
}


def make_specimen(spec: dict) -> Specimen:
    """Build a specimen from a table such as ``{"kind": "linear", "k": 0.613}``."""
    if not isinstance(spec, dict) or "kind" not in spec:
        raise ConfigError(f"specimen must be a table with a 'kind' key, got {spec!r}")
    kind = spec["kind"]
    cls = SPECIMEN_KINDS.get(kind)
    if cls is None:
        raise ConfigError(f"unknown specimen kind {kind!r}; known: {', '.join(sorted(SPECIMEN_KINDS))}")
    params = {k: v for k, v in spec.items() if k != "kind"}
    for name, value in params.items():
        if isinstance(value, str) or (isinstance(value, numbers.Real) and not isinstance(value, bool)
                                      and not math.isfinite(value)):
            raise ConfigError(f"specimen {kind!r}: {name} must be a finite number, got {value!r}")
    try:
        return cls(**params)
    except TypeError as exc:
        raise ConfigError(f"specimen {kind!r}: {exc}") from None


def specimen_spec(specimen: Specimen) -> dict:
    """The table that :func:`make_specimen` turns back into ``specimen``."""
    params = {k: v for k, v in vars(specimen).items() if not k.startswith("_")}
    return {"kind": specimen.kind, **params}


__all__ = ["Specimen", "SPECIMEN_KINDS", "make_specimen", "specimen_spec",
           "Linear", "BilinearGap", "MenegottoPinto", "PinchedWood", "PeakOriented", "Diagnosed", "CrackingInfill"]
