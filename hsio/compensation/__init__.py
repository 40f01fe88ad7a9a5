"""Feed-forward compensation of actuator execution error (docs/method.md section 4).

* :mod:`~hsio.compensation.hockey_stick`: the error model (eq. 1) and its least-squares fit.
* :mod:`~hsio.compensation.feedforward`: the adjusted command (eq. 2).
* :mod:`~hsio.compensation.online`: a and b re-estimated during the test.
* :mod:`~hsio.compensation.stage`: the per-actuator stage between the integrator and the actuators.
"""
