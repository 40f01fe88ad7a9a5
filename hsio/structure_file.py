"""Structure files: a structure as data (TOML), checked key by key.

The format is documented table by table in docs/structures.md. Every error is a
:class:`~hsio.errors.ConfigError` that names the file, the table (with its array index) and the
key, e.g. ``three_storey.toml: experimental[0].dof: unknown DOF 'floor4'``.

:func:`load_structure` takes a path or the name of a shipped structure (the files in
``hsio/library/``: the paper's ``validation``, ``structure_I``, ``structure_II`` and the
``three_storey`` building).
"""

from __future__ import annotations

import inspect
import math
import numbers
import os
import tomllib
import unicodedata
from importlib import resources
from pathlib import Path

import numpy as np
import scipy.linalg

from hsio.errors import ConfigError
from hsio.files import read_bounded
from hsio.specimens import SPECIMEN_KINDS, make_specimen
from hsio.structures import (DAMPING_KINDS, INSTRUMENT_KINDS, Damping, ExperimentalElement, Instrument, NumericalElement,
                             OuterLoop, Spring, StaticLoad, Structure, dt_out_of_bounds, ramp_out_of_bounds)

MAX_DOF = 1000
MAX_ELEMENTS = 10000
MAX_NAME = 100  # characters of a name (a DOF, element, actuator, instrument, ...)
MAX_FILE_BYTES = 4_000_000
FREQUENCY_BOUNDS_HZ = (1e-3, 1e7)
GROUND = "ground"
PAPER = ("validation", "structure_I", "structure_II")  # E&M 2007, Tables I-III

TABLES = {
    "structure": {"name", "description", "dt"},
    "dof": {"name", "mass", "iota"},
    "mass": {"matrix"},
    "damping": {"kind", "zeta", "modes"},
    "spring": {"name", "dof", "to", "k"},
    "numerical": {"name", "dof", "to", "model"},
    "experimental": {"name", "dof", "ref", "dofs", "actuator", "actuators", "K_EI", "model", "setup",
                     "displacement_from", "outer_loop"},
    "static": {"name", "actuator", "force_kN", "ramp_s", "model", "K_EI"},
    "instrument": {"name", "kind", "element", "scale", "noise", "resolution"},
}
ARRAYS = ("dof", "spring", "numerical", "experimental", "static", "instrument")


def shipped_names() -> list[str]:
    """Names of the structures shipped with hsio (``hsio/library/*.toml``)."""
    library = resources.files("hsio") / "library"
    names = sorted(p.name[:-5] for p in library.iterdir() if p.name.endswith(".toml"))
    paper = [n for n in PAPER if n in names]
    return paper + [n for n in names if n not in PAPER]


def load_shipped(name: str) -> Structure:
    """A shipped structure by name."""
    names = shipped_names()
    if name not in names:
        raise ConfigError(f"unknown structure {name!r}; known: {', '.join(names)}")
    resource = resources.files("hsio") / "library" / f"{name}.toml"
    return parse_structure(resource.read_bytes(), f"{name}.toml (shipped)")


def is_shipped_name(path_or_name: str | Path) -> bool:
    """Whether :func:`load_structure` takes ``path_or_name`` as a shipped structure's name (a
    string with no suffix and no folder) rather than a path."""
    text = str(path_or_name)
    return (isinstance(path_or_name, str) and "/" not in text and "\\" not in text
            and not text.lower().endswith(".toml"))


def structure_file(path_or_name: str | Path, relative_to: str | Path | None = None) -> Path | None:
    """The file that :func:`load_structure` reads for ``path_or_name``: the path, or the shipped
    structure's file in ``hsio/library/`` (None for a name that no shipped structure has)."""
    if is_shipped_name(path_or_name):
        if str(path_or_name) not in shipped_names():
            return None
        return Path(str(resources.files("hsio") / "library" / f"{path_or_name}.toml"))
    path = Path(path_or_name).expanduser()
    return Path(relative_to) / path if relative_to is not None and not path.is_absolute() else path


def load_structure(path_or_name: str | Path, relative_to: str | Path | None = None) -> Structure:
    """A structure from a file path, or a shipped structure's name (no suffix, no folder).

    A relative path is taken relative to the folder ``relative_to`` (e.g. that of the run
    configuration that names the file), else to the working directory.
    """
    if not isinstance(path_or_name, (str, os.PathLike)) or isinstance(os.fspath(path_or_name), bytes):
        raise ConfigError(f"load_structure: a shipped structure's name or a structure file's path (str or "
                          f"pathlib.Path), got {type(path_or_name).__name__} {path_or_name!r:.80}")
    if is_shipped_name(path_or_name):
        return load_shipped(str(path_or_name))
    path = structure_file(path_or_name, relative_to)
    try:
        data = read_bounded(path, MAX_FILE_BYTES, lambda reason: ConfigError(
            f"{path}: {reason} (a structure file is TOML text of at most {MAX_FILE_BYTES} bytes)"))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the structure file ({exc.strerror or exc})") from None
    return parse_structure(data, str(path), default_name=path.stem)


