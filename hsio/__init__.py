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

from hsio.api import make_integrator, open_site, run_numerical, simulate
from hsio.errors import ConfigError, HsioError, InterlockError, LimitError
from hsio.experiment import ExperimentStopped
from hsio.ground_motion import GroundMotion, read_at2, synthetic_record
from hsio.result import Result, max_error_pct
from hsio.sites import ActuatorSite, NumericalSite
from hsio.structures import Structure, load_structure

try:
    from importlib.metadata import PackageNotFoundError, version

    __version__ = version("hsio")
except PackageNotFoundError:  # pragma: no cover - running from a source tree that is not installed
    __version__ = "unknown"


__all__ = ["load_structure", "Structure", "GroundMotion", "read_at2", "synthetic_record", "run_numerical",
           "open_site", "simulate", "make_integrator", "Result", "max_error_pct", "ExperimentStopped",
           "ActuatorSite", "NumericalSite", "HsioError", "ConfigError", "LimitError", "InterlockError"]
