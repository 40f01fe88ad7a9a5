"""Time integrators: plain numerical code, no I/O, no sleeps, no globals."""

from hsio.integrators.alpha_os import AlphaOS, AlphaOSState
from hsio.integrators.force_control import ImplicitForceControl, ImplicitState, StepReport
from hsio.integrators.newmark import newmark_average_acceleration

__all__ = ["AlphaOS", "AlphaOSState", "ImplicitForceControl", "ImplicitState", "StepReport",
           "newmark_average_acceleration"]