def parse_structure(data: bytes | str, filename: str, default_name: str = "structure") -> Structure:
    """Check and build a structure from the text of a structure file named ``filename``."""
    if isinstance(data, bytes):
        try:
            data = data.decode("utf-8-sig")  # a byte-order mark (Windows editors) is dropped
        except UnicodeDecodeError as exc:
            raise ConfigError(f"{filename}: not UTF-8 text (byte {exc.start} is 0x{data[exc.start]:02x})") from None
    try:
        doc = tomllib.loads(data)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{filename}: not valid TOML: {exc}") from None
    return structure_from_tables(doc, filename, default_name)


def structure_from_tables(doc: dict, filename: str, default_name: str = "structure") -> Structure:
    """Check and build a structure from the tables of a structure file (as tomllib reads them)."""
    return _Reader(filename, default_name).build(doc)


def is_plain_name(name: str) -> bool:
    """A name that can be one folder of a path as it is: no separator, not '.' or '..' (nor any
    leading '.'), no control character."""
    return (bool(name.strip()) and not name.startswith(".") and not any(c in name for c in "/\\")
            and all(ord(c) >= 32 for c in name))


class _Reader:
    def __init__(self, filename: str, default_name: str):
        self.file = filename
        self.default_name = default_name

    def error(self, where: str, message: str) -> ConfigError:
        return ConfigError(f"{self.file}: {where}: {message}")

    # -- values ---------------------------------------------------------------------------

    def number(self, where: str, value, *, positive: bool = False, non_negative: bool = False) -> float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise self.error(where, f"must be a number, got {value!r}")
        value = float(value)  # numpy scalars (np.float32, np.int64) as Python floats
        if not math.isfinite(value):
            raise self.error(where, f"must be finite, got {value!r}")
        if positive and not value > 0:
            raise self.error(where, f"must be positive, got {value!r}")
        if non_negative and value < 0:
            raise self.error(where, f"must not be negative, got {value!r}")
        return float(value)

    def string(self, where: str, value) -> str:
        """A name: not empty, at most MAX_NAME characters, no control character (a line break, a
        tab, ...): names are printed in tables, plotted and recorded as columns."""
        if not isinstance(value, str) or not value.strip():
            raise self.error(where, f"must be a non-empty string, got {value!r}")
        if len(value) > MAX_NAME:
            raise self.error(where, f"a name of {len(value)} characters; at most {MAX_NAME}")
        control = next((c for c in value if unicodedata.category(c) in ("Cc", "Zl", "Zp")), None)
        if control is not None:
            raise self.error(where, f"{value!r} holds the control character {control!r}; names are printed, "
                             "plotted and recorded: give one without")
        return value

    def table(self, where: str, value, keys: set[str]) -> dict:
        if not isinstance(value, dict):
            raise self.error(where, f"must be a table, got {value!r}")
        unknown = sorted(set(value) - keys)
        if unknown:
            raise self.error(f"{where}.{unknown[0]}", f"unknown key; known: {', '.join(sorted(keys))}")
        return value

    def required(self, where: str, table: dict, key: str):
        if key not in table:
            raise self.error(f"{where}.{key}", "missing")
        return table[key]

    # -- the document -----------------------------------------------------------------------

    def build(self, doc: dict) -> Structure:
        unknown = sorted(set(doc) - set(TABLES))
        if unknown:
            raise self.error(unknown[0], f"unknown table; known: {', '.join(TABLES)}")
        for name in ARRAYS:
            if name in doc and not isinstance(doc[name], list):
                raise self.error(name, f"must be an array of tables ([[{name}]])")
            if len(doc.get(name, [])) > (MAX_DOF if name == "dof" else MAX_ELEMENTS):
                cap = MAX_DOF if name == "dof" else MAX_ELEMENTS
                raise self.error(name, f"{len(doc[name])} entries; at most {cap}")
        if "structure" not in doc:
            raise self.error("structure", "missing: a structure file starts with a [structure] table (dt at least)")
        head = self.table("structure", doc["structure"], TABLES["structure"])
        name = self.string("structure.name", head.get("name", self.default_name))
        description = head.get("description", "")
        if not isinstance(description, str):
            raise self.error("structure.description", f"must be a string, got {description!r}")
        dt = self.number("structure.dt", self.required("structure", head, "dt"), positive=True)
        if dt_out_of_bounds(dt):
            raise self.error("structure.dt", dt_out_of_bounds(dt))

        dofs = doc.get("dof", [])
        if not dofs:
            raise self.error("dof", "missing: declare each degree of freedom in a [[dof]] table")
        self.dof_index: dict[str, int] = {}
        dof_names, masses, iota = [], [], []
        has_matrix = "mass" in doc
        for k, entry in enumerate(dofs):
            where = f"dof[{k}]"
            entry = self.table(where, entry, TABLES["dof"])
            dof_name = self.string(f"{where}.name", self.required(where, entry, "name"))
            if dof_name == GROUND:
                raise self.error(f"{where}.name", f"{GROUND!r} is reserved for the ground")
            if dof_name in self.dof_index:
                raise self.error(f"{where}.name", f"DOF {dof_name!r} is declared twice")
            self.dof_index[dof_name] = k
            dof_names.append(dof_name)
            if has_matrix:
                if "mass" in entry:
                    raise self.error(f"{where}.mass", "give the masses either per DOF or as [mass] matrix, not both")
            else:
                masses.append(self.number(f"{where}.mass", self.required(where, entry, "mass"), positive=True))
            iota.append(self.number(f"{where}.iota", entry.get("iota", 1.0)))
        n = len(dof_names)

        matrix = None
        if has_matrix:
            M = self.mass_matrix(self.table("mass", doc["mass"], TABLES["mass"]), n)
            matrix = tuple(tuple(float(v) for v in row) for row in M)
            masses = [float(v) for v in np.diag(M)]

        damping = self.damping(self.table("damping", doc.get("damping", {}), TABLES["damping"]), n)
        springs = tuple(self.spring(k, e) for k, e in enumerate(doc.get("spring", [])))
        numerical = tuple(self.numerical(k, e) for k, e in enumerate(doc.get("numerical", [])))
        experimental = tuple(self.experimental(k, e) for k, e in enumerate(doc.get("experimental", [])))
        static = tuple(self.static(k, e) for k, e in enumerate(doc.get("static", [])))
        instruments = tuple(self.instrument(k, e) for k, e in enumerate(doc.get("instrument", [])))
        named = [(f"spring[{k}]", s.name) for k, s in enumerate(springs) if s.name]
        named += [(f"numerical[{k}]", e.name) for k, e in enumerate(numerical)]
        named += [(f"experimental[{k}]", e.name) for k, e in enumerate(experimental)]
        named += [(f"static[{k}]", e.name) for k, e in enumerate(static)]
        first: dict[str, str] = {}
        for where, element_name in named:
            if element_name in first:
                raise self.error(f"{where}.name", f"{element_name!r} already names {first[element_name]}")
            first[element_name] = where
        for key in ("dof", "actuator"):
            seen: dict = {}
            for k, e in enumerate(experimental):
                for value in (e.basic_dofs if key == "dof" else e.actuator_names):
                    if value in seen:
                        plural = "s" if (e.dofs if key == "dof" else e.actuators) else ""
                        raise self.error(f"experimental[{k}].{key}{plural}", f"already used by experimental[{seen[value]}]")
                    seen[value] = k
        used = {a: f"experimental[{k}]" for k, e in enumerate(experimental) for a in e.actuator_names}
        for k, e in enumerate(static):
            if e.actuator in used:
                raise self.error(f"static[{k}].actuator", f"actuator {e.actuator!r} already used by {used[e.actuator]}")
            used[e.actuator] = f"static[{k}]"

        if not any(iota):
            raise self.error("dof", "every DOF has iota = 0: the ground motion would load none of them")
        structure = Structure(name=name, dof_names=tuple(dof_names), masses=tuple(masses), experimental=experimental,
                              springs=springs, numerical=numerical, damping=damping, dt=dt, description=description,
                              mass_matrix=matrix, influence=None if all(v == 1.0 for v in iota) else tuple(iota),
                              source=self.file, static=static, instruments=instruments)
        return structure  # Structure checks its instruments, stability and damping itself (check_instruments, ...)

    def mass_matrix(self, table: dict, n: int) -> np.ndarray:
        rows = self.required("mass", table, "matrix")
        if not isinstance(rows, list) or len(rows) != n or any(not isinstance(r, list) or len(r) != n for r in rows):
            raise self.error("mass.matrix", f"must be {n} rows of {n} numbers (one per [[dof]])")
        M = np.array([[self.number(f"mass.matrix[{i}][{j}]", v) for j, v in enumerate(row)] for i, row in enumerate(rows)])
        scale = np.max(np.abs(M))
        if not np.allclose(M, M.T, rtol=0.0, atol=1e-12 * scale):
            i, j = np.unravel_index(np.argmax(np.abs(M - M.T)), M.shape)
            raise self.error("mass.matrix", f"not symmetric: [{i}][{j}] = {float(M[i, j])!r} but [{j}][{i}] = "
                             f"{float(M[j, i])!r}")
        try:
            np.linalg.cholesky(M)
        except np.linalg.LinAlgError:
            raise self.error("mass.matrix", "not positive definite") from None
        return M

    def damping(self, table: dict, n: int) -> Damping:
        kind = table.get("kind", "rayleigh" if n > 1 else "mass")
        if kind not in DAMPING_KINDS:
            raise self.error("damping.kind", f"must be one of {', '.join(DAMPING_KINDS)}, got {kind!r}")
        zeta = table.get("zeta", 0.05)
        if isinstance(zeta, list):
            ratios = tuple(self.number(f"damping.zeta[{k}]", z, non_negative=True) for k, z in enumerate(zeta))
        else:
            ratios = (self.number("damping.zeta", zeta, non_negative=True),)
        over = [k for k, z in enumerate(ratios) if z >= 1.0]
        if over:
            where = f"damping.zeta[{over[0]}]" if isinstance(zeta, list) else "damping.zeta"
            raise self.error(where, f"a damping ratio is a fraction of critical, below 1; got {ratios[over[0]]!r}")
        if kind == "modal":
            if "modes" in table:
                raise self.error("damping.modes", "modal damping applies to every mode; give zeta per mode instead")
            if len(ratios) not in (1, n):
                raise self.error("damping.zeta", f"{len(ratios)} ratios for {n} modes: give one, or one per mode")
            return Damping(ratios[0] if len(ratios) == 1 else ratios, "modal")  # [z]: z for every mode
        count = 2 if kind == "rayleigh" else 1
        modes = table.get("modes", [1, 2] if kind == "rayleigh" else [1])
        if not isinstance(modes, list) or len(modes) != count:
            raise self.error("damping.modes", f"{kind} damping takes {count} mode number(s), got {modes!r}")
        for k, m in enumerate(modes):
            if isinstance(m, bool) or not isinstance(m, int):
                raise self.error(f"damping.modes[{k}]", f"must be a mode number (1 = lowest), got {m!r}")
            if not 1 <= m <= n:
                raise self.error(f"damping.modes[{k}]", f"mode {m} does not exist: the structure has {n} mode(s)")
        if count == 2 and modes[0] == modes[1]:
            raise self.error("damping.modes", f"rayleigh damping needs two different modes, got {modes}")
        if len(ratios) not in (1, count):
            raise self.error("damping.zeta", f"{len(ratios)} ratios for {count} mode(s)")
        value = ratios if len(ratios) > 1 else ratios[0]  # [z]: z on both modes
        return Damping(value, kind, tuple(modes))

    def dof(self, where: str, value) -> int:
        name = self.string(where, value)
        if name not in self.dof_index:
            raise self.error(where, f"unknown DOF {name!r}; DOFs: {', '.join(self.dof_index)}")
        return self.dof_index[name]

    def ends(self, where: str, entry: dict) -> tuple[int, int | None]:
        i = self.dof(f"{where}.dof", self.required(where, entry, "dof"))
        to = entry.get("to", GROUND)
        if to == GROUND:
            return i, None
        j = self.dof(f"{where}.to", to)
        if j == i:
            raise self.error(f"{where}.to", f"the element joins DOF {to!r} to itself")
        return i, j

    def model(self, where: str, value) -> dict:
        if not isinstance(value, dict):
            raise self.error(where, f"must be a table such as {{ kind = \"linear\", k = 1.0 }}, got {value!r}")
        kind = value.get("kind")
        if not isinstance(kind, str) or kind not in SPECIMEN_KINDS:
            raise self.error(f"{where}.kind", f"unknown specimen model {kind!r}; known: {', '.join(sorted(SPECIMEN_KINDS))}")
        # A model's parameters are its constructor's public arguments; a leading "_" marks the
        # model's own state (e.g. the committed state of `diagnosed`), never a file's key.
        params = {k: p for k, p in inspect.signature(SPECIMEN_KINDS[kind]).parameters.items() if not k.startswith("_")}
        spec = {"kind": kind}
        for key, v in value.items():
            if key == "kind":
                continue
            if key not in params:
                raise self.error(f"{where}.{key}", f"unknown parameter of {kind!r}; known: {', '.join(params)}")
            spec[key] = self.number(f"{where}.{key}", v)
        required = [k for k, p in params.items() if p.default is inspect.Parameter.empty]
        for key in required:
            if key not in spec:
                raise self.error(f"{where}.{key}", f"missing: {kind!r} needs {', '.join(required)} "
                                 f"(optional: {', '.join(k for k in params if k not in required) or 'none'})")
        try:
            model = make_specimen(spec)
        except (ConfigError, ValueError) as exc:
            raise self.error(where, str(exc)) from None
        if not (math.isfinite(model.initial_stiffness) and model.initial_stiffness > 0):
            raise self.error(where, f"initial stiffness must be positive, got {model.initial_stiffness!r}")
        return spec

    def spring(self, k: int, entry) -> Spring:
        where = f"spring[{k}]"
        entry = self.table(where, entry, TABLES["spring"])
        i, j = self.ends(where, entry)
        stiffness = self.number(f"{where}.k", self.required(where, entry, "k"), positive=True)
        name = self.string(f"{where}.name", entry["name"]) if "name" in entry else ""
        return Spring(i, j, stiffness, name)

    def numerical(self, k: int, entry) -> NumericalElement:
        where = f"numerical[{k}]"
        entry = self.table(where, entry, TABLES["numerical"])
        i, j = self.ends(where, entry)
        name = self.string(f"{where}.name", entry.get("name", f"numerical{k}"))
        return NumericalElement(name, i, self.model(f"{where}.model", self.required(where, entry, "model")), j)

    def experimental(self, k: int, entry) -> ExperimentalElement:
        where = f"experimental[{k}]"
        entry = self.table(where, entry, TABLES["experimental"])
        if "dofs" in entry or "actuators" in entry or "setup" in entry:
            if "ref" in entry:
                given = next(key for key in ("dofs", "actuators", "setup") if key in entry)
                raise self.error(f"{where}.ref", f"an element between two DOFs has one DOF, one actuator and no setup; "
                                 f"this one gives {given} (an element loaded through a setup acts on its basic DOFs, "
                                 "docs/setups.md)")
            return self.experimental_setup(k, where, entry)
        i = self.dof(f"{where}.dof", self.required(where, entry, "dof"))
        ref = None
        if entry.get("ref", GROUND) != GROUND:
            ref = self.dof(f"{where}.ref", entry["ref"])
            if ref == i:
                raise self.error(f"{where}.ref", f"the element joins DOF {entry['ref']!r} to itself")
        name = self.string(f"{where}.name", entry.get("name", list(self.dof_index)[i]))
        actuator = self.string(f"{where}.actuator", entry.get("actuator", name))
        spec = self.model(f"{where}.model", self.required(where, entry, "model"))
        K_EI = self.number(f"{where}.K_EI", entry["K_EI"], positive=True) if "K_EI" in entry else None
        source, outer = self.external_displacement(where, entry)
        return ExperimentalElement(name, i, spec, actuator, K_EI, displacement_from=source, outer_loop=outer, ref=ref)

    def external_displacement(self, where: str, entry: dict) -> tuple[str, OuterLoop | None]:
        """An element's ``displacement_from`` and ``outer_loop`` (docs/setups.md)."""
        source = self.string(f"{where}.displacement_from", entry["displacement_from"]) if "displacement_from" in entry else ""
        outer = None
        if "outer_loop" in entry:
            if not source:
                raise self.error(f"{where}.outer_loop", "needs displacement_from (the instrument it closes on)")
            table = self.table(f"{where}.outer_loop", entry["outer_loop"], {"tolerance_mm", "max_iterations"})
            tol = self.number(f"{where}.outer_loop.tolerance_mm", table.get("tolerance_mm", 0.02), positive=True)
            n_max = table.get("max_iterations", 5)
            if isinstance(n_max, bool) or not isinstance(n_max, int) or not 1 <= n_max <= 50:
                raise self.error(f"{where}.outer_loop.max_iterations", f"must be a whole number in 1..50, got {n_max!r}")
            outer = OuterLoop(tol, n_max)
        return source, outer

    def experimental_setup(self, k: int, where: str, entry: dict) -> ExperimentalElement:
        """An element loaded through a setup: dofs, actuators, setup, a multi-DOF model (docs/setups.md)."""
        from hsio.setups import make_setup
        from hsio.specimens.matrix import MATRIX_KINDS, make_matrix_specimen

        if "dof" in entry and "dofs" in entry:
            raise self.error(f"{where}.dof", "give either dof or dofs, not both")
        if "actuator" in entry and "actuators" in entry:
            raise self.error(f"{where}.actuator", "give either actuator or actuators, not both")
        if "dofs" in entry:
            names = entry["dofs"]
            if not isinstance(names, list) or not names:
                raise self.error(f"{where}.dofs", f"must be a non-empty array of DOF names, got {names!r}")
            dofs = tuple(self.dof(f"{where}.dofs[{j}]", v) for j, v in enumerate(names))
            if len(set(dofs)) != len(dofs):
                raise self.error(f"{where}.dofs", f"a DOF appears twice in {names!r}")
        else:
            dofs = (self.dof(f"{where}.dof", self.required(where, entry, "dof")),)
        n = len(dofs)
        name = self.string(f"{where}.name", entry.get("name", list(self.dof_index)[dofs[0]]))
        table = entry.get("setup", {"kind": "none"})
        try:
            setup = make_setup(table, n, f"{where}.setup")
        except ConfigError as exc:
            raise ConfigError(f"{self.file}: {exc}") from None
        if "actuators" in entry:
            actuators = entry["actuators"]
            if not isinstance(actuators, list):
                raise self.error(f"{where}.actuators", f"must be an array of actuator names, got {actuators!r}")
            actuators = tuple(self.string(f"{where}.actuators[{j}]", a) for j, a in enumerate(actuators))
        elif "actuator" in entry:
            actuators = (self.string(f"{where}.actuator", entry["actuator"]),)
        else:
            actuators = tuple(f"{name}.{getattr(a, 'name', j)}" for j, a in enumerate(getattr(setup, "actuators", ())))
            m = setup.n_actuators
            actuators = actuators or ((name,) if m == 1 else tuple(f"{name}.{j}" for j in range(m)))
        if len(actuators) != setup.n_actuators:
            raise self.error(f"{where}.actuators", f"{len(actuators)} actuator(s); setup "
                             f"{table.get('kind', 'none')!r} drives {setup.n_actuators}")
        if len(set(actuators)) != len(actuators):
            raise self.error(f"{where}.actuators", f"an actuator appears twice in {list(actuators)}")
        model = self.required(where, entry, "model")
        if isinstance(model, dict) and model.get("kind") in MATRIX_KINDS:
            spec = dict(model)
            if spec.get("kind") == "matrix":
                K = spec.get("K")
                if (not isinstance(K, list) or len(K) != n
                        or any(not isinstance(r, list) or len(r) != n for r in K)):
                    raise self.error(f"{where}.model.K", f"must be {n} rows of {n} numbers (one per basic DOF)")
                spec["K"] = tuple(tuple(self.number(f"{where}.model.K[{i}][{j}]", v) for j, v in enumerate(r))
                                  for i, r in enumerate(K))
            else:
                for key, v in spec.items():
                    if key != "kind":
                        self.number(f"{where}.model.{key}", v)
            try:
                specimen = make_matrix_specimen(spec, getattr(setup, "basic", None) or None)
            except ConfigError as exc:
                raise self.error(f"{where}.model", str(exc)) from None
            if specimen.n != n:
                raise self.error(f"{where}.model", f"the model has {specimen.n} basic DOFs; dofs names {n}")
        elif n == 1:
            spec = self.model(f"{where}.model", model)
        else:
            raise self.error(f"{where}.model.kind", f"an element with {n} basic DOFs needs a multi-DOF model: "
                             f"one of {', '.join(MATRIX_KINDS)}")
        K_EI = None
        if "K_EI" in entry:
            value = entry["K_EI"]
            if n == 1 and not isinstance(value, list):
                K_EI = self.number(f"{where}.K_EI", value, positive=True)
            else:
                if not isinstance(value, list) or len(value) != n or any(not isinstance(r, list) or len(r) != n for r in value):
                    raise self.error(f"{where}.K_EI", f"must be {n} rows of {n} numbers (one per basic DOF)")
                K = np.array([[self.number(f"{where}.K_EI[{i}][{j}]", v) for j, v in enumerate(r)]
                              for i, r in enumerate(value)])
                if not np.allclose(K, K.T, rtol=0, atol=1e-12 * np.max(np.abs(K))):
                    raise self.error(f"{where}.K_EI", "must be symmetric")
                try:
                    np.linalg.cholesky(K)
                except np.linalg.LinAlgError:
                    raise self.error(f"{where}.K_EI", "must be positive definite") from None
                K_EI = tuple(tuple(float(v) for v in r) for r in K)
        source, outer = self.external_displacement(where, entry)
        return ExperimentalElement(name, dofs[0], spec, actuators[0], K_EI, dofs=dofs, actuators=actuators,
                                   setup=dict(table), displacement_from=source, outer_loop=outer)

    def check_instruments(self, experimental, instruments) -> None:
        """Instruments have distinct names and known kinds and read existing elements; an element's
        ``displacement_from`` names a displacement instrument on that element (or on none), used by
        no other element, with a positive scale (docs/setups.md): an outer loop drives the
        element's actuator by what it reads."""
        by_name = {}
        for k, inst in enumerate(instruments):
            self.string(f"instrument[{k}].name", inst.name)
            if not isinstance(inst.kind, str) or inst.kind not in INSTRUMENT_KINDS:
                raise self.error(f"instrument[{k}].kind",
                                 f"unknown instrument {inst.kind!r}; known: {', '.join(INSTRUMENT_KINDS)}")
            if self.number(f"instrument[{k}].scale", inst.scale) == 0:
                raise self.error(f"instrument[{k}].scale", "must not be zero (the instrument would read nothing)")
            for key in ("noise", "resolution"):
                self.number(f"instrument[{k}].{key}", getattr(inst, key), non_negative=True)
            if inst.name in by_name:
                raise self.error(f"instrument[{k}].name", f"{inst.name!r} already names instrument[{by_name[inst.name]}]")
            by_name[inst.name] = k
            if inst.element and inst.element not in {e.name for e in experimental}:
                raise self.error(f"instrument[{k}].element", f"no experimental element {inst.element!r}")
        taken: dict[str, str] = {}
        for k, e in enumerate(experimental):
            if e.displacement_from:
                if e.displacement_from not in by_name:
                    raise self.error(f"experimental[{k}].displacement_from", f"no instrument {e.displacement_from!r}; "
                                     f"instruments: {', '.join(by_name) or 'none'}")
                inst = instruments[by_name[e.displacement_from]]
                if inst.unit != "mm":
                    raise self.error(f"experimental[{k}].displacement_from",
                                     f"instrument {inst.name!r} is a {inst.kind} ({inst.unit}), not a displacement")
                if e.has_setup and not e.is_parallel:
                    raise self.error(f"experimental[{k}].displacement_from",
                                     "an external displacement is taken for elements without setups or with a "
                                     "'parallel' one only")
                if e.is_parallel and e.make_setup().factors.displacement != 1.0:
                    raise self.error(f"experimental[{k}].displacement_from", "an instrument reads the lab's mm: "
                                     "the parallel setup's displacement factor must be 1")
                if inst.scale < 0:  # emulation: it would read against the element's direction
                    raise self.error(f"experimental[{k}].displacement_from",
                                     f"instrument {inst.name!r} has scale {inst.scale:g}: it would read the element's "
                                     "displacement with the opposite sign (give a positive scale)")
                if inst.element and inst.element != e.name:  # an outer loop would drive this actuator by it
                    raise self.error(f"experimental[{k}].displacement_from",
                                     f"instrument {inst.name!r} reads element {inst.element!r}, not {e.name!r}")
                if e.displacement_from in taken:
                    raise self.error(f"experimental[{k}].displacement_from",
                                     f"instrument {inst.name!r} already gives the displacement of {taken[inst.name]}")
                taken[inst.name] = f"experimental[{k}]"

    def instrument(self, k: int, entry) -> Instrument:
        """An external instrument (docs/setups.md)."""
        where = f"instrument[{k}]"
        entry = self.table(where, entry, TABLES["instrument"])
        name, kind = self.required(where, entry, "name"), self.required(where, entry, "kind")
        element = self.string(f"{where}.element", entry["element"]) if "element" in entry else ""
        scale, noise, resolution = (self.number(f"{where}.{key}", entry.get(key, default))
                                    for key, default in (("scale", 1.0), ("noise", 0.0), ("resolution", 0.0)))
        return Instrument(name, kind, element, scale, noise, resolution)  # checked by Structure (check_instruments)

    def static(self, k: int, entry) -> StaticLoad:
        """An actuator that holds a preload in force control (docs/setups.md)."""
        where = f"static[{k}]"
        entry = self.table(where, entry, TABLES["static"])
        name = self.string(f"{where}.name", self.required(where, entry, "name"))
        actuator = self.string(f"{where}.actuator", entry.get("actuator", name))
        force = self.number(f"{where}.force_kN", self.required(where, entry, "force_kN"))
        if force == 0:
            raise self.error(f"{where}.force_kN", "a preload of zero needs no static actuator")
        ramp = self.number(f"{where}.ramp_s", entry.get("ramp_s", 5.0), positive=True)
        if ramp_out_of_bounds(ramp):
            raise self.error(f"{where}.ramp_s", ramp_out_of_bounds(ramp))
        spec = self.model(f"{where}.model", self.required(where, entry, "model"))
        K_EI = self.number(f"{where}.K_EI", entry["K_EI"], positive=True) if "K_EI" in entry else None
        return StaticLoad(name, force, spec, ramp, actuator, K_EI)

    def check_frequencies(self, structure: Structure) -> None:
        """Sanity bounds of the natural frequencies (docs/faults.md): beyond them a mass or a
        stiffness is off by many orders of magnitude, almost always a typing error or a unit."""
        try:
            w2 = scipy.linalg.eigh(structure.K_init, structure.M, eigvals_only=True)
        except (np.linalg.LinAlgError, ValueError):
            w2 = np.array([np.nan])
        f = np.sqrt(np.clip(w2, 0.0, None)) / (2 * math.pi)
        low, high = FREQUENCY_BOUNDS_HZ
        bad = np.flatnonzero(~((f >= low) & (f <= high)))
        if bad.size:
            raise self.error("dof", f"mode {bad[0] + 1} at {f[bad[0]]:.3g} Hz is out of bounds: natural frequencies "
                             f"must be within {low:g}..{high:g} Hz (check the masses and stiffnesses and their units)")

    def check_damping(self, structure: Structure) -> None:
        """No mode gets a negative damping ratio. Rayleigh damping anchored on two modes whose
        ratios grow faster (or slower) than their frequencies has a0 < 0 (or a1 < 0): the modes
        below the first anchor (or above the second) then get zeta_r = a0 / (2 w_r) + a1 w_r / 2
        < 0, a C that feeds energy into them rather than dissipating it. Two modes of one
        frequency (a symmetric structure) cannot take two different Rayleigh ratios."""
        d = structure.damping
        if d.kind == "rayleigh":
            (i, j), (z_i, z_j) = d.mode_numbers(), d.ratios(2)
            w = np.sqrt(np.sort(scipy.linalg.eigh(structure.K_init, structure.M, eigvals_only=True)))
            if z_i != z_j and abs(w[j - 1] - w[i - 1]) <= 1e-9 * max(w[i - 1], w[j - 1]):
                raise self.error("damping.modes", f"rayleigh damping cannot give modes {i} and {j} two ratios "
                                 f"({100 * z_i:g} % and {100 * z_j:g} %): both are at {w[i - 1] / (2 * math.pi):.6g} "
                                 "Hz; give one ratio, or anchor modes of two frequencies")
        if d.kind == "modal" and not isinstance(d.zeta, (int, float)) and len(d.zeta) == structure.n_dof:
            # Modes of one frequency have no shapes of their own (any combination of them is a mode):
            # a ratio each would give C = M Phi diag(2 zeta w) Phi^T M that depends on which
            # combination the eigensolver returns, e.g. on the order of the [[dof]] tables.
            w = np.sqrt(np.clip(scipy.linalg.eigh(structure.K_init, structure.M, eigvals_only=True), 0.0, None))
            z = [float(v) for v in d.zeta]
            for r in range(1, len(w)):
                if z[r] != z[r - 1] and abs(w[r] - w[r - 1]) <= 1e-9 * w[r]:
                    raise self.error("damping.zeta", f"modal damping cannot give modes {r} and {r + 1} two ratios "
                                     f"({100 * z[r - 1]:g} % and {100 * z[r]:g} %): both are at "
                                     f"{w[r] / (2 * math.pi):.6g} Hz, where any combination of the two is a mode "
                                     "shape; give them one ratio")
        zeta = structure.damping_ratios()
        bad = np.flatnonzero(zeta < -1e-9)
        if bad.size:
            d = structure.damping
            ratios = list(d.ratios(len(d.mode_numbers()))) if d.kind != "modal" else d.zeta
            r = int(bad[0])
            raise self.error("damping.zeta", f"{d.kind} damping with zeta = {ratios} on modes "
                             f"{list(d.mode_numbers())} gives mode {r + 1} ({structure.natural_frequencies_hz()[r]:.3g} Hz) "
                             f"a negative damping ratio ({100 * zeta[r]:.3g} %), which would feed energy into it: "
                             "choose ratios or modes that damp every mode (Structure.damping_ratios() shows them)")

    def check_stable(self, structure: Structure) -> None:
        """K_I is not singular. Checked on K_I scaled by its diagonal, so that neither the masses
        nor the units of a DOF (mm or rad) make a stiff structure look singular or hide a free DOF."""
        K = np.asarray(structure.K_init, dtype=float)
        diagonal = np.diag(K)
        free = np.flatnonzero(~(diagonal > 0))
        if free.size:
            k = int(free[0])
        else:
            scale = 1.0 / np.sqrt(diagonal)
            w, phi = scipy.linalg.eigh(K * scale[:, None] * scale[None, :])
            if w[0] > 1e-12 * w[-1]:
                self.check_frequencies(structure)
                return
            k = int(np.argmax(np.abs(phi[:, 0])))
        raise self.error(f"dof[{k}]", f"DOF {structure.dof_names[k]!r} has no stiffness path to the ground "
                         "(the initial stiffness K_I is singular): add a spring or element")
