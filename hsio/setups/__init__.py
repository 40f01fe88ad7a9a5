"""Experimental setups: an element's basic DOFs to actuator strokes and back (docs/setups.md).

A setup turns the displacements an integrator wants at an experimental element's basic degrees of
freedom into actuator strokes, and the actuators' measured strokes and forces back into basic
displacements and forces, with the exact large-displacement geometry and its linearised form.
"""

from hsio.setups.base import Factors, Setup
from hsio.setups.factory import SETUP_KINDS, IdentitySetup, make_setup
from hsio.setups.parallel import ParallelSetup
from hsio.setups.planar import (PlanarActuator, PlanarSetup, inverted_v_brace, one_actuator, three_actuators,
                                two_actuators)

__all__ = ["Factors", "Setup", "SETUP_KINDS", "IdentitySetup", "make_setup", "ParallelSetup", "PlanarActuator", "PlanarSetup", "one_actuator", "two_actuators",
           "three_actuators", "inverted_v_brace"]
