"""The input files of a run, fingerprinted for `hsio resume` (docs/safety.md section 8).

A resume builds the structure, the ground motion and the hardware link again from the files
that the recorded configuration names. A file edited between the interrupted run and the resume
would change the test in the middle of its record (a structure ten times stiffer from the
resumed step on), so a run records, when it begins, the SHA-256 of each such file (meta
``inputs``) and of the ground motion it runs (meta ``ground_motion_sha256``); the resume
computes them again and refuses where one differs, before anything opens.

The configuration itself and the emulated controller's settings (with an actuator model's) are
held in the record, and the resume reads them from there: they are not among these files.
"""

from __future__ import annotations

import errno
import hashlib
from pathlib import Path

import numpy as np

from hsio import hardware
from hsio.config import RunConfig
from hsio.errors import ConfigError
from hsio.structure_file import structure_file

CHUNK_BYTES = 1 << 20


def input_files(config: RunConfig) -> list[tuple[str, Path]]:
    """``(what, path)`` of each file that a run of ``config``, and a resume of it, reads: the
    structure file (or the shipped structure's), the record file, and the files of the hardware
    backend (:func:`hsio.hardware.input_files`: a register map, an EDS, the DAQ module's map)."""
    files = []
    structure = config["structure"]
    path = structure_file(structure["file"] or structure["name"])
    if path is not None:
        files.append(("[structure] file" if structure["file"] else "[structure] name (shipped)", path))
    if config["record"]["file"]:
        files.append(("[record] file", Path(config["record"]["file"])))
    return files + hardware.input_files(config["hardware"]["url"], config["driver"])


def sha256_of(path: Path) -> str:
    """The SHA-256 of the regular file ``path``, read in chunks (a device or a FIFO is refused,
    never read for ever); OSError when it cannot be read."""
    if not path.is_file():
        if path.exists():
            raise OSError(errno.EINVAL, "not a regular file", str(path))
        raise FileNotFoundError(errno.ENOENT, "no such file", str(path))
    digest = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(CHUNK_BYTES):
            digest.update(chunk)
    return digest.hexdigest()


def fingerprints(config: RunConfig) -> list[dict]:
    """``{"what", "path", "sha256"}`` of each of :func:`input_files`, as a run records them when it
    begins; a file that cannot be read is a ConfigError naming it."""
    out = []
    for what, path in input_files(config):
        try:
            out.append({"what": what, "path": str(path.resolve()), "sha256": sha256_of(path)})
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    return out


def ground_fingerprint(ground) -> str:
    """The SHA-256 of a ground motion's time step and samples (float64, little-endian)."""
    digest = hashlib.sha256(repr(float(ground.dt)).encode())
    digest.update(np.ascontiguousarray(ground.accel_g, dtype="<f8").tobytes())
    return digest.hexdigest()


def compare_inputs(recorded: list[dict], config: RunConfig) -> tuple[list[str], list[str]]:
    """The files of :func:`input_files` against their fingerprints in ``recorded`` (a run's meta
    ``inputs``): one line per file that changed or cannot be read now, and one per file that has
    no fingerprint (a file the hsio that recorded the run did not fingerprint)."""
    now = dict(input_files(config))
    changed = []
    for entry in recorded:
        what = entry["what"]
        path = now.pop(what, None)
        if path is None:
            continue  # a file that this resume does not read
        try:
            digest = sha256_of(path)
        except OSError as exc:
            reason = "missing" if exc.errno == errno.ENOENT else f"cannot be read ({exc.strerror or exc})"
            changed.append(f"{path} ({what}): {reason}")
            continue
        if digest != entry["sha256"]:
            changed.append(f"{path} ({what}): changed (sha256 {entry['sha256'][:12]}... when the run began, "
                           f"{digest[:12]}... now)")
    unchecked = [f"{path} ({what})" for what, path in now.items()]
    return changed, unchecked
