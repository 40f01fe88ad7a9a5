"""Errors raised by hsio. Each names what is wrong and where."""

MAX_MESSAGE_CHARS = 4000  # a message quoting a value from a file (a line of megabytes) is cut to this


class HsioError(Exception):
    """Base class of every error hsio raises on purpose.

    Its text is at most :data:`MAX_MESSAGE_CHARS` characters: a longer one (a value quoted whole
    from a file) loses its middle, keeping where (file, line, key) and the end of the sentence."""

    def __str__(self) -> str:
        text = super().__str__()
        if len(text) <= MAX_MESSAGE_CHARS:
            return text
        head, tail = 3 * MAX_MESSAGE_CHARS // 4, MAX_MESSAGE_CHARS // 8
        return f"{text[:head]} ... ({len(text) - head - tail} characters left out) ... {text[-tail:]}"


class ConfigError(HsioError):
    """A configuration (TOML file, keyword, structure name) is invalid."""


class RecordError(HsioError):
    """A ground-motion record or data file cannot be read or holds bad values."""


class LimitError(HsioError):
    """A command was refused because it is beyond an actuator limit.

    Nothing was sent. The caller stops, holds the actuators and reads the hold back
    (docs/safety.md section 3).
    """


class CommunicationError(HsioError):
    """A controller did not answer, answered with an error, or the link dropped."""


class InterlockError(HsioError):
    """A controller reports an interlock (limit trip, fault) and holds."""


class ProtocolError(CommunicationError):
    """A controller answered with a protocol-level error that carries a code (a Modbus
    exception code, a CANopen SDO abort code). Control flow tests ``code``, never the text."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = int(code)


class ModbusExceptionError(ProtocolError):
    """A Modbus exception response; ``code`` is the exception code (2: illegal data address, ...)."""


class SdoAbortError(ProtocolError):
    """A CANopen SDO transfer aborted; ``code`` is the 32-bit abort code (0x06020000: no such object)."""


class ControllerRestartedError(CommunicationError):
    """The controller restarted during the run (a new boot id or a boot-up message): its state
    is lost and the run stops."""


class ImplausibleMeasurementError(InterlockError):
    """A measured value is not plausible (not finite, beyond a physical bound, an impossible
    jump); it never reaches the integrator and the run stops as for an interlock (the hold is read
    back)."""
