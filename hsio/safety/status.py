"""Why a run stopped, and the exit status of `hsio run` for each cause (docs/safety.md section 5).

    0  the run finished
    2  bad input (configuration, data file), or the dry run refused the test: nothing moved
    3  stopped by a limit or a fault (a refused command, a controller trip, a lost link), also
       while the hardware opens (the axes may have been enabled by then)
    4  stopped by an interlock of hsio's own (following error, implausible measurement, force drop)
    5  stopped by the operator (stop key, control socket) or by a signal (SIGTERM, SIGINT)
"""

from __future__ import annotations

from hsio.errors import CommunicationError, ConfigError, HsioError, InterlockError

OK, BAD_INPUT, LIMIT_OR_FAULT, INTERLOCK, OPERATOR = 0, 2, 3, 4, 5


class InterlockTrip(HsioError):
    """An interlock of the control loop tripped (docs/safety.md section 3); the actuators hold."""

    def __init__(self, message: str, kind: str = "interlock", actuator: str = ""):
        super().__init__(message)
        self.kind = kind
        self.actuator = actuator


class OperatorStop(HsioError):
    """The operator (a key, the control socket) or a signal stopped the run."""


class DryRunRefused(ConfigError):
    """The dry run predicts that the test exceeds a limit of the actuators; nothing moved."""


def exit_status(exc: BaseException | None) -> int:
    """The exit status for a run that ended with ``exc`` (None: finished)."""
    if exc is None:
        return OK
    stopped = hasattr(exc, "result")  # an ExperimentStopped: the loop ran, ``cause`` says why it stopped
    cause = getattr(exc, "cause", None) or exc
    if isinstance(cause, (OperatorStop, KeyboardInterrupt)):
        return OPERATOR
    if isinstance(cause, InterlockTrip):
        return INTERLOCK
    if isinstance(cause, (CommunicationError, InterlockError)):
        return LIMIT_OR_FAULT  # a lost link, a restart, a trip: a fault even before the steps began
    if not stopped and isinstance(exc, HsioError):
        return BAD_INPUT
    return LIMIT_OR_FAULT


def outcome_name(status: int) -> str:
    """A word for the ledger and the summary."""
    return {OK: "finished", BAD_INPUT: "refused", LIMIT_OR_FAULT: "stopped by a limit or fault",
            INTERLOCK: "stopped by an interlock", OPERATOR: "stopped by the operator"}.get(status, f"exit {status}")
