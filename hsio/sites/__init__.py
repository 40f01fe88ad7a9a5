"""Experimental sites: where the integrator's trial commands are imposed and measured.

:class:`ActuatorSite` drives actuators (emulated or real) through the controller-rate loop;
:class:`NumericalSite` evaluates the specimen models instead (the purely numerical simulation,
NS). Both follow one contract, :class:`~hsio.sites.base.ExperimentalSite`.
"""

from hsio.sites.actuators import ActuatorSite
from hsio.sites.base import Daq, ExperimentalSite
from hsio.sites.numerical import NumericalSite

__all__ = ["ActuatorSite", "Daq", "ExperimentalSite", "NumericalSite"]
