"""Concrete Actuator/DAQ implementations that talk to real servo controllers."""
