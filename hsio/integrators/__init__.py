"""Time integrators: plain numerical code, no I/O, no sleeps, no globals.

Each method runs in the one experiment loop (:mod:`hsio.experiment`) through the contract of
:mod:`hsio.integrators.base`: alpha-OS (:class:`OperatorSplitting`), and implicit DC, FC and
mixed (:class:`ImplicitMethod`).
"""

from hsio.integrators.alpha_os import AlphaOS, AlphaOSState, OperatorSplitting
from hsio.integrators.base import Integrator, StepOutcome
from hsio.integrators.implicit import ImplicitAlpha, ImplicitState, StepReport
from hsio.integrators.mixed import METHODS as IMPLICIT_METHODS
from hsio.integrators.mixed import ImplicitMethod, SwitchingRule
from hsio.integrators.newmark import newmark_average_acceleration

METHODS = ("alpha_os", *IMPLICIT_METHODS)

__all__ = ["AlphaOS", "AlphaOSState", "OperatorSplitting", "Integrator", "StepOutcome", "ImplicitAlpha",
           "ImplicitState", "StepReport", "ImplicitMethod", "SwitchingRule", "newmark_average_acceleration",
           "METHODS", "IMPLICIT_METHODS"]
