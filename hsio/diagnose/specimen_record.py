"""A measured specimen record (displacement and force of a physical substructure) and its readers.

* CSV: a header row ``time_s,displacement_mm,force_kN`` (any order), uniform time step.
* DAQ text export: the displacement and force channels, scaled; a record paused and resumed
  (``DAQ Pause`` / ``DAQ Resume`` events) is cut into segments, each tested on its own (the
  specimen's settings may change while the DAQ is paused, e.g. a damper's coil current).
* hsio's own recordings (``run.sqlite``): the measured displacement and force of one actuator.

The displacement is taken relative to its median (a static offset of the transducer is no
deformation of the specimen).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hsio.diagnose.record import Sampled, checked_channels
from hsio.errors import RecordError

CSV_COLUMNS = ("time_s", "displacement_mm", "force_kN")


@dataclass(frozen=True)
class SpecimenRecord(Sampled):
    source: str
    dt: float
    displacement_mm: np.ndarray
    force_kN: np.ndarray

    def __post_init__(self):
        checked_channels(self, ("displacement_mm", "force_kN"))

    @property
    def n(self) -> int:
        return self.displacement_mm.size


def _centred(source: str, dt: float, u: np.ndarray, f: np.ndarray) -> SpecimenRecord:
    return SpecimenRecord(source, dt, u - np.median(u), f)


def read_csv(path: str | Path) -> SpecimenRecord:
    from hsio.diagnose.readers import read_csv_table

    def header_error(fields):
        return None if sorted(fields) == sorted(CSV_COLUMNS) else ",".join(CSV_COLUMNS)

    path, col, dt = read_csv_table(path, header_error)
    return _centred(str(path), dt, col["displacement_mm"], col["force_kN"])


def write_csv(record: SpecimenRecord, path: str | Path) -> Path:
    path = Path(path)
    np.savetxt(path, np.column_stack([record.time_s, record.displacement_mm, record.force_kN]), delimiter=",",
               header=",".join(CSV_COLUMNS), comments="", fmt="%.9g")
    return path


def daq_segments(path: Path) -> list[int]:
    """Row indices (0-based, data rows) where the DAQ resumed after a pause."""
    from hsio.diagnose.readers import daq_header_size, read_bytes

    text = read_bytes(path).decode("latin-1")
    lines = text.splitlines()
    header_size = daq_header_size(lines, path)
    starts, row = [], 0
    for line in lines[header_size:]:
        if not line.strip():
            continue
        if "resume" in line.lower() and row > 0:
            starts.append(row)
        row += 1
    return starts


def read_daq(path: str | Path, displacement: str, force: str, displacement_scale: float,
             force_scale: float) -> list[SpecimenRecord]:
    """The segments of a DAQ export (one when it was never paused)."""
    from hsio.diagnose.readers import DaqChannels
    from hsio.diagnose.readers import read_daq as read_channels

    path = Path(path)
    rec = read_channels(path, DaqChannels(displacement, displacement, force, displacement_scale, displacement_scale, force_scale))
    bounds = [0, *daq_segments(path), rec.n]
    records = []
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        if b - a < 100:
            continue
        name = str(path) if len(bounds) == 2 else f"{path}#segment{i + 1}"
        records.append(_centred(name, rec.dt, rec.measured_mm[a:b], rec.force_kN[a:b]))
    if not records:
        raise RecordError(f"{path}: no segment of at least 100 samples")
    return records


def read_specimen(path: str | Path, fmt: str | None = None, displacement: str = "CHANNEL0", force: str = "CHANNEL1",
                  displacement_scale: float = 10.0, force_scale: float = 9.80665,
                  actuator: str | None = None) -> list[SpecimenRecord]:
    """The record(s) in ``path``: csv, daq (one per segment) or an hsio run."""
    from hsio.diagnose.readers import detect_format, read_run

    fmt = fmt or detect_format(path)
    if actuator is not None and fmt != "run":
        raise RecordError(f"{path}: --actuator chooses an actuator of an hsio recording (run.sqlite); "
                          f"this is a {fmt} record of one specimen")
    if fmt == "csv":
        return [read_csv(path)]
    if fmt == "daq":
        return read_daq(path, displacement, force, displacement_scale, force_scale)
    if fmt == "run":
        rec = read_run(path, actuator)
        return [_centred(rec.source, rec.dt, rec.measured_mm, rec.force_kN)]
    raise RecordError(f"{path}: unknown format {fmt!r}; known: csv, daq, run")
