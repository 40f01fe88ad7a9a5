"""Emulated servo-hydraulic controllers and their protocol front-ends.

``hsio.emulators.servo`` is the controller itself (1024 Hz loop, PID, servo-valve and actuator
physics, specimen, limits and interlocks); ``hsio.emulators.local`` binds it in process to hsio's
Actuator interface.
"""
