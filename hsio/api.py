"""hsio as a library: what a notebook or a script needs, in a few calls.

    import hsio

    structure = hsio.load_structure("validation")            # a shipped name or a TOML file
    ground = hsio.synthetic_record(duration_s=10.0, dt=structure.dt)
    ns = hsio.run_numerical(structure, ground)               # NS: specimen models, no hardware
    with hsio.open_site(structure, "emulator://", test_rate=20) as site:
        hs = hsio.simulate(structure, ground, site)          # HS: the same loop on actuators
    hs.to_dataframe()                                        # pandas (optional extra)
    hs.plot("hs.png", reference=ns)

Several records on one specimen: keep the site open and start each record from where the
specimen stands (docs/safety.md section 6):

    with hsio.open_site(structure, "emulator://") as site:
        first = hsio.simulate(structure, small, site)
        second = hsio.simulate(structure, large, site, start="present")

``hsio run`` is a thin shell over these functions (:mod:`hsio.runner`).
"""

from __future__ import annotations

from hsio.clock import LockstepClock, RealTimeClock
from hsio.control_loop import ControlLoop
from hsio.errors import ConfigError
from hsio.experiment import run_steps
from hsio.ground_motion import GroundMotion
from hsio.hardware import open_hardware
from hsio.integrators import IMPLICIT_METHODS, METHODS, ImplicitMethod, OperatorSplitting, SwitchingRule
from hsio.recording import Recorder
from hsio.result import Result
from hsio.safety.interlocks import InterlockMonitor
from hsio.safety.settings import SafetySettings
from hsio.secant import SecantEstimator
from hsio.sites import ActuatorSite, NumericalSite
from hsio.structures import Structure

__all__ = ["make_integrator", "run_numerical", "open_site", "simulate"]


def make_integrator(structure: Structure, method: str = "alpha_os", alpha: float = -0.05, *,
                    correct_measured_displacement: bool = True, rule: SwitchingRule | None = None,
                    j_max: int = 3, tol_displacement: float = 0.02, tol_force: float = 0.05):
    """The integration method ``method`` for ``structure`` (docs/method.md sections 2, 3 and 5).

    ``alpha_os``: operator splitting, one trial per step. ``implicit_dc``, ``force_control``,
    ``mixed``: the implicit alpha method by secant iteration (at most ``j_max`` commands per
    step, tolerances in mm and kN); ``rule`` gives the switching thresholds of ``mixed``
    (default 1.2 and 0.8 times each element's K^EI).
    """
    if method not in METHODS:
        raise ConfigError(f"integrator method must be one of {', '.join(METHODS)}, got {method!r}")
    dofs = structure.experimental_dofs
    K_EI = [e.K_EI for e in structure.experimental]
    if method == "alpha_os":
        return OperatorSplitting(structure.M, structure.C, structure.K_init, structure.dt, alpha, dofs, K_EI,
                                 correct_measured_displacement)
    numerical = structure.numerical_assembly()
    if not numerical.is_linear:
        raise ConfigError(f"structure {structure.name!r}: the implicit methods ({', '.join(IMPLICIT_METHODS)}) take "
                          f"linear numerical elements only (the secant model of eq. 9 covers the experimental "
                          f"elements); use method = 'alpha_os'")
    return ImplicitMethod(structure.M, structure.C, numerical.K_linear, dofs, K_EI, structure.dt, alpha, method,
                          rule, structure.dof_names, j_max=j_max, tol_displacement=tol_displacement,
                          tol_force=tol_force)


def run_numerical(structure: Structure, ground: GroundMotion, method: str = "alpha_os", alpha: float = -0.05,
                  control=None, **options) -> Result:
    """NS: the run with the specimen models in place of the actuators.

    For the implicit methods the reference is implicit DC iterated to 1e-10 (at most 20
    iterations): the converged solution that any of them approaches.
    """
    if method in IMPLICIT_METHODS:
        integrator = make_integrator(structure, "implicit_dc", alpha, j_max=20, tol_displacement=1e-10,
                                     tol_force=1e-10)
    else:
        integrator = make_integrator(structure, method, alpha, **options)
    return simulate(structure, ground, NumericalSite.of(structure), integrator=integrator, control=control)


def open_site(structure: Structure, hardware: str = "emulator://", *, clock: str = "lockstep",
              test_rate: float = 20.0, hold_fraction: float = 0.5, n_avg: int = 4, keep_samples: bool = True,
              options: dict | None = None, estimator: SecantEstimator | None = None,
              compensation=None, safety: SafetySettings | None = None) -> ActuatorSite:
    """Open the actuators of ``structure``'s experimental elements at ``hardware`` (a URL:
    ``emulator://``, ``modbus+tcp://HOST:PORT``, ...) behind the controller-rate loop.

    ``options`` is the [emulator] table for ``emulator://`` and the [driver] table otherwise.
    Use it as a context manager (or call ``close()``): the actuators are left holding.
    ``safety`` sets the interlocks checked every controller period (docs/safety.md section 3;
    default: the documented defaults, on).
    """
    safety = safety or SafetySettings()
    if clock not in ("lockstep", "realtime"):
        raise ConfigError(f"clock must be 'lockstep' or 'realtime', got {clock!r}")
    ticker = LockstepClock() if clock == "lockstep" else RealTimeClock()
    actuators = open_hardware(hardware, structure.experimental, ticker, options or {})
    try:
        monitor = InterlockMonitor(actuators, safety) if safety.interlocks else None
        loop = ControlLoop(actuators, ticker, structure.dt, test_rate, n_avg=n_avg, keep_samples=keep_samples,
                           hold_fraction=hold_fraction, monitor=monitor)
    except BaseException:
        for actuator in actuators:
            try:
                actuator.close()
            except Exception:
                pass
        raise
    try:
        return ActuatorSite(loop, estimator, compensation)
    except BaseException:
        loop.close()
        raise


def simulate(structure: Structure, ground: GroundMotion, site, method: str = "alpha_os", alpha: float = -0.05,
             recorder: Recorder | None = None, progress=None, integrator=None, control=None, start: str = "rest",
             resume_state=None, **options) -> Result:
    """``method`` over the whole record against ``site``: HS on actuators (from :func:`open_site`),
    NS on a :class:`~hsio.sites.NumericalSite`.

    ``start="present"`` starts from where the specimen stands (the site's committed state, e.g.
    after an earlier record on the same open site); ``control`` (a
    :class:`hsio.safety.control.RunControl`) pauses, resumes or stops the run between steps.

    ``options`` go to :func:`make_integrator` (or pass a ready ``integrator``). Raises :class:`hsio.experiment.ExperimentStopped`
    (carrying the steps made, the actuators holding) if the run stops early.
    """
    if integrator is None:
        integrator = make_integrator(structure, method, alpha, **options)
    return run_steps(structure, ground, integrator, site, recorder, progress, control=control, start=start,
                     resume_state=resume_state)
