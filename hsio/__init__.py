"""hsio: hybrid simulation of structures.

Units everywhere inside hsio: kN, mm, s; mass in kN s^2/mm (docs/method.md).

What a notebook needs is here (docs/api.md):

    import hsio

    structure = hsio.load_structure("validation")
    ground = hsio.synthetic_record(duration_s=10.0, dt=structure.dt)
    ns = hsio.run_numerical(structure, ground)
    with hsio.open_site(structure, "emulator://", test_rate=20) as site:
        hs = hsio.simulate(structure, ground, site)
    hs.to_dataframe(); hs.plot("hs.png", reference=ns)
"""

import importlib

# The names a notebook uses, imported when first used: `import hsio` (and so the `hsio` command,
# which answers Ctrl-C, --help and bad arguments at once) does not wait for numpy and scipy.
_EXPORTS = {
    "make_integrator": "hsio.api", "open_site": "hsio.api", "run_numerical": "hsio.api", "simulate": "hsio.api",
    "ConfigError": "hsio.errors", "HsioError": "hsio.errors", "InterlockError": "hsio.errors",
    "LimitError": "hsio.errors", "ExperimentStopped": "hsio.experiment", "GroundMotion": "hsio.ground_motion",
    "read_at2": "hsio.ground_motion", "read_record": "hsio.ground_motion", "synthetic_record": "hsio.ground_motion", "Result": "hsio.result",
    "max_error_pct": "hsio.result", "ActuatorSite": "hsio.sites", "NumericalSite": "hsio.sites",
    "Structure": "hsio.structures", "load_structure": "hsio.structures",
}


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("hsio")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree that is not installed
        return "unknown"


def __getattr__(name: str):
    if name == "__version__":  # looked up when first used: `hsio` starts without importlib.metadata
        globals()[name] = value = _version()
        return value
    module = _EXPORTS.get(name)
    if module is None:  # a subpackage or module (hsio.api, hsio.secant, ...), as after an import of it
        try:
            return importlib.import_module(f"hsio.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"hsio.{name}":
                raise
            raise AttributeError(f"module 'hsio' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted([*globals(), *_EXPORTS])


__all__ = ["load_structure", "Structure", "GroundMotion", "read_at2", "read_record", "synthetic_record", "run_numerical",
           "open_site", "simulate", "make_integrator", "Result", "max_error_pct", "ExperimentStopped",
           "ActuatorSite", "NumericalSite", "HsioError", "ConfigError", "LimitError", "InterlockError"]
